// requires: fmm/basis.wgsl
// The FMM's transport operator on the GPU (docs/fmm.md): one application
// `out_i = Σ_tasks f K(i, j) A_j L_j` with Cartesian Taylor expansions of the form-factor
// tensor, in seven entry points dispatched in this order by crates/pc-fmm/src/gpu.rs:
//   p2m         one invocation per leaf: the multipole moments of its active splats (P2M);
//   m2m         one per internal node of one level, deepest level first: the moments of its
//               children shifted to its centre (M2M);
//   m2l         one per node item (a run of one compact node's tasks, crates/pc-fmm/src/
//               gpu_work.rs): M2L from nodes, P2L from splats, into the node's local
//               expansion (its first item) or a spare one (the others, in `spares`);
//   m2l_gather  one per node with spare expansions: adds them to its own, in order;
//   l2l         one per node of one level, root's children first: its parent's local
//               expansion re-expanded about its centre, added to its own (L2L);
//   splat       one per splat item (a run of one splat's tasks): L2P of its leaf's local
//               expansion (the splat's first item), then M2P and P2P tasks: a partial sum;
//   gather      one per splat: its partial sums added in order: the operator's output.
// CPU twin: crates/pc-fmm/src/cpu.rs (CpuFmm::upward / interact / downward), with the same
// floating-point operations in the same order per output value (up to the driver's fusing of
// multiply-adds) for a receiver whose tasks make one item; one cut into several items sums the
// same terms in parts. Every invocation writes only its own expansion or partial sum, so no
// atomics are needed.
//
// The loops over multi-indices and translation terms are generated, unrolled, by gpu.rs
// (`basis_wgsl`, composed in place of fmm/basis.wgsl): only loops over tasks, splats and
// children remain. llvmpipe ends every loop of an invocation group after 65535 iterations in
// all, so a kernel must not loop per coefficient; gpu.rs also checks the task loops against it.
//
// One coefficient of an expansion is a mat3x3: column c = colour c, rows = the 3 components
// of the vector charge (`[colour * 3 + component]` of pc_fmm::expansion::Coef, column-major).
// In storage, NP coefficients of 9 floats per compact node: `multipole[node * NP9 + α * 9 + k]`,
// same for `locals`.

const INV_PI: f32 = 0.31830988618379067;
// Flag of a node task's source that is a single splat (pc_fmm::plan::POINT).
const POINT: u32 = 0x80000000u;
// SplatTask kinds.
const KIND_M2P: u32 = 0u;
const KIND_P2P: u32 = 1u;
const KIND_P2P_RANGE: u32 = 2u;

// Flag of a node item's destination that is a spare expansion (pc_fmm::gpu_work::SPARE).
const SPARE: u32 = 0x80000000u;
// SplatItem flags (pc_fmm::gpu_work): the item starts with the L2P; its tasks are the leaf's
// first splat's, of which only the KIND_P2P_RANGE ones count.
const ITEM_L2P: u32 = 1u;
const ITEM_RANGE: u32 = 2u;

struct Params {
    // Invocations of this dispatch.
    count: u32,
    // Offset in `lists` of this dispatch's slot list (m2m, l2l), or its first item (m2l,
    // splat).
    first: u32,
    // Offsets in `lists` of its sections: leaf slots, compact-to-slot map, leaf slot per splat,
    // node items (5 u32: node, lo, hi, split, dst), node gathers (3 u32: node, lo, hi), splat
    // items (4 u32: splat, lo, hi, flags), splat item CSR offsets (splats + 1).
    leaves: u32,
    nodes: u32,
    splat_leaf: u32,
    node_items: u32,
    node_gathers: u32,
    splat_items: u32,
    splat_item_offsets: u32,
    // Splats: the partial sums follow their outputs in `out_field`.
    splats: u32,
    // The m2l and splat dispatches bind a window of their task array (node_tasks, splat_tasks)
    // starting at this record: task t is at t - task_base.
    task_base: u32,
    pad: u32,
}

// Per node-pool slot (pc_fmm::tree::Tree).
struct Node {
    center: vec3<f32>,
    // Compact expansion index, 0xffffffff for an empty slot.
    compact: u32,
    lo: u32,
    hi: u32,
    first_child: u32,
    parent: u32,
}

// pc_fmm::plan::NodeTask: M2L from node slot `src`, or P2L from splat `src & ~POINT`.
struct NodeTask {
    src: u32,
    fraction: f32,
}

