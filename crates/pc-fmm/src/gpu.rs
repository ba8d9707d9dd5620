//! The GPU operator: the FMM of [`crate::cpu`] as WGSL compute shaders (shaders/fmm/fmm.wgsl),
//! the same phases with the same floating-point operations in the same order per output value
//! (up to the driver's fusing of multiply-adds), so the two agree to f32 rounding:
//!
//! P2M (one invocation per leaf) → M2M (per internal node, one dispatch per level, deepest
//! first) → M2L + P2L (per node item, [`crate::gpu_work`]) → the cut nodes' parts added → L2L
//! (per node, one dispatch per level, root's children first) → L2P + M2P + P2P (per splat
//! item) → the items' partial sums added (per splat).
//!
//! [`GpuFmm::new`] uploads the static data once (splats, per-slot tree records, level lists, the
//! interaction plan regrouped by receiving splat and cut into work items of bounded cost) and
//! compiles the kernels for the basis's order. Every loop over multi-indices or translation terms is written out term by term from
//! the [`Basis`] tables ([`basis_wgsl`] in [`crate::gpu_wgsl`], composed in place of shaders/fmm/basis.wgsl): the
//! expansions then live in registers with constant indices, and only loops over tasks remain —
//! which matters on llvmpipe, whose shaders stop after 65535 loop iterations per invocation
//! group, all loops together (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`), silently. The work items
//! keep the task loops well within that budget; on a software adapter [`GpuFmm::new`] still
//! bounds them ([`Work::loop_bounds`]) and refuses a plan that could exceed it (a
//! leaf of more than 8191 splats, say). Each application then uploads the radiance, runs the dispatches
//! and reads the output back.
//!
//! Limits: each expansion buffer (`nodes × coefficients × 36` bytes) and every other array must
//! fit one storage binding (128 MiB on llvmpipe); [`GpuFmm::new`] says which does not, and the
//! stage's `auto` backend then solves on the CPU.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use pc_gpu::{grid, Bind, Binding, Buffer, GpuContext};

use crate::cpu::PhaseTimes;
use crate::error::FmmError;
use crate::expansion::Basis;
pub use crate::gpu_wgsl::{basis_wgsl, source};
use crate::gpu_work::{self, Work};
use crate::plan::{NodeTask, Plan};
use crate::tree::{Points, Tree, NONE};

/// The kernels' file (entry points `p2m`, `m2m`, `m2l`, `l2l`, `splat`), below `shaders/`.
pub const FMM_WGSL: &str = "fmm/fmm.wgsl";
/// The stand-in for [`basis_wgsl`] (order 4, empty bodies) that lets fmm.wgsl validate alone.
pub const BASIS_STUB_WGSL: &str = "fmm/basis.wgsl";

/// Threads per workgroup of every entry point (`@workgroup_size(64)`).
const GROUP: u32 = 64;
/// Storage buffers the kernels bind.
const STORAGE_BINDINGS: u32 = 11;
/// Bindings of the task arrays, bound in windows (fmm.wgsl `node_tasks`, `splat_tasks`).
const NODE_TASKS: usize = 5;
const SPLAT_TASKS: usize = 6;
/// Highest order the kernels are generated for: the M2L code grows as the number of terms,
/// (p+1)…(p+6)/720 (3003 at order 8), and so do compile time and register pressure.
pub const MAX_ORDER: usize = 8;
/// llvmpipe's budget of loop iterations per shader invocation group (all loops together), and
/// the lanes of a group (256-bit vectors of f32).
const SOFTWARE_LOOP_LIMIT: u64 = 65535;
const SOFTWARE_LANES: usize = 8;

/// Per node-pool slot record (WGSL `Node`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuNode {
    pub center: [f32; 3],
    pub compact: u32,
    pub lo: u32,
    pub hi: u32,
    pub first_child: u32,
    pub parent: u32,
}

/// Per-dispatch uniform (WGSL `Params`): the invocation count, this dispatch's slot list and
/// the offsets of the sections of the `lists` buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuParams {
    pub count: u32,
    pub first: u32,
    pub leaves: u32,
    pub nodes: u32,
    pub splat_leaf: u32,
    pub node_items: u32,
    pub node_gathers: u32,
    pub splat_items: u32,
    pub splat_item_offsets: u32,
    pub splats: u32,
    /// First task record of the bound window of the task array (m2l, splat).
    pub task_base: u32,
    pub pad: u32,
}

