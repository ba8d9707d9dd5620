// requires: common/octree.wgsl
// Shared specular optics and random numbers (seed §8.5.5, §8.5.6), used by the renderer and the
// photon tracer. Twins: crates/pc-tree/src/optics.rs (reflect, fresnel, shading_normal,
// specular_bounce), crates/pc-tree/src/rng.rs (pcg, rand), pc_tree::disk_point and
// pc_tree::field_normal. A kernel that includes this file declares `splats: array<Splat>`,
// `node_info: array<NodeInfo>` and `splat_leaf: array<u32>`.

const PI: f32 = 3.14159265358979;
const CLASS_EMITTER: u32 = 1u;
const CLASS_MIRROR: u32 = 2u;
const CLASS_DIELECTRIC: u32 = 3u;

// A material (twin of pc_artifact::octree::MaterialRecord).
struct Material {
    color: vec3<f32>,
    class_id: u32,
    radiance: vec3<f32>,
    ior: f32,
    phong: f32,
    per_point_color: u32,
    _pad: vec2<u32>,
}

// ---- counter-based random numbers (twin of pc_tree::rng) ------------------------------------

fn pcg(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// A uniform number in [0, 1) for (seed, stream, index, dimension), 24 random bits.
fn rand4(seed: u32, stream: u32, index: u32, d: u32) -> f32 {
    let h = pcg(stream ^ pcg(index ^ pcg(d ^ pcg(seed))));
    return f32(h >> 8u) * (1.0 / 16777216.0);
}

// ---- geometry (twins of pc-tree) ------------------------------------------------------------

fn tangent_frame_u(n: vec3<f32>) -> vec3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
}

// A point of splat s's disk for (u1, u2) uniform in [0, 1)², folded into its border clip.
fn disk_point(s: Splat, u1: f32, u2: f32) -> vec3<f32> {
    let tu = tangent_frame_u(s.normal);
    let tv = cross(s.normal, tu);
    let r = sqrt(u1) * s.radius;
    let phi = 2.0 * PI * u2;
    return fold_into_clip(s, s.position + (tu * cos(phi) + tv * sin(phi)) * r);
}

// A direction about the unit normal n with density cos θ / π for (u1, u2) uniform in [0, 1)²
// (twin of pc_tree::cosine_dir).
fn cosine_dir(n: vec3<f32>, u1: f32, u2: f32) -> vec3<f32> {
    let tu = tangent_frame_u(n);
    let tv = cross(n, tu);
    let r = sqrt(u1);
    let phi = 2.0 * PI * u2;
    let z = sqrt(max(1.0 - u1, 0.0));
    return normalize(tu * (r * cos(phi)) + tv * (r * sin(phi)) + n * z);
}

fn field_normal(info: NodeInfo, x: vec3<f32>) -> vec3<f32> {
    let n = info.normal;
    let u = tangent_frame_u(n);
    let v = cross(n, u);
    let d = x - info.centroid;
    let m = n + u * (info.tilt.x * dot(d, u)) + v * (info.tilt.y * dot(d, v));
    let l = length(m);
    if l > 0.0 {
        return m / l;
    }
    return n;
}

// ---- specular interactions (twins of pc_tree::optics) ---------------------------------------

fn reflect_dir(d: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return d - 2.0 * dot(d, n) * n;
}

fn fresnel(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = eta * eta * max(1.0 - cos_i * cos_i, 0.0);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin2_t);
    let rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// The normal at x of specular splat j: its leaf's normal field, or its own normal when the leaf
// has none or the field disagrees with the splat's side.
fn shading_normal(j: u32, x: vec3<f32>) -> vec3<f32> {
    let ns = splats[j].normal;
    let info = node_info[splat_leaf[j]];
    // No field, or one that misses the splat's own normal at its centre (fitted across a sharp
    // edge; twin of FIELD_RESIDUAL_COS in optics.rs): the splat's own normal.
    if all(info.normal == vec3<f32>(0.0)) || dot(field_normal(info, splats[j].position), ns) < FIELD_RESIDUAL_COS {
        return ns;
    }
    var n = field_normal(info, x);
    // A field that turns more than FIELD_MIN_COS away from the splat blends across a sharp
    // edge (twin of optics.rs).
    if dot(n, ns) < FIELD_MIN_COS {
        n = ns;
    }
    return n;
}

const FIELD_MIN_COS: f32 = 0.9;
const FIELD_RESIDUAL_COS: f32 = 0.995;

struct Bounce {
    dir: vec3<f32>,
    tint: vec3<f32>,
}

// What a ray along unit `dir` meets on a specular splat with own normal `ns` and shading normal
// `n` (twin of pc_tree::optics's Interface): the shading normal facing it, and for a dielectric
// of index `ior` the Fresnel reflectance and, unless totally reflected, the refracted direction.
struct Interface {
    nf: vec3<f32>,
    f: f32,
    refracted: vec3<f32>,
    transmits: bool,
}

fn interface_at(m: Material, ns: vec3<f32>, n: vec3<f32>, dir: vec3<f32>) -> Interface {
    var nf = n;
    if dot(dir, n) >= 0.0 {
        nf = -n;
    }
    var out = Interface(nf, 1.0, vec3<f32>(0.0), false);
    if m.class_id == CLASS_MIRROR {
        return out;
    }
    var eta = m.ior;
    if dot(dir, ns) < 0.0 {
        eta = 1.0 / m.ior;
    }
    let ci = -dot(dir, nf);
    out.f = fresnel(clamp(ci, 0.0, 1.0), eta);
    let sin2_t = eta * eta * max(1.0 - ci * ci, 0.0);
    if sin2_t < 1.0 {
        out.refracted = normalize(eta * dir + (eta * ci - sqrt(1.0 - sin2_t)) * nf);
        out.transmits = true;
    }
    return out;
}

// The specular bounce of a ray along unit `dir` on a splat with own normal `ns`, shading normal
// `n`, material `m` and color `color`: mirrors reflect and tint; dielectrics reflect with the
// Fresnel probability (always under total internal reflection), otherwise refract, tinted; `u`
// in [0, 1) is the random choice.
fn specular_bounce(m: Material, color: vec3<f32>, ns: vec3<f32>, n: vec3<f32>, dir: vec3<f32>, u: f32) -> Bounce {
    let i = interface_at(m, ns, n, dir);
    if m.class_id == CLASS_MIRROR {
        return Bounce(reflect_dir(dir, i.nf), color);
    }
    if i.transmits && u >= i.f {
        return Bounce(i.refracted, color);
    }
    return Bounce(reflect_dir(dir, i.nf), vec3<f32>(1.0));
}

// Both ways out of a dielectric at once (twin of pc_tree::optics::dielectric_split): the
// reflection tinted by the Fresnel reflectance f and, when `transmits` (not total internal
// reflection), the refraction tinted by (1 - f) and `color`. Arguments as specular_bounce's.
struct Split {
    reflected: vec3<f32>,
    r_tint: vec3<f32>,
    refracted: vec3<f32>,
    t_tint: vec3<f32>,
    transmits: bool,
}

fn dielectric_split(m: Material, color: vec3<f32>, ns: vec3<f32>, n: vec3<f32>, dir: vec3<f32>) -> Split {
    let i = interface_at(m, ns, n, dir);
    return Split(reflect_dir(dir, i.nf), vec3<f32>(i.f), i.refracted, (1.0 - i.f) * color, i.transmits);
}
