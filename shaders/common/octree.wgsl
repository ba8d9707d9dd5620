// Shared octree code (seed §8.5.10-§8.5.12): node pool encoding, records, point location.
// Twin of pc-artifact/src/octree.rs and pc-tree/src/lib.rs. A kernel that includes this file
// declares `octree_nodes: array<u32>` (storage) and `octree_frame: Frame` (uniform).

const NODE_LEAF: u32 = 0x80000000u;
const NODE_EMPTY: u32 = 0x40000000u;
const NODE_PTR: u32 = 0x3fffffffu;
const INVALID: u32 = 0xffffffffu;

struct Frame {
    origin: vec3<f32>,
    size: f32,
    inv_size: f32,
    depth: u32,
    max_depth: u32,
    max_leaf_points: u32,
    node_count: u32,
    leaf_count: u32,
    splat_count: u32,
    ref_count: u32,
}

struct Splat {
    position: vec3<f32>,
    radius: f32,
    normal: vec3<f32>,
    material: u32,
    albedo: vec3<f32>,
    source: u32,
    // Border clip: the splat keeps the points x with dot(x - position, o_k) <= clip.w for its
    // two clip lines (clip_lines; Splat::clip in pc-artifact).
    clip: vec4<f32>,
}

// The unit outward normals of a splat's two clip lines (pc_artifact::octree::clip_lines):
// |clip.xyz| = 1 / cos(phi), o = q^ cos(phi) +- (n x q^) sin(phi); zero for an interior splat.
fn clip_lines(s: Splat) -> array<vec3<f32>, 2> {
    let q = s.clip.xyz;
    let s2 = dot(q, q);
    if s2 == 0.0 {
        return array<vec3<f32>, 2>(vec3<f32>(0.0), vec3<f32>(0.0));
    }
    let c = 1.0 / sqrt(s2);
    let sn = sqrt(max(1.0 - c * c, 0.0));
    let t = cross(s.normal, q);
    let a = c * c;
    let b = c * sn;
    return array<vec3<f32>, 2>(q * a + t * b, q * a - t * b);
}

fn within_clip(s: Splat, x: vec3<f32>) -> bool {
    let o = clip_lines(s);
    let d = x - s.position;
    return dot(d, o[0]) <= s.clip.w && dot(d, o[1]) <= s.clip.w;
}

// A point of the splat's plane mirrored across the clip lines it lies beyond, repeated up to
// three rounds (Splat::fold_into_clip).
fn fold_into_clip(s: Splat, x: vec3<f32>) -> vec3<f32> {
    let o = clip_lines(s);
    var y = x;
    for (var round = 0u; round < 3u; round++) {
        let e0 = dot(y - s.position, o[0]) - s.clip.w;
        if e0 > 0.0 {
            y = y - 2.0 * e0 * o[0];
        }
        let e1 = dot(y - s.position, o[1]) - s.clip.w;
        if e1 > 0.0 {
            y = y - 2.0 * e1 * o[1];
        }
        if e0 <= 0.0 && e1 <= 0.0 {
            break;
        }
    }
    return y;
}

struct NodeInfo {
    centroid: vec3<f32>,
    disk_radius: f32,
    normal: vec3<f32>,
    area: f32,
    tilt: vec2<f32>,
    count: u32,
    material_class: u32,
}

struct Located {
    slot: u32,
    node: u32,
    depth: u32,
}

// The leaf or empty node containing p: the p·N − int(p·N) descent of §8.5.11 with N = 2.
// slot == INVALID when p lies outside the root cube. Rounds exactly like the CPU twin.
fn octree_locate(p: vec3<f32>) -> Located {
    var q = (p - octree_frame.origin) * octree_frame.inv_size;
    if any(q < vec3<f32>(0.0)) || any(q >= vec3<f32>(1.0)) {
        return Located(INVALID, 0u, 0u);
    }
    var slot = 0u;
    // A valid pool is at most 21 levels deep (pc-tree checks this on open); the bound keeps a
    // malformed one from hanging the GPU.
    for (var depth = 0u; depth <= 21u; depth = depth + 1u) {
        let w = octree_nodes[slot];
        if (w & (NODE_LEAF | NODE_EMPTY)) != 0u {
            return Located(slot, w, depth);
        }
        let t = q * 2.0;
        let c = floor(t);
        q = t - c;
        slot = (w & NODE_PTR) + u32(c.x) + 2u * u32(c.y) + 4u * u32(c.z);
    }
    return Located(INVALID, 0u, 0u);
}