/// Errs when a kernel may loop more often per invocation group than `adapter` (a software
/// one) allows.
fn check_loop_bounds(adapter: &str, bounds: &[(&'static str, u64)]) -> Result<(), FmmError> {
    match bounds.iter().find(|b| b.1 > SOFTWARE_LOOP_LIMIT) {
        Some((kernel, bound)) => Err(FmmError::GpuPlan(format!(
            "{adapter} ends a shader's loops after {SOFTWARE_LOOP_LIMIT} iterations per invocation group, and this plan may need {bound} in the {kernel} kernel"
        ))),
        None => Ok(()),
    }
}

/// The entry points, in the order of [`Phase`].
const ENTRIES: [&str; 7] = ["p2m", "m2m", "m2l", "m2l_gather", "l2l", "splat", "gather"];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    P2m = 0,
    M2m = 1,
    M2l = 2,
    M2lGather = 3,
    L2l = 4,
    Splat = 5,
    Gather = 6,
}

/// The FMM on the GPU: static data resident, kernels compiled for one order.
pub struct GpuFmm {
    describe: String,
    /// Dispatches per application.
    pub dispatches: usize,
    pub applications: u32,
    /// Accumulated seconds per phase (the upload with the upward pass, the readback with the
    /// downward one; each dispatch waits for the device, so these are device times on llvmpipe
    /// and close to them elsewhere).
    pub times: PhaseTimes,
    /// [`Work::loop_bounds`] of the plan on llvmpipe's groups: the most loop iterations of one
    /// invocation group per kernel.
    pub loop_bounds: Vec<(&'static str, u64)>,
    /// Work items: splat items (active splats), node items (compact nodes), spare expansions.
    pub items: (usize, usize, u32),
    /// The configured expansion order; relaxed products run kernels compiled for lower ones
    /// (at first use), as the CPU's do ([`crate::cpu::order_within`]).
    order: u32,
    theta: f32,
    /// The context, buffers, kernels and dispatches that run one application.
    device: Device,
}

/// Bytes of a slice, for size checks.
fn bytes<T>(v: &[T]) -> u64 {
    std::mem::size_of_val(v) as u64
}

impl GpuFmm {
    pub fn new(
        ctx: GpuContext,
        basis: &Basis,
        tree: &Tree,
        points: &Points,
        plan: &Plan,
    ) -> Result<GpuFmm, FmmError> {
        let window = ctx.binding_limit();
        GpuFmm::with_task_window(ctx, basis, tree, points, plan, window)
    }

    /// [`GpuFmm::new`] binding the task arrays in windows of at most `window` bytes (the
    /// device's binding limit there; tests make it small to run the windowed dispatches).
    pub fn with_task_window(
        ctx: GpuContext,
        basis: &Basis,
        tree: &Tree,
        points: &Points,
        plan: &Plan,
        window: u64,
    ) -> Result<GpuFmm, FmmError> {
        let binding_limit = check_device(&ctx, basis, tree, plan)?;
        let work = Work::new(tree, points, plan)?;
        let loop_bounds = work.loop_bounds(tree, SOFTWARE_LANES);
        if ctx.is_software() {
            check_loop_bounds(&ctx.info.name, &loop_bounds)?;
        }
        let host = HostData::new(basis, tree, points, &work);
        host.check_sizes(binding_limit)?;
        let buffers = Buffers::new(&ctx, &host, plan, &work)?;
        // The task arrays may exceed one binding: their dispatches bind them in windows.
        let align = ctx.device.limits().min_storage_buffer_offset_alignment as u64;
        let task_windows = |spans: &mut dyn Iterator<Item = (u32, u32)>,
                            total: usize,
                            record: usize|
         -> Result<Vec<gpu_work::Window>, FmmError> {
            let record = record as u64;
            let max = (window.min(binding_limit) / record).min(u32::MAX as u64) as u32;
            gpu_work::windows(spans, total as u32, max, align.div_ceil(record) as u32)
        };
        let node_windows = task_windows(
            &mut work.node_items.iter().map(|t| (t.lo, t.hi)),
            plan.node_tasks.len(),
            std::mem::size_of::<NodeTask>(),
        )?;
        let splat_windows = task_windows(
            &mut work.splat_items.iter().map(|t| (t.lo, t.hi)),
            work.splat_tasks.len(),
            std::mem::size_of::<gpu_work::SplatTask>(),
        )?;
        let steps = dispatch_steps(&ctx, &host, tree, &work, &node_windows, &splat_windows);
        let mut kernels: Vec<Option<Vec<pc_gpu::Kernel>>> =
            (0..=basis.order).map(|_| None).collect();
        kernels[basis.order] = Some(compile(&ctx, basis.order)?);
        Ok(GpuFmm {
            describe: ctx.describe(),
            dispatches: steps.len(),
            applications: 0,
            times: PhaseTimes::default(),
            loop_bounds,
            items: (work.splat_items.len(), work.node_items.len(), work.spares),
            order: basis.order as u32,
            theta: plan.theta,
            device: Device {
                task_arrays: [
                    (
                        NODE_TASKS,
                        std::mem::size_of::<NodeTask>() as u64,
                        plan.node_tasks.len() as u64,
                    ),
                    (
                        SPLAT_TASKS,
                        std::mem::size_of::<gpu_work::SplatTask>() as u64,
                        work.splat_tasks.len() as u64,
                    ),
                ],
                splats: host.splats,
                field_bytes: host.field_bytes,
                ctx,
                kernels,
                buffers,
                steps,
            },
        })
    }
}

/// What the device must allow before anything is uploaded: the order the kernels are generated
/// for, the storage buffers they bind, the expansions in one binding, a plan of this tree.
/// Returns the storage binding limit.
fn check_device(
    ctx: &GpuContext,
    basis: &Basis,
    tree: &Tree,
    plan: &Plan,
) -> Result<u64, FmmError> {
    if basis.order > MAX_ORDER {
        return Err(FmmError::GpuPlan(format!(
            "the kernels are generated up to order {MAX_ORDER}, not {}",
            basis.order
        )));
    }
    let limits = ctx.device.limits();
    if limits.max_storage_buffers_per_shader_stage < STORAGE_BINDINGS {
        return Err(FmmError::GpuPlan(format!(
            "the kernels bind {STORAGE_BINDINGS} storage buffers, the device allows {} per shader stage",
            limits.max_storage_buffers_per_shader_stage
        )));
    }
    let binding_limit = limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size);
    let nodes = tree.nodes.len();
    let expansion_bytes = expansion_bytes(basis, tree);
    if expansion_bytes > binding_limit {
        return Err(FmmError::GpuPlan(format!(
            "the expansions of {nodes} nodes at order {} ({} coefficients × 9 floats) need {expansion_bytes} bytes per buffer, over the device's storage binding limit of {binding_limit} bytes",
            basis.order,
            basis.len()
        )));
    }
    if plan.node_offsets.len() != nodes + 1
        || plan.leaf_offsets.len() != tree.leaves.len() + 1
        || plan
            .node_offsets
            .last()
            .is_some_and(|&e| e as usize != plan.node_tasks.len())
        || plan
            .leaf_offsets
            .last()
            .is_some_and(|&e| e as usize != plan.leaf_tasks.len())
    {
        return Err(FmmError::GpuPlan("the plan does not fit the tree".into()));
    }
    Ok(binding_limit)
}

/// Bytes of one expansion buffer: every compact node's coefficients, 9 floats each.
fn expansion_bytes(basis: &Basis, tree: &Tree) -> u64 {
    (tree.nodes.len() * basis.len() * 9 * 4) as u64
}

/// The static data as the kernels read it, built on the host.
struct HostData {
    /// Splats: position and area, normal and whether active (WGSL `vec4`s).
    pos_area: Vec<[f32; 4]>,
    normal_active: Vec<[f32; 4]>,
    /// Per node-pool slot records.
    slots: Vec<GpuNode>,
    /// The M2M slot list of every level (internal nodes only), the L2L list of every level
    /// below the root, then the sections `base` points at.
    lists: Vec<u32>,
    /// `(first, count)` in `lists` of each level's M2M dispatch (deepest first) and L2L one.
    m2m_levels: Vec<(u32, u32)>,
    l2l_levels: Vec<(u32, u32)>,
    /// The uniform every dispatch starts from.
    base: GpuParams,
    splats: usize,
    expansion_bytes: u64,
    /// The outputs (12 bytes a splat).
    field_bytes: u64,
    /// The outputs, then the splat items' partial sums.
    out_bytes: u64,
    /// The spare expansions of cut nodes.
    spare_bytes: u64,
}

impl HostData {
    fn new(basis: &Basis, tree: &Tree, points: &Points, work: &Work) -> HostData {
        let n = points.pos.len();
        let pos_area = (0..n)
            .map(|i| {
                let p = points.pos[i];
                [p[0], p[1], p[2], points.area[i]]
            })
            .collect();
        let normal_active = (0..n)
            .map(|i| {
                let m = points.normal[i];
                [m[0], m[1], m[2], if points.active[i] { 1.0 } else { 0.0 }]
            })
            .collect();
        let slots = (0..tree.slots)
            .map(|s| GpuNode {
                center: tree.center[s],
                compact: tree.compact[s],
                lo: tree.lo[s],
                hi: tree.hi[s],
                first_child: tree.first_child[s],
                parent: tree.parent[s],
            })
            .collect();
        let mut lists: Vec<u32> = Vec::new();
        let mut m2m_levels = Vec::new();
        for level in tree.levels.iter().rev() {
            let first = lists.len() as u32;
            lists.extend(
                level
                    .iter()
                    .copied()
                    .filter(|&s| tree.first_child[s as usize] != NONE),
            );
            let count = lists.len() as u32 - first;
            if count > 0 {
                m2m_levels.push((first, count));
            }
        }
        let mut l2l_levels = Vec::new();
        for level in tree.levels.iter().skip(1) {
            if !level.is_empty() {
                l2l_levels.push((lists.len() as u32, level.len() as u32));
                lists.extend_from_slice(level);
            }
        }
        let mut section = |v: &[u32]| {
            let at = lists.len() as u32;
            lists.extend_from_slice(v);
            at
        };
        let base = GpuParams {
            leaves: section(&tree.leaves),
            nodes: section(&tree.nodes),
            splat_leaf: section(&points.leaf),
            node_items: section(bytemuck::cast_slice(&work.node_items)),
            node_gathers: section(bytemuck::cast_slice(&work.node_gathers)),
            splat_items: section(bytemuck::cast_slice(&work.splat_items)),
            splat_item_offsets: section(&work.splat_item_offsets),
            splats: n as u32,
            ..Default::default()
        };
        let field_bytes = (n * 12) as u64;
        HostData {
            pos_area,
            normal_active,
            slots,
            lists,
            m2m_levels,
            l2l_levels,
            base,
            splats: n,
            expansion_bytes: expansion_bytes(basis, tree),
            field_bytes,
            out_bytes: field_bytes + 12 * work.splat_items.len() as u64,
            spare_bytes: (work.spares as usize * basis.len() * 9 * 4) as u64,
        }
    }

    /// Every array fits one storage binding; the error says which does not.
    fn check_sizes(&self, binding_limit: u64) -> Result<(), FmmError> {
        for (what, size) in [
            ("splat positions", bytes(&self.pos_area)),
            ("splat normals", bytes(&self.normal_active)),
            ("tree nodes", bytes(&self.slots)),
            ("tree lists", bytes(&self.lists)),
            ("spare local expansions", self.spare_bytes),
            ("outputs with the partial sums", self.out_bytes),
        ] {
            if size > binding_limit {
                return Err(FmmError::GpuPlan(format!(
                    "the {what} need {size} bytes, over the device's storage binding limit of {binding_limit} bytes"
                )));
            }
        }
        Ok(())
    }
}

/// The device buffers, in the kernels' binding order after the uniform.
struct Buffers {
    pos: Buffer,
    normal: Buffer,
    nodes: Buffer,
    lists: Buffer,
    node_tasks: Buffer,
    splat_tasks: Buffer,
    radiance: Buffer,
    multipole: Buffer,
    local: Buffer,
    out: Buffer,
    spare: Buffer,
}

impl Buffers {
    /// Uploads the static data and allocates the expansions and outputs.
    fn new(
        ctx: &GpuContext,
        host: &HostData,
        plan: &Plan,
        work: &Work,
    ) -> Result<Buffers, FmmError> {
        let err = FmmError::Gpu;
        let storage = |label: &str, bytes: &[u8]| ctx.storage(label, bytes).map_err(err);
        let output = |label: &str, size: u64| ctx.output(label, size).map_err(err);
        Ok(Buffers {
            pos: storage("fmm positions", bytemuck::cast_slice(&host.pos_area))?,
            normal: storage("fmm normals", bytemuck::cast_slice(&host.normal_active))?,
            nodes: storage("fmm nodes", bytemuck::cast_slice(&host.slots))?,
            lists: storage("fmm lists", bytemuck::cast_slice(&host.lists))?,
            node_tasks: ctx
                .storage_windowed("fmm node tasks", bytemuck::cast_slice(&plan.node_tasks))
                .map_err(err)?,
            splat_tasks: ctx
                .storage_windowed("fmm splat tasks", bytemuck::cast_slice(&work.splat_tasks))
                .map_err(err)?,
            radiance: output("fmm radiance", host.field_bytes)?,
            multipole: output("fmm multipole expansions", host.expansion_bytes)?,
            local: output("fmm local expansions", host.expansion_bytes)?,
            out: output("fmm output", host.out_bytes)?,
            spare: output("fmm spare local expansions", host.spare_bytes)?,
        })
    }
}

/// One dispatch of an application: its kernel ([`Phase`]), uniform, workgroups, and the window
/// of a task array it binds (the binding, first and end record).
struct Step {
    phase: Phase,
    params: Buffer,
    groups: (u32, u32, u32),
    window: Option<(usize, u64, u64)>,
}

/// The dispatches of one application, in order: P2M, M2M per level, M2L per node-task window,
/// the cut nodes' gather, L2L per level, the splat items per splat-task window, the gather.
fn dispatch_steps(
    ctx: &GpuContext,
    host: &HostData,
    tree: &Tree,
    work: &Work,
    node_windows: &[gpu_work::Window],
    splat_windows: &[gpu_work::Window],
) -> Vec<Step> {
    let mut steps = Vec::new();
    let mut step = |phase: Phase, first: u32, count: u32, window: Option<(usize, u64, u64)>| {
        if count == 0 {
            return;
        }
        let task_base = window.map_or(0, |w| w.1 as u32);
        let p = GpuParams {
            count,
            first,
            task_base,
            ..host.base
        };
        let label = format!("fmm {} params", ENTRIES[phase as usize]);
        steps.push(Step {
            phase,
            params: ctx.uniform(&label, bytemuck::bytes_of(&p)),
            groups: grid(count, GROUP),
            window,
        });
    };
    step(Phase::P2m, 0, tree.leaves.len() as u32, None);
    for &(first, count) in &host.m2m_levels {
        step(Phase::M2m, first, count, None);
    }
    let window = |at: usize, w: &gpu_work::Window| Some((at, w.base as u64, w.end as u64));
    for w in node_windows {
        step(Phase::M2l, w.first, w.count, window(NODE_TASKS, w));
    }
    step(Phase::M2lGather, 0, work.node_gathers.len() as u32, None);
    for &(first, count) in &host.l2l_levels {
        step(Phase::L2l, first, count, None);
    }
    for w in splat_windows {
        step(Phase::Splat, w.first, w.count, window(SPLAT_TASKS, w));
    }
    step(Phase::Gather, 0, host.splats as u32, None);
    steps
}

/// The kernels of one order, in the order of [`ENTRIES`].
fn compile(ctx: &GpuContext, order: usize) -> Result<Vec<pc_gpu::Kernel>, FmmError> {
    let mut b = vec![Binding::Uniform];
    b.extend([Binding::ReadOnly; 7]);
    b.extend([Binding::ReadWrite; 4]);
    let src = source(&Basis::new(order)).map_err(FmmError::Gpu)?;
    ENTRIES
        .iter()
        .map(|e| ctx.kernel(&format!("fmm/{e}/order {order}"), &src, e, &b))
        .collect::<Result<Vec<_>, _>>()
        .map_err(FmmError::Gpu)
}

/// What runs an application on the device.
struct Device {
    ctx: GpuContext,
    /// The kernels per order: the configured one's compiled up front, lower ones (relaxed
    /// products) at first use. A lower order's expansions are a prefix of the configured one's
    /// in size, so the same buffers serve (each order's kernels address them with their own
    /// stride).
    kernels: Vec<Option<Vec<pc_gpu::Kernel>>>,
    buffers: Buffers,
    steps: Vec<Step>,
    /// Binding, record size and records of the two task arrays.
    task_arrays: [(usize, u64, u64); 2],
    splats: usize,
    field_bytes: u64,
}

impl Device {
    /// One application at `order` (at most the configured one): the radiance up, the
    /// dispatches, the output back.
    fn apply(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        order: usize,
        times: &mut PhaseTimes,
    ) -> Result<(), FmmError> {
        let n = self.splats;
        let order = order.min(self.kernels.len() - 1);
        if self.kernels[order].is_none() {
            self.kernels[order] = Some(compile(&self.ctx, order)?);
        }
        let kernels = self.kernels[order].as_ref().expect("compiled above");
        if radiance.len() != n || out.len() != n {
            return Err(FmmError::GpuPlan(format!(
                "{} radiances and {} outputs for {n} splats",
                radiance.len(),
                out.len()
            )));
        }
        if n == 0 {
            return Ok(());
        }
        let (ctx, b) = (&self.ctx, &self.buffers);
        ctx.write(&b.radiance, bytemuck::cast_slice(radiance));
        for step in &self.steps {
            let buffers = [
                &step.params,
                &b.pos,
                &b.normal,
                &b.nodes,
                &b.lists,
                &b.node_tasks,
                &b.splat_tasks,
                &b.radiance,
                &b.multipole,
                &b.local,
                &b.out,
                &b.spare,
            ];
            // The task arrays are bound in windows: the step's own, or a first record for the
            // kernels that do not read them (the whole array may exceed one binding).
            let mut binds = buffers.map(Bind::whole);
            for (at, record, len) in self.task_arrays {
                let (lo, hi) = match step.window {
                    Some((w, lo, hi)) if w == at => (lo, hi),
                    _ => (0, len.min(1)),
                };
                binds[at] = Bind::window(buffers[at], lo * record, (hi - lo) * record);
            }
            let t = Instant::now();
            kernels[step.phase as usize]
                .run_binds(ctx, &binds, step.groups)
                .map_err(FmmError::Gpu)?;
            let s = t.elapsed().as_secs_f64();
            match step.phase {
                Phase::P2m | Phase::M2m => times.upward += s,
                Phase::M2l | Phase::M2lGather => times.m2l += s,
                _ => times.downward += s,
            }
        }
        let t = Instant::now();
        let data = ctx.read(&b.out, self.field_bytes).map_err(FmmError::Gpu)?;
        bytemuck::cast_slice_mut::<[f32; 3], u8>(out).copy_from_slice(&data);
        times.downward += t.elapsed().as_secs_f64();
        Ok(())
    }
}

impl crate::Operator for GpuFmm {
    fn apply_relaxed(
        &mut self,
        radiance: &[[f32; 3]],
        out: &mut [[f32; 3]],
        relax: f64,
    ) -> Result<u32, FmmError> {
        let order = crate::cpu::order_within(self.order as usize, self.theta, relax);
        self.device.apply(radiance, out, order, &mut self.times)?;
        self.applications += 1;
        Ok(order as u32)
    }

    fn order(&self) -> u32 {
        self.order
    }

    fn device(&self) -> String {
        format!("GPU ({})", self.describe)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu_work::SplatTask;

    #[test]
    fn records_match_their_wgsl_twins() {
        let m = pc_gpu::validate_wgsl(&source(&Basis::new(2)).unwrap()).unwrap();
        let (size, members) = pc_gpu::wgsl_struct_layout(&m, "Node").unwrap();
        assert_eq!(size as usize, std::mem::size_of::<GpuNode>());
        assert_eq!(members[1], ("compact".to_string(), 12));
        let (size, _) = pc_gpu::wgsl_struct_layout(&m, "Params").unwrap();
        assert_eq!(size as usize, std::mem::size_of::<GpuParams>());
        let (size, _) = pc_gpu::wgsl_struct_layout(&m, "SplatTask").unwrap();
        assert_eq!(size as usize, std::mem::size_of::<SplatTask>());
        let (size, _) = pc_gpu::wgsl_struct_layout(&m, "NodeTask").unwrap();
        assert_eq!(size as usize, std::mem::size_of::<NodeTask>());
    }

    #[test]
    fn a_software_adapter_refuses_loops_beyond_its_budget() {
        let fine = [("p2m", 16), ("splat", SOFTWARE_LOOP_LIMIT)];
        assert!(check_loop_bounds("llvmpipe", &fine).is_ok());
        let over = [("p2m", 70_000), ("splat", 90_000)];
        assert_eq!(
            check_loop_bounds("llvmpipe", &over).unwrap_err().to_string(),
            "FMM on the GPU: llvmpipe ends a shader's loops after 65535 iterations per invocation group, and this plan may need 70000 in the p2m kernel"
        );
    }
}
