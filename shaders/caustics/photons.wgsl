// requires: common/octree.wgsl common/traverse.wgsl common/optics.wgsl
// Photon tracing kernel (seed §8.5.4 to §8.5.7): one thread per photon id. Line-by-line twin of
// crates/pc-caustics/src/trace.rs (Tracer::start, Tracer::step) and of Leaves::pick in
// crates/pc-caustics/src/emit.rs; draws the same counter-based random numbers, so a photon
// follows the same path on both sides up to floating-point rounding. Driven by
// crates/pc-caustics/src/gpu.rs, which compacts the stored photons in id order.

// An octree leaf's own splats [lo, hi) and their summed area (twin of emit::Leaf).
struct Leaf {
    lo: u32,
    hi: u32,
    area: f32,
    _pad: u32,
}

// Photons first .. first + count of one aim (twin of emit::Aim): from a point light at `origin`
// (source_leaf == INVALID) or from a splat of emitter leaf `source_leaf`, each carrying `power`.
// `sampling` is emit::Sampling: SAMPLING_WHOLE and SAMPLING_AREA aim at a splat of specular leaf
// `target_leaf` (SAMPLING_AREA scales the power by link_weight of the two points);
// SAMPLING_DIRECTION draws a direction by cosine and keeps the photon if its first hit is a
// specular splat of [lo, hi) (the subtree of node-pool slot `node`), scaled by link_weight there.
struct Aim {
    origin: vec3<f32>,
    source_leaf: u32,
    power: vec3<f32>,
    target_leaf: u32,
    first: u32,
    sampling: u32,
    k: f32,
    lo: u32,
    hi: u32,
    node: u32,
    _pad2: u32,
    _pad3: u32,
}

const SAMPLING_WHOLE: u32 = 0u;
const SAMPLING_AREA: u32 = 1u;
const SAMPLING_DIRECTION: u32 = 2u;

