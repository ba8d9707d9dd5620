// requires: common/octree.wgsl common/traverse.wgsl
// Ray casting kernel: the nearest splat hit of each ray in a buffer (or any hit, for
// visibility). Used by the renderer's benchmark and by the V-map's visibility rays.
// CPU twin: pc_tree::OctreeView::intersect / occluded. Driven by crates/pc-tree/src/gpu.rs.

// With the surfaces its ends ignore (pc_tree::gpu::RayIn, pc_tree::between; a plain ray: none).
struct RayIn {
    origin: vec3<f32>,
    t_min: f32,
    dir: vec3<f32>,
    t_max: f32,
    ends: Ends,
}

struct CastParams {
    count: u32,
    any_hit: u32,
    _pad: vec2<u32>,
}

@group(0) @binding(0) var<uniform> octree_frame: Frame;
@group(0) @binding(1) var<storage, read> octree_nodes: array<u32>;
@group(0) @binding(2) var<storage, read> begin_end: array<u32>;
@group(0) @binding(3) var<storage, read> splats: array<Splat>;
@group(0) @binding(4) var<storage, read> rays: array<RayIn>;
@group(0) @binding(5) var<uniform> cast_params: CastParams;
// x = bits of t, y = data-pool index of the splat hit or INVALID.
@group(0) @binding(6) var<storage, read_write> hits: array<vec2<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * 64u;
    if i >= cast_params.count {
        return;
    }
    let r = rays[i];
    let h = trace_between(r.origin, r.dir, r.t_min, r.t_max, cast_params.any_hit != 0u, r.ends);
    if h.found {
        hits[i] = vec2<u32>(bitcast<u32>(h.t), h.splat);
    } else {
        hits[i] = vec2<u32>(0u, INVALID);
    }
}