// A pc_fmm::plan::LeafTask as its receiving splat sees it: M2P from node slot src_lo, P2P from
// splats [src_lo, src_hi) to this splat alone, or to every splat of the leaf (listed under the
// leaf's first splat).
struct SplatTask {
    src_lo: u32,
    src_hi: u32,
    fraction: f32,
    kind: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Splats in the normalised frame: xyz position, w area.
@group(0) @binding(1) var<storage, read> pos_area: array<vec4<f32>>;
// xyz normal, w 1 for an active splat, 0 for one outside the solve.
@group(0) @binding(2) var<storage, read> normal_active: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> tree_nodes: array<Node>;
// Level slot lists and the sections named in Params.
@group(0) @binding(4) var<storage, read> lists: array<u32>;
@group(0) @binding(5) var<storage, read> node_tasks: array<NodeTask>;
@group(0) @binding(6) var<storage, read> splat_tasks: array<SplatTask>;
// RGB radiance per splat, 3 floats.
@group(0) @binding(7) var<storage, read> radiance: array<f32>;
@group(0) @binding(8) var<storage, read_write> multipole: array<f32>;
@group(0) @binding(9) var<storage, read_write> locals: array<f32>;
// The operator's output per splat, 3 floats, then the partial sum of every splat item.
@group(0) @binding(10) var<storage, read_write> out_field: array<f32>;
// The spare local expansions of nodes whose tasks were cut into several items (NP9 floats
// each).
@group(0) @binding(11) var<storage, read_write> spares: array<f32>;

// Per-invocation scratch of the generated code (zero at the start of every invocation):
// monomials, kernel coefficients a_γ and g_γ (a symmetric matrix each), and the expansion
// being accumulated.
var<private> pw: array<f32, NP>;
var<private> ka: array<f32, NP>;
var<private> kg: array<mat3x3<f32>, NP>;
var<private> ex: array<mat3x3<f32>, NP>;

fn invocation(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.x + gid.y * groups.x * 64u;
}

fn load_multipole(at: u32) -> mat3x3<f32> {
    return mat3x3<f32>(
        multipole[at], multipole[at + 1u], multipole[at + 2u],
        multipole[at + 3u], multipole[at + 4u], multipole[at + 5u],
        multipole[at + 6u], multipole[at + 7u], multipole[at + 8u],
    );
}

fn load_local(at: u32) -> mat3x3<f32> {
    return mat3x3<f32>(
        locals[at], locals[at + 1u], locals[at + 2u],
        locals[at + 3u], locals[at + 4u], locals[at + 5u],
        locals[at + 6u], locals[at + 7u], locals[at + 8u],
    );
}

fn store_multipole(at: u32, m: mat3x3<f32>) {
    multipole[at] = m[0].x;
    multipole[at + 1u] = m[0].y;
    multipole[at + 2u] = m[0].z;
    multipole[at + 3u] = m[1].x;
    multipole[at + 4u] = m[1].y;
    multipole[at + 5u] = m[1].z;
    multipole[at + 6u] = m[2].x;
    multipole[at + 7u] = m[2].y;
    multipole[at + 8u] = m[2].z;
}

fn load_spare(at: u32) -> mat3x3<f32> {
    return mat3x3<f32>(
        spares[at], spares[at + 1u], spares[at + 2u],
        spares[at + 3u], spares[at + 4u], spares[at + 5u],
        spares[at + 6u], spares[at + 7u], spares[at + 8u],
    );
}

fn store_spare(at: u32, m: mat3x3<f32>) {
    spares[at] = m[0].x;
    spares[at + 1u] = m[0].y;
    spares[at + 2u] = m[0].z;
    spares[at + 3u] = m[1].x;
    spares[at + 4u] = m[1].y;
    spares[at + 5u] = m[1].z;
    spares[at + 6u] = m[2].x;
    spares[at + 7u] = m[2].y;
    spares[at + 8u] = m[2].z;
}

fn store_local(at: u32, m: mat3x3<f32>) {
    locals[at] = m[0].x;
    locals[at + 1u] = m[0].y;
    locals[at + 2u] = m[0].z;
    locals[at + 3u] = m[1].x;
    locals[at + 4u] = m[1].y;
    locals[at + 5u] = m[1].z;
    locals[at + 6u] = m[2].x;
    locals[at + 7u] = m[2].y;
    locals[at + 8u] = m[2].z;
}

// The symmetric tensor (xx, xy, xz, yy, yz, zz) as a matrix.
fn sym(g0: f32, g1: f32, g2: f32, g3: f32, g4: f32, g5: f32) -> mat3x3<f32> {
    return mat3x3<f32>(g0, g1, g2, g1, g3, g4, g2, g4, g5);
}

fn is_active(j: u32) -> bool {
    return normal_active[j].w != 0.0;
}

// w_j = A_j L_j (zero for an inactive splat), cpu::weights.
fn weight(j: u32) -> vec3<f32> {
    if !is_active(j) {
        return vec3<f32>(0.0);
    }
    let a = pos_area[j].w;
    return vec3<f32>(a * radiance[j * 3u], a * radiance[j * 3u + 1u], a * radiance[j * 3u + 2u]);
}

// q_j = n_j w_j (column c = n_j w_c), cpu::charges.
fn charge(j: u32) -> mat3x3<f32> {
    let w = weight(j);
    let n = normal_active[j].xyz;
    return mat3x3<f32>(n * w.x, n * w.y, n * w.z);
}

const PI: f32 = 3.14159265358979323846;

// Near-field kernel of P2P, cpu::kernel_near: the form factor of source disk j (area a_j) seen
// from point i per unit source area, cos θ_i cos θ_j / (π r² + a_j) / r².
fn kernel_near(xi: vec3<f32>, ni: vec3<f32>, xj: vec3<f32>, nj: vec3<f32>, aj: f32) -> f32 {
    let d = xj - xi;
    let ci = ni.x * d.x + ni.y * d.y + ni.z * d.z;
    let cj = -(nj.x * d.x + nj.y * d.y + nj.z * d.z);
    if ci <= 0.0 || cj <= 0.0 {
        return 0.0;
    }
    let r2 = d.x * d.x + d.y * d.y + d.z * d.z;
    return ci * cj / (r2 * (PI * r2 + aj));
}

// n · F per colour of a field F (columns = colours).
fn project(n: vec3<f32>, f: mat3x3<f32>) -> vec3<f32> {
    return vec3<f32>(
        n.x * f[0].x + n.y * f[0].y + n.z * f[0].z,
        n.x * f[1].x + n.y * f[1].y + n.z * f[1].z,
        n.x * f[2].x + n.y * f[2].y + n.z * f[2].z,
    );
}

// P2M: the moments of one leaf's active splats about its centre (CpuFmm::upward, first part).
@compute @workgroup_size(64)
fn p2m(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let li = invocation(gid, groups);
    if li >= params.count {
        return;
    }
    let nd = tree_nodes[lists[params.leaves + li]];
    for (var j = nd.lo; j < nd.hi; j = j + 1u) {
        if is_active(j) {
            let q = charge(j);
            gen_monomials(pos_area[j].xyz - nd.center);
            gen_p2m(q);
        }
    }
    gen_store_multipole(nd.compact * NP9);
}

// M2M: the moments of one internal node from its non-empty children's (CpuFmm::upward, per
// level). The slot list holds the level's internal nodes only.
@compute @workgroup_size(64)
fn m2m(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = invocation(gid, groups);
    if i >= params.count {
        return;
    }
    let nd = tree_nodes[lists[params.first + i]];
    for (var c = 0u; c < 8u; c = c + 1u) {
        let child = tree_nodes[nd.first_child + c];
        if child.hi > child.lo {
            gen_monomials(child.center - nd.center);
            gen_m2m(child.compact * NP9);
        }
    }
    gen_store_multipole(nd.compact * NP9);
}

// M2L and P2L: one node item's part of a compact node's local expansion (CpuFmm::interact):
// its M2L tasks (slots, below `split`) then its P2L tasks (splats, POINT set), into the
// node's own expansion (zero for a node without tasks) or a spare one.
@compute @workgroup_size(64)
fn m2l(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let inv = invocation(gid, groups);
    if inv >= params.count {
        return;
    }
    let at = params.node_items + (params.first + inv) * 5u;
    let ci = lists[at];
    let lo = lists[at + 1u];
    let hi = lists[at + 2u];
    let split = lists[at + 3u];
    let ca = tree_nodes[lists[params.nodes + ci]].center;
    for (var t = lo; t < split; t = t + 1u) {
        let task = node_tasks[t - params.task_base];
        let src = tree_nodes[task.src];
        gen_kernel_coeffs(src.center - ca);
        gen_m2l(src.compact * NP9, task.fraction);
    }
    for (var t = split; t < hi; t = t + 1u) {
        let task = node_tasks[t - params.task_base];
        let j = task.src & ~POINT;
        gen_kernel_coeffs(pos_area[j].xyz - ca);
        gen_p2l(charge(j), task.fraction);
    }
    let dst = lists[at + 4u];
    if (dst & SPARE) != 0u {
        gen_store_spare((dst & ~SPARE) * NP9);
    } else {
        gen_store_locals(dst * NP9);
    }
}

// A node whose tasks were cut into several items: its spare expansions added to its own, in
// item order.
@compute @workgroup_size(64)
fn m2l_gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = invocation(gid, groups);
    if k >= params.count {
        return;
    }
    let at = params.node_gathers + k * 3u;
    let ci = lists[at];
    gen_load_locals(ci * NP9);
    for (var e = lists[at + 1u]; e < lists[at + 2u]; e = e + 1u) {
        gen_add_spare(e * NP9);
    }
    gen_store_locals(ci * NP9);
}

