"""The Mitsuba peer of `cargo xtask bench --only mitsuba` (dev-only; run by xtask in a virtual
environment with Mitsuba 3 from PyPI, never part of pcgi).

Usage: mitsuba_time.py REFERENCE_DIR TARGET_ERROR THREADS [PCGI_IMAGE.exr]

Builds the reference scene from its *.scene.json (the exact shapes, materials, camera and
integrator Mitsuba rendered the reference with), then path-traces it on THREADS threads at 1, 2,
4, ... samples per pixel (passes of at most 256, each with its own seed, averaged) until the
image's per-pixel relative error against the reference,
    sqrt(mean(((x - ref) / (|ref| + 0.01 mean(ref)))^2))   over all pixels and channels,
is at most TARGET_ERROR (or 16384 spp, or 900 s). The render times exclude Dr.Jit's one-off
kernel compilation (a warm-up render at 1 spp first). With PCGI_IMAGE, its error by the same
function is printed too (a check on the Rust side's figure). Prints one JSON line.
"""

import json
import sys
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v]}


def bsdf(b):
    t = b["type"]
    if t == "diffuse":
        return {"type": "diffuse", "reflectance": rgb(b["reflectance"])}
    if t == "conductor":
        return {"type": "conductor", "material": b.get("material", "none")}
    if t == "dielectric":
        return {"type": "dielectric", "int_ior": b["int_ior"], "ext_ior": b["ext_ior"]}
    raise SystemExit(f"mitsuba_time: unknown bsdf type {t!r}")


def scene_dict(desc):
    scene = {"type": "scene"}
    for s in desc["shapes"]:
        shape = {
            "type": s["type"],
            "to_world": mi.ScalarTransform4f(s["to_world"]),
            "bsdf": bsdf(s["bsdf"]),
        }
        if s.get("emitter"):
            shape["emitter"] = {"type": "area", "radiance": rgb(s["emitter"]["radiance"])}
        scene[s["name"]] = shape
    cam = desc["sensor"]
    film = cam["film"]
    scene["sensor"] = {
        "type": "perspective",
        "fov": cam["fov_deg"],
        "fov_axis": cam["fov_axis"],
        "near_clip": cam["near_clip"],
        "far_clip": cam["far_clip"],
        "to_world": mi.ScalarTransform4f(cam["to_world"]),
        "film": {
            "type": "hdrfilm",
            "width": film["width"],
            "height": film["height"],
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
            "sample_border": False,
        },
        "sampler": {"type": "independent"},
    }
    integ = desc["integrator"]
    scene["integrator"] = {
        "type": "path",
        "max_depth": integ["max_depth"],
        "rr_depth": integ["rr_depth"],
        "hide_emitters": integ["hide_emitters"],
    }
    return scene


def per_pixel_error(x, ref):
    d = (x - ref) / (np.abs(ref) + 0.01 * ref.mean())
    return float(np.sqrt(np.mean(d * d)))


def main():
    ref_dir, target, threads = Path(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    pcgi_image = sys.argv[4] if len(sys.argv) > 4 else None
    dr.set_thread_count(threads)
    name = ref_dir.name
    desc = json.loads((ref_dir / f"{name}.scene.json").read_text())
    ref = np.array(mi.Bitmap(str(ref_dir / f"{name}.exr")).convert(
        mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32), dtype=np.float64)
    scene = mi.load_dict(scene_dict(desc))
    t0 = time.perf_counter()
    np.array(mi.render(scene, spp=1, seed=1 << 20))
    warmup = time.perf_counter() - t0
    steps = []
    spp, total_time, seed = 1, 0.0, 0
    acc, done = None, 0
    while True:
        # Render up to `spp` samples in all (passes of at most 256), adding to the running sum.
        t = time.perf_counter()
        while done < spp:
            n = min(256, spp - done)
            img = np.array(mi.render(scene, spp=n, seed=seed), dtype=np.float64)
            seed += 1
            acc = img * n if acc is None else acc + img * n
            done += n
        total_time += time.perf_counter() - t
        err = per_pixel_error(acc / done, ref)
        steps.append({"spp": done, "seconds": round(total_time, 4), "error": round(err, 5)})
        if err <= target or spp >= 16384 or total_time > 900:
            break
        spp *= 2
    out = {
        "peer": f"Mitsuba {mi.__version__} ({mi.variant()})",
        "threads": threads,
        "target_error": target,
        "reached": steps[-1]["error"] <= target,
        "warmup_seconds": round(warmup, 3),
        "steps": steps,
    }
    if pcgi_image:
        x = np.array(mi.Bitmap(pcgi_image).convert(
            mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32), dtype=np.float64)
        out["pcgi_error_check"] = round(per_pixel_error(x, ref), 5)
    print(json.dumps(out))


main()
