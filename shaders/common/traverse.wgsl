// requires: common/octree.wgsl
// Shared ray traversal (twin of crates/pc-tree/src/ray.rs): ray-splat intersection and the
// octree walk with exact face stepping (docs/raytrace.md). A kernel that includes this file
// declares `octree_frame`, `octree_nodes`, `begin_end: array<u32>` and `splats: array<Splat>`.

// Ray parameter at which the ray crosses the splat inside its disk and its border clip, or -1.
fn intersect_splat(o: vec3<f32>, d: vec3<f32>, s: Splat) -> f32 {
    let denom = dot(d, s.normal);
    if abs(denom) < 1e-8 {
        return -1.0;
    }
    let t = dot(s.position - o, s.normal) / denom;
    let x = o + d * t;
    let e = x - s.position;
    if dot(e, e) <= s.radius * s.radius && within_clip(s, x) {
        return t;
    }
    return -1.0;
}

fn below(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) - 1u);
}

struct Hit {
    t: f32,
    splat: u32,
    leaf: u32,
    found: bool,
}

const MAX_LEVELS: u32 = 21u;
const ROOT: u32 = 2097152u;
const CELL: f32 = 4.76837158203125e-7; // 2^-21, exact

// Nearest hit in [t_min, t_max]; with any_hit, the first one found (shadow rays).
// Twin of OctreeView::walk: integer cell coordinates, exact face stepping, and the descent
// (§8.5.11) resumed from the deepest common ancestor of consecutive cells.
fn trace(o: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32, any_hit: bool) -> Hit {
    let none = Own(vec3<f32>(0.0), INVALID);
    return trace_between(o, dir, t_min, t_max, any_hit, Ends(none, none, vec2<f32>(-3.40282347e38, 3.40282347e38), vec2<f32>(0.0)));
}

// An end's own surface (pc_tree::between::Own): splats of `material` facing like `normal`.
struct Own {
    normal: vec3<f32>,
    material: u32,
}

// The surfaces a segment's ends ignore (pc_tree::between::Between): each end's own surface, and
// where the first end's own zone ends and the second's begins.
struct Ends {
    own0: Own,
    own1: Own,
    zones: vec2<f32>,
    _pad: vec2<f32>,
}

// Twin of pc_tree::between::OWN_COS.
const OWN_COS: f32 = 0.85;

// Twin of Own::is.
fn is_own(o: Own, s: Splat) -> bool {
    return dot(s.normal, o.normal) > OWN_COS && s.material == o.material;
}

// Twins of pc_tree::between::{OWN_HEIGHT, OWN_SLOPE, OWN_ROUGH, OWN_REACH}.
const OWN_HEIGHT: f32 = 1.0;
const OWN_SLOPE: f32 = 0.1;
const OWN_ROUGH: f32 = 5.0;
const OWN_REACH: f32 = 32.0;
// Where a first-hit ray leaving a splat starts, in its radii (twin of
// pc_tree::between::LEAVE_EPS).
const LEAVE_EPS: f32 = 1e-3;

// How far along a ray leaving a splat the splat's own zone reaches (twin of own_zone).
fn own_zone(radius: f32, rough: f32, cos_n: f32) -> f32 {
    let h = OWN_HEIGHT * radius + OWN_ROUGH * rough;
    let reach = OWN_REACH * h;
    let rise = cos_n - OWN_SLOPE;
    if rise * reach <= h {
        return reach;
    }
    return h / rise;
}

// The ends of a ray leaving splat s (on a leaf of roughness `rough`) along dir, the far end no
// surface (twin of Between::leaving).
fn leaving(s: Splat, rough: f32, dir: vec3<f32>) -> Ends {
    let none = Own(vec3<f32>(0.0), INVALID);
    return Ends(Own(s.normal, s.material), none, vec2<f32>(own_zone(s.radius, rough, dot(s.normal, dir)), 3.40282347e38), vec2<f32>(0.0));
}

// Whether a hit at t on splat s is an end's own surface (twin of Between::ignores).
fn ignored(e: Ends, t: f32, s: Splat) -> bool {
    return (t < e.zones.x && is_own(e.own0, s)) || (t > e.zones.y && is_own(e.own1, s));
}