// L2L: add the parent's local expansion, re-expanded about this node's centre, to this node's
// (CpuFmm::downward, per level below the root).
@compute @workgroup_size(64)
fn l2l(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = invocation(gid, groups);
    if i >= params.count {
        return;
    }
    let nd = tree_nodes[lists[params.first + i]];
    let parent = tree_nodes[nd.parent];
    gen_load_locals(nd.compact * NP9);
    gen_monomials(nd.center - parent.center);
    gen_l2l(parent.compact * NP9);
    gen_store_locals(nd.compact * NP9);
}

// P2P of one task to splat i: fraction · Σ_{j ≠ i, active} K_near(i, j) w_j.
fn p2p_row(i: u32, task: SplatTask) -> vec3<f32> {
    let xi = pos_area[i].xyz;
    let ni = normal_active[i].xyz;
    var a = vec3<f32>(0.0);
    for (var j = task.src_lo; j < task.src_hi; j = j + 1u) {
        if j != i && is_active(j) {
            let pj = pos_area[j];
            let k = kernel_near(xi, ni, pj.xyz, normal_active[j].xyz, pj.w);
            if k > 0.0 {
                a += k * weight(j);
            }
        }
    }
    return task.fraction * a;
}

// One splat item, part of a splat's leaf phase (CpuFmm::downward, second part): the L2P of
// its leaf's local expansion when it is the splat's first item, then its tasks in the plan's
// order: the P2P tasks to the whole leaf (listed under the leaf's first splat, ITEM_RANGE) or
// the splat's own M2P and P2P tasks. Writes the item's partial sum.
@compute @workgroup_size(64)
fn splat(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let inv = invocation(gid, groups);
    if inv >= params.count {
        return;
    }
    let k = params.first + inv;
    let at = params.splat_items + k * 4u;
    let i = lists[at];
    let lo = lists[at + 1u];
    let hi = lists[at + 2u];
    let flags = lists[at + 3u];
    let xi = pos_area[i].xyz;
    let ni = normal_active[i].xyz;
    var v = vec3<f32>(0.0);
    if (flags & ITEM_L2P) != 0u {
        let nd = tree_nodes[lists[params.splat_leaf + i]];
        gen_monomials(xi - nd.center);
        v = -INV_PI * project(ni, gen_l2p(nd.compact * NP9));
    }
    if (flags & ITEM_RANGE) != 0u {
        for (var t = lo; t < hi; t = t + 1u) {
            let task = splat_tasks[t - params.task_base];
            if task.kind == KIND_P2P_RANGE {
                v += p2p_row(i, task);
            }
        }
    } else {
        for (var t = lo; t < hi; t = t + 1u) {
            let task = splat_tasks[t - params.task_base];
            if task.kind == KIND_M2P {
                let src = tree_nodes[task.src_lo];
                gen_kernel_coeffs(src.center - xi);
                let f = project(ni, gen_m2p(src.compact * NP9));
                v -= task.fraction * INV_PI * f;
            } else {
                v += p2p_row(i, task);
            }
        }
    }
    let o = (params.splats + k) * 3u;
    out_field[o] = v.x;
    out_field[o + 1u] = v.y;
    out_field[o + 2u] = v.z;
}

// One splat's output: its items' partial sums added in order (zero for an inactive splat,
// which has none).
@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = invocation(gid, groups);
    if i >= params.count {
        return;
    }
    var v = vec3<f32>(0.0);
    let hi = lists[params.splat_item_offsets + i + 1u];
    for (var k = lists[params.splat_item_offsets + i]; k < hi; k = k + 1u) {
        let o = (params.splats + k) * 3u;
        v += vec3<f32>(out_field[o], out_field[o + 1u], out_field[o + 2u]);
    }
    out_field[i * 3u] = v.x;
    out_field[i * 3u + 1u] = v.y;
    out_field[i * 3u + 2u] = v.z;
}
