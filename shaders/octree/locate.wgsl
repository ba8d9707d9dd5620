// requires: common/octree.wgsl
// Point location kernel: one thread per query point, writes (slot, node word, depth).
// CPU twin: pc_tree::OctreeView::locate. Driven by crates/pc-octree/src/gpu/locate.rs.

@group(0) @binding(0) var<uniform> octree_frame: Frame;
@group(0) @binding(1) var<storage, read> octree_nodes: array<u32>;
@group(0) @binding(2) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> results: array<vec4<u32>>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * 64u;
    if i >= arrayLength(&queries) {
        return;
    }
    let r = octree_locate(queries[i].xyz);
    results[i] = vec4<u32>(r.slot, r.node, r.depth, 0u);
}