struct PhotonParams {
    seed: u32,
    max_bounces: u32,
    aim_count: u32,
    // This dispatch traces photons id_offset .. id_offset + count.
    id_offset: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// One photon's fate (twin of pc_artifact::photons::Photon; `fate` in place of its padding).
struct PhotonOut {
    position: vec3<f32>,
    splat: u32,
    dir: vec3<f32>,
    bounces: u32,
    power: vec3<f32>,
    fate: u32,
}

const FATE_STORED: u32 = 0u;
const FATE_OCCLUDED: u32 = 1u;
const FATE_LOST: u32 = 2u;
const FATE_ABSORBED: u32 = 3u;
const F32_MAX: f32 = 3.40282347e38;
// Random-number dimensions of a photon: 0..5 for the emission, then one per bounce.
const DIM_BOUNCE: u32 = 8u;

@group(0) @binding(0) var<uniform> octree_frame: Frame;
@group(0) @binding(1) var<storage, read> octree_nodes: array<u32>;
@group(0) @binding(2) var<storage, read> begin_end: array<u32>;
@group(0) @binding(3) var<storage, read> splats: array<Splat>;
@group(0) @binding(4) var<storage, read> node_info: array<NodeInfo>;
@group(0) @binding(5) var<storage, read> splat_area: array<f32>;
@group(0) @binding(6) var<storage, read> splat_leaf: array<u32>;
@group(0) @binding(7) var<storage, read> materials: array<Material>;
@group(0) @binding(8) var<storage, read> leaves: array<Leaf>;
@group(0) @binding(9) var<storage, read> aims: array<Aim>;
@group(0) @binding(10) var<uniform> params: PhotonParams;
@group(0) @binding(11) var<storage, read_write> out_photons: array<PhotonOut>;
// Each octree leaf's roughness, per node-pool slot (pc_tree::between::leaf_roughness).
@group(0) @binding(12) var<storage, read> leaf_rough: array<f32>;

// The nearest hit of a ray from ro along rd leaving splat j (INVALID: none) past j's own zone
// (twin of the CPU's Between::leaving with Accel::intersect_between).
fn trace_from(ro: vec3<f32>, rd: vec3<f32>, t_min: f32, j: u32) -> Hit {
    if j == INVALID {
        return trace(ro, rd, t_min, F32_MAX, false);
    }
    return trace_between(ro, rd, t_min, F32_MAX, false, leaving(splats[j], leaf_rough[splat_leaf[j]], rd));
}

fn r(id: u32, d: u32) -> f32 {
    return rand4(params.seed, id, 0u, d);
}

// A splat of leaf l drawn in proportion to area (twin of Leaves::pick).
fn pick(l: u32, u: f32) -> u32 {
    let leaf = leaves[l];
    var t = u * leaf.area;
    for (var j = leaf.lo; j < leaf.hi; j = j + 1u) {
        t = t - splat_area[j];
        if t < 0.0 {
            return j;
        }
    }
    return leaf.hi - 1u;
}

// A specular-link path's geometry under the balance heuristic (twin of emit::link_weight).
fn link_weight(cos_s: f32, cos_t: f32, d: f32, k: f32) -> f32 {
    let g = cos_s * cos_t;
    if g <= 0.0 {
        return 0.0;
    }
    return g / (d * d + k * g);
}

// Whether the ray from `ro` along `rd` (from t_min on) can meet a disk of the node at node-pool
// slot `node`: it passes within the node's average-disk radius of its centroid, padded. Twin of
// trace::may_meet in crates/pc-caustics/src/trace.rs.
fn may_meet(node: u32, ro: vec3<f32>, rd: vec3<f32>, t_min: f32) -> bool {
    let info = node_info[node];
    let to = info.centroid - ro;
    let reach = info.disk_radius * (1.0 + 1e-4) + length(to) * 1e-5;
    let t = max(dot(to, rd), t_min);
    let off = to - rd * t;
    return dot(off, off) <= reach * reach;
}

fn fate(f: u32) -> PhotonOut {
    return PhotonOut(vec3<f32>(0.0), INVALID, vec3<f32>(0.0), 0u, vec3<f32>(0.0), f);
}

fn photon(id: u32) -> PhotonOut {
    // The aim of photon id: the last one whose first id is <= id.
    var lo = 0u;
    var hi = params.aim_count;
    loop {
        if lo >= hi {
            break;
        }
        let mid = (lo + hi) / 2u;
        if aims[mid].first <= id {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    let aim = aims[lo - 1u];
    // Start: the light's position, or a point on an emitter splat drawn by area.
    var origin = aim.origin;
    var t_min = 0.0;
    var leaving_splat = INVALID;
    var emitter_normal = vec3<f32>(0.0);
    if aim.source_leaf != INVALID {
        leaving_splat = pick(aim.source_leaf, r(id, 0u));
        let s = splats[leaving_splat];
        origin = disk_point(s, r(id, 1u), r(id, 2u));
        t_min = LEAVE_EPS * s.radius;
        emitter_normal = s.normal;
    }
    var rd: vec3<f32>;
    var first_min = 0.0;
    var cos_s = 0.0;
    var power = aim.power;
    if aim.sampling == SAMPLING_DIRECTION {
        // A direction by cosine about the source splat; its first hit decides.
        if aim.source_leaf == INVALID {
            return fate(FATE_LOST);
        }
        rd = cosine_dir(emitter_normal, r(id, 3u), r(id, 4u));
        cos_s = dot(emitter_normal, rd);
        if !may_meet(aim.node, origin, rd, t_min) {
            // Its first hit cannot be the node's: what the walk would conclude.
            return fate(FATE_OCCLUDED);
        }
    } else {
        // Aim: a point on a splat of the target leaf, drawn by area.
        let target_splat = splats[pick(aim.target_leaf, r(id, 3u))];
        let to = disk_point(target_splat, r(id, 4u), r(id, 5u)) - origin;
        let dist = length(to);
        if dist <= t_min {
            return fate(FATE_OCCLUDED);
        }
        rd = to / dist;
        if aim.source_leaf != INVALID && dot(emitter_normal, rd) <= 0.0 {
            return fate(FATE_OCCLUDED);
        }
        if aim.sampling == SAMPLING_AREA {
            let ct = abs(dot(target_splat.normal, rd));
            let ce = select(1.0, dot(emitter_normal, rd), aim.source_leaf != INVALID);
            power = power * link_weight(ce, ct, dist, aim.k);
        }
        // The first hit must be the aimed surface: overlapping disks of the same surface lie
        // within about a radius of the aim point along the ray.
        first_min = dist - 2.0 * target_splat.radius;
    }
    var ro = origin;
    var bounces = 0u;
    loop {
        // Leaving a surface (an emitter splat or a specular bounce): past its own zone.
        let hit = trace_from(ro, rd, t_min, leaving_splat);
        if !hit.found {
            // A path drawn by direction that meets nothing missed its target.
            if bounces == 0u && aim.sampling == SAMPLING_DIRECTION {
                return fate(FATE_OCCLUDED);
            }
            return fate(FATE_LOST);
        }
        let s = splats[hit.splat];
        let m = materials[s.material];
        let specular = m.class_id == CLASS_MIRROR || m.class_id == CLASS_DIELECTRIC;
        if bounces == 0u {
            if aim.sampling == SAMPLING_DIRECTION {
                if hit.splat < aim.lo || hit.splat >= aim.hi || !specular {
                    return fate(FATE_OCCLUDED);
                }
                power = power * link_weight(cos_s, abs(dot(rd, s.normal)), hit.t, aim.k);
            } else if hit.t < first_min {
                return fate(FATE_OCCLUDED);
            }
        }
        let x = ro + rd * hit.t;
        if specular {
            if bounces == params.max_bounces {
                return fate(FATE_LOST);
            }
            let u = r(id, DIM_BOUNCE + bounces);
            let n = shading_normal(hit.splat, x);
            let b = specular_bounce(m, m.color * s.albedo, s.normal, n, rd, u);
            power = power * b.tint;
            bounces = bounces + 1u;
            ro = x;
            rd = b.dir;
            t_min = LEAVE_EPS * s.radius;
            leaving_splat = hit.splat;
            continue;
        }
        if bounces == 0u {
            return fate(FATE_OCCLUDED);
        }
        if dot(rd, s.normal) >= 0.0 {
            return fate(FATE_ABSORBED);
        }
        return PhotonOut(x, hit.splat, rd, bounces, power, FATE_STORED);
    }
    return fate(FATE_LOST);
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * 64u;
    if i >= params.count {
        return;
    }
    out_photons[i] = photon(params.id_offset + i);
}