// `trace`, passing over the hits `ignored` names. Twin of pc_tree::accel::Accel's walk with a
// Between (visible_between).
fn trace_between(o: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32, any_hit: bool, ends: Ends) -> Hit {
    var none = Hit(0.0, 0u, 0u, false);
    let qo = (o - octree_frame.origin) * octree_frame.inv_size;
    let qd = dir * octree_frame.inv_size + vec3<f32>(0.0);
    let inv = 1.0 / qd;
    let a = (vec3<f32>(0.0) - qo) * inv;
    let b = (vec3<f32>(1.0) - qo) * inv;
    let t0 = max(max(min(a.x, b.x), min(a.y, b.y)), min(a.z, b.z));
    let t1 = min(min(max(a.x, b.x), max(a.y, b.y)), max(a.z, b.z));
    if !(t0 <= t1) {
        return none;
    }
    let t_start = max(max(t0, t_min), 0.0);
    let t_end = min(t1, t_max);
    if t_start > t_end {
        return none;
    }
    let q = clamp(qo + qd * t_start, vec3<f32>(0.0), vec3<f32>(below(1.0)));
    var qi = min(vec3<u32>(q * f32(ROOT)), vec3<u32>(ROOT - 1u));
    var path: array<u32, 22>;
    path[0] = octree_nodes[0];
    var depth = 0u;
    for (var step = 0u; step < 1000000u; step = step + 1u) {
        var w = path[depth];
        loop {
            if (w & (NODE_LEAF | NODE_EMPTY)) != 0u || depth >= MAX_LEVELS {
                break;
            }
            let sh = MAX_LEVELS - 1u - depth;
            let bits = (qi >> vec3<u32>(sh)) & vec3<u32>(1u);
            w = octree_nodes[(w & NODE_PTR) + (bits.x | (bits.y << 1u) | (bits.z << 2u))];
            depth = depth + 1u;
            path[depth] = w;
        }
        let shift = MAX_LEVELS - depth;
        let lo_i = (qi >> vec3<u32>(shift)) << vec3<u32>(shift);
        let size_i = 1u << shift;
        let lo = vec3<f32>(lo_i) * CELL;
        let hi = vec3<f32>(lo_i + vec3<u32>(size_i)) * CELL;
        let far = select(lo, hi, qd >= vec3<f32>(0.0));
        let ta = (far - qo) * inv;
        let t_exit = min(min(ta.x, ta.y), ta.z);
        if (w & NODE_LEAF) != 0u {
            let limit = min(t_exit, t_end);
            let off = w & NODE_PTR;
            let begin = begin_end[off];
            let extra = begin_end[off + 1u];
            let end = begin_end[off + 2u + extra];
            var best = none;
            let count = (end - begin) + extra;
            for (var k = 0u; k < count; k = k + 1u) {
                var i = begin + k;
                if k >= end - begin {
                    i = begin_end[off + 2u + (k - (end - begin))];
                }
                let s = splats[i];
                let th = intersect_splat(o, dir, s);
                if th >= t_min && th <= limit && ignored(ends, th, s) {
                    continue;
                }
                if th >= t_min && th <= limit && (!best.found || th < best.t) && th >= 0.0 {
                    best = Hit(th, i, w, true);
                    if any_hit {
                        return best;
                    }
                }
            }
            if best.found {
                return best;
            }
        }
        if t_exit >= t_end {
            return none;
        }
        let next = qo + qd * t_exit;
        var ni = vec3<u32>(0u);
        for (var axis = 0u; axis < 3u; axis = axis + 1u) {
            if ta[axis] <= t_exit {
                if qd[axis] >= 0.0 {
                    if lo_i[axis] + size_i >= ROOT {
                        return none;
                    }
                    ni[axis] = lo_i[axis] + size_i;
                } else {
                    if lo_i[axis] == 0u {
                        return none;
                    }
                    ni[axis] = lo_i[axis] - 1u;
                }
            } else {
                let c = min(u32(max(next[axis], 0.0) * f32(ROOT)), ROOT - 1u);
                ni[axis] = clamp(c, lo_i[axis], lo_i[axis] + size_i - 1u);
            }
        }
        let diff = (qi.x ^ ni.x) | (qi.y ^ ni.y) | (qi.z ^ ni.z);
        depth = min(depth, countLeadingZeros(diff) - (32u - MAX_LEVELS));
        qi = ni;
    }
    return none;
}

fn occluded(o: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32) -> bool {
    return trace(o, dir, t_min, t_max, true).found;
}
