//! Point location on the GPU: `shaders/octree/locate.wgsl`, twin of `pc_tree::OctreeView::locate`.

use glam::Vec3;
use pc_gpu::{grid, Binding, GpuContext, GpuError, Kernel};
use pc_tree::gpu::{GpuOctree, OctreeParts};
use pc_tree::{Located, OctreeView};

/// The kernel's source (`shaders/octree/locate.wgsl` with the files it requires).
pub fn source() -> Result<String, GpuError> {
    pc_gpu::shaders::source("octree/locate.wgsl")
}

/// A compiled point-location kernel.
pub struct LocateKernel {
    kernel: Kernel,
}

impl LocateKernel {
    pub fn new(ctx: &GpuContext) -> Result<LocateKernel, GpuError> {
        let bindings = [
            Binding::Uniform,
            Binding::ReadOnly,
            Binding::ReadOnly,
            Binding::ReadWrite,
        ];
        Ok(LocateKernel {
            kernel: ctx.kernel("octree/locate", &source()?, "main", &bindings)?,
        })
    }

    /// Locate every point; `None` where a point lies outside the root cube.
    pub fn run(
        &self,
        ctx: &GpuContext,
        tree: &OctreeView,
        points: &[Vec3],
    ) -> Result<Vec<Option<Located>>, GpuError> {
        if points.is_empty() {
            return Ok(Vec::new());
        }
        let queries: Vec<[f32; 4]> = points.iter().map(|p| [p.x, p.y, p.z, 0.0]).collect();
        let octree = GpuOctree::upload(ctx, tree, OctreeParts::Locate)?;
        let q = ctx.storage("queries", bytemuck::cast_slice(&queries))?;
        let size = (points.len() * 16) as u64;
        let out = ctx.output("results", size)?;
        let binds: Vec<&pc_gpu::Buffer> = octree.buffers().chain([&q, &out]).collect();
        self.kernel
            .run(ctx, &binds, grid(points.len() as u32, 64))?;
        let bytes = ctx.read(&out, size)?;
        let words: &[[u32; 4]] = bytemuck::cast_slice(&bytes);
        Ok(words
            .iter()
            .map(|w| {
                (w[0] != u32::MAX).then_some(Located {
                    slot: w[0],
                    node: w[1],
                    depth: w[2],
                })
            })
            .collect())
    }
}
