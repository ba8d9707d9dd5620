//! `pc_gpu::times`: what a process spent on the GPU, counted as it goes (docs/gpu.md). Skipped
//! without a GPU adapter unless `PC_REQUIRE_GPU=1`.

use pc_gpu::{grid, Binding};

/// One kernel built, one buffer up, one dispatch, one readback: each counted with its bytes, and
/// the kernel's work is there to read back.
#[test]
fn a_dispatch_is_counted_with_its_bytes() {
    let Some(ctx) = pc_gpu::test_context() else {
        return;
    };
    // (This test binary's only test: the counters are the process's.)
    assert_eq!(pc_gpu::times(), None, "no dispatch yet");
    let src = "
        @group(0) @binding(0) var<storage, read> input: array<u32>;
        @group(0) @binding(1) var<storage, read_write> output: array<u32>;
        @compute @workgroup_size(64)
        fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
            if gid.x < arrayLength(&input) {
                output[gid.x] = input[gid.x] * 2u;
            }
        }";
    let kernel = ctx
        .kernel(
            "double",
            src,
            "main",
            &[Binding::ReadOnly, Binding::ReadWrite],
        )
        .unwrap();
    let values: Vec<u32> = (0..1000).collect();
    let input = ctx.storage("input", bytemuck::cast_slice(&values)).unwrap();
    let output = ctx.output("output", 4000).unwrap();
    kernel
        .run(&ctx, &[&input, &output], grid(1000, 64))
        .unwrap();
    let back = ctx.read(&output, 4000).unwrap();
    let doubled: &[u32] = bytemuck::cast_slice(&back);
    assert_eq!(doubled[999], 1998);
    let t = pc_gpu::times().expect("a dispatch ran");
    assert_eq!(t.kernels_built, 1);
    assert_eq!(t.upload_bytes, 4000);
    assert_eq!(t.dispatches, 1);
    assert_eq!(t.read_bytes, 4000);
    assert!(t.dispatch_seconds > 0.0 && t.read_seconds > 0.0);
    // Where the adapter writes timestamps, the dispatch was timed on the GPU's clock too, and
    // the summary says so.
    let stamps = ctx
        .adapter
        .features()
        .contains(wgpu::Features::TIMESTAMP_QUERY);
    assert_eq!(t.kernels_timed, stamps as u64);
    assert!(t.kernel_seconds.is_finite() && t.kernel_seconds >= 0.0);
    let line = t.to_string();
    assert_eq!(line.contains("on the GPU's clock"), stamps, "{line}");
    assert!(line.starts_with("GPU: 1 kernels built in "), "{line}");
    assert_eq!(t.json()["dispatches"], 1);
}
