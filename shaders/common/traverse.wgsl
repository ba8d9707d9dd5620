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

// Words of a node-pool slot's slab past the pool in `octree_nodes` (twin of
// pc_tree::accel::POOL_SLAB_WORDS): axis xyz, lo, hi as bits, and 1 where the walk tests it.
const SLAB_WORDS: u32 = 6u;

struct SlabEntry {
    t: f32,
    meets: bool,
}

// Where the stretch [t_min, limit] of the ray enters the slab of the words at `at`, and whether
// it meets it (twin of pc_tree::ray::Slab::entry). A ray parallel to the slab meets it where
// its origin lies in it, from t_min on.
fn slab_entry(at: u32, o: vec3<f32>, dir: vec3<f32>, t_min: f32, limit: f32) -> SlabEntry {
    let axis = bitcast<vec3<f32>>(vec3<u32>(octree_nodes[at], octree_nodes[at + 1u], octree_nodes[at + 2u]));
    let lo = bitcast<f32>(octree_nodes[at + 3u]);
    let hi = bitcast<f32>(octree_nodes[at + 4u]);
    let s0 = dot(axis, o);
    let ds = dot(axis, dir);
    if ds == 0.0 {
        return SlabEntry(t_min, s0 >= lo && s0 <= hi);
    }
    let ta = (lo - s0) / ds;
    let tb = (hi - s0) / ds;
    let enter = max(min(ta, tb), t_min);
    let leave = min(max(ta, tb), limit);
    return SlabEntry(enter, enter <= leave);
}

// `trace`, passing over the hits `ignored` names. Twin of pc_tree::accel::Accel's walk with a
// Between (visible_between), and like it, by the slabs of pc_tree::accel::Accel::pool_slabs
// that follow the pool in `octree_nodes` (every walk kernel's upload has them): where the ray's
// stretch from t_min to the exit of a node's cell misses the node's slab, the node is passed
// whole; where it meets it, the walk jumps to where it enters the slab; a leaf whose slab the
// stretch misses is not tested (pc_tree::ray::walk_with). No disk below a node lies outside its
// slab, and the slabs are padded far above the rounding, so the hits are the walk's without
// them.
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
    // The pool (node_count words, as the upload sets it), then SLAB_WORDS a slot.
    let slabs = octree_frame.node_count;
    let q = clamp(qo + qd * t_start, vec3<f32>(0.0), vec3<f32>(below(1.0)));
    var qi = min(vec3<u32>(q * f32(ROOT)), vec3<u32>(ROOT - 1u));
    // The node words from the root to the current cell.
    var path: array<u32, 22>;
    path[0] = octree_nodes[0];
    var depth = 0u;
    // The ray's parameter at qi: where it entered qi's cell, or the slab it jumped to.
    var t_at = t_start;
    for (var step = 0u; step < 1000000u; step = step + 1u) {
        var w = path[depth];
        // The pool slot of w: the root's, or its parent's pointer and qi's child bits there.
        var slot = 0u;
        if depth > 0u {
            let up = (qi >> vec3<u32>(MAX_LEVELS - depth)) & vec3<u32>(1u);
            slot = (path[depth - 1u] & NODE_PTR) + (up.x | (up.y << 1u) | (up.z << 2u));
        }
        loop {
            if (w & (NODE_LEAF | NODE_EMPTY)) != 0u || depth >= MAX_LEVELS {
                break;
            }
            let at = slabs + SLAB_WORDS * slot;
            if octree_nodes[at + 5u] != 0u {
                let sh0 = MAX_LEVELS - depth;
                let lo0 = (qi >> vec3<u32>(sh0)) << vec3<u32>(sh0);
                let size0 = 1u << sh0;
                let far0 = select(vec3<f32>(lo0) * CELL, vec3<f32>(lo0 + vec3<u32>(size0)) * CELL, qd >= vec3<f32>(0.0));
                let ta0 = (far0 - qo) * inv;
                let e = slab_entry(at, o, dir, t_min, min(min(min(ta0.x, ta0.y), ta0.z), t_end));
                if !e.meets {
                    // No leaf below can accept a hit: pass the node whole.
                    break;
                }
                if e.t > t_at {
                    // Straight to the cell where the ray enters the slab, within the node.
                    let qe = qo + qd * e.t;
                    qi = clamp(min(vec3<u32>(max(qe, vec3<f32>(0.0)) * f32(ROOT)), vec3<u32>(ROOT - 1u)), lo0, lo0 + vec3<u32>(size0 - 1u));
                    t_at = e.t;
                }
            }
            let sh = MAX_LEVELS - 1u - depth;
            let bits = (qi >> vec3<u32>(sh)) & vec3<u32>(1u);
            slot = (w & NODE_PTR) + (bits.x | (bits.y << 1u) | (bits.z << 2u));
            w = octree_nodes[slot];
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
        let at = slabs + SLAB_WORDS * slot;
        let limit = min(t_exit, t_end);
        if (w & NODE_LEAF) != 0u && (octree_nodes[at + 5u] == 0u || slab_entry(at, o, dir, t_min, limit).meets) {
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
        // Not below a jump's parameter: a jump can land one cell short of its point.
        t_at = max(t_at, t_exit);
    }
    return none;
}

fn occluded(o: vec3<f32>, dir: vec3<f32>, t_min: f32, t_max: f32) -> bool {
    return trace(o, dir, t_min, t_max, true).found;
}
