// requires: common/octree.wgsl common/traverse.wgsl common/optics.wgsl
// The final gather (docs/fmm.md, "Final gather"): one thread per splat to gather, which casts a
// stratified grid of cosine-distributed rays from its centre, each passing over its own rough
// surface within its own zone (`leaving`, common/traverse.wgsl), and averages the reflected
// radiance L − Lₑ of the splats they hit from the front.
// Line-by-line twin of pc_fmm::gather::gather_splat (crates/pc-fmm/src/gather.rs), from the same
// counter-based random numbers. Driven by pc_fmm::gather::GpuGather.

// This dispatch casts each splat's rays first .. first + rays of strata² (all of them on a
// hardware GPU; a few at a time on a software adapter, whose loops end after 65535 iterations
// per invocation group, all loops together: pc_fmm::gather::GpuGather), adding to the sums
// the dispatch before left in the slots; the last divides.
struct GatherParams {
    strata: u32,
    count: u32,
    first: u32,
    rays: u32,
}

// The splat to gather (written by the host) and its gathered light (written here).
struct GatherSlot {
    value: vec3<f32>,
    splat: u32,
}

// Twin of gather::SEED.
const GATHER_SEED: u32 = 0x67617468u;

@group(0) @binding(0) var<uniform> octree_frame: Frame;
@group(0) @binding(1) var<storage, read> octree_nodes: array<u32>;
@group(0) @binding(2) var<storage, read> begin_end: array<u32>;
@group(0) @binding(3) var<storage, read> splats: array<Splat>;
@group(0) @binding(4) var<storage, read> node_info: array<NodeInfo>;
@group(0) @binding(5) var<storage, read> splat_area: array<f32>;
@group(0) @binding(6) var<storage, read> splat_leaf: array<u32>;
// L − Lₑ of every splat (zero where a splat takes no part); w unused.
@group(0) @binding(7) var<storage, read> reflected: array<vec4<f32>>;
@group(0) @binding(8) var<uniform> params: GatherParams;
@group(0) @binding(9) var<storage, read_write> slots: array<GatherSlot>;
// Each octree leaf's roughness, per node-pool slot (pc_tree::between::leaf_roughness).
@group(0) @binding(10) var<storage, read> leaf_rough: array<f32>;

// Splat i's rays of this dispatch added to `sum` (its rays so far); over all of them, its mean.
fn gather(i: u32, sum_before: vec3<f32>) -> vec3<f32> {
    let s = splats[i];
    let n = s.normal;
    let rough = leaf_rough[splat_leaf[i]];
    let m = f32(params.strata);
    let count = params.strata * params.strata;
    let last = min(params.first + params.rays, count);
    var sum = sum_before;
    for (var k = params.first; k < last; k = k + 1u) {
        let u1 = (f32(k / params.strata) + rand4(GATHER_SEED, i, k, 0u)) / m;
        let u2 = (f32(k % params.strata) + rand4(GATHER_SEED, i, k, 1u)) / m;
        let dir = cosine_dir(n, u1, u2);
        let hit = trace_between(s.position, dir, LEAVE_EPS * s.radius, 3.40282347e38, false, leaving(s, rough, dir));
        if hit.found && dot(splats[hit.splat].normal, dir) < 0.0 {
            sum = sum + reflected[hit.splat].xyz;
        }
    }
    if last < count {
        return sum;
    }
    return sum / f32(max(count, 1u));
}

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let j = gid.x + gid.y * groups.x * 64u;
    if j >= params.count {
        return;
    }
    slots[j].value = gather(slots[j].splat, slots[j].value);
}
