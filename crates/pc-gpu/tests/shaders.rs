//! Every WGSL file in shaders/ parses and validates with naga, composed with the files its
//! `// requires:` first line names (no GPU needed).

#[test]
fn every_kernel_validates_with_its_common_files() {
    let mut kernels = 0;
    for (path, text) in pc_gpu::shaders::files() {
        if path.starts_with("common/") {
            continue;
        }
        assert!(
            !pc_gpu::shaders::requires(text).is_empty() || !text.contains("octree_"),
            "{path}: no `// requires:` line"
        );
        let src = pc_gpu::shaders::source(path).unwrap_or_else(|e| panic!("{path}: {e}"));
        pc_gpu::validate_wgsl(&src).unwrap_or_else(|e| panic!("{path}: {e}"));
        kernels += 1;
    }
    assert!(kernels >= 3, "found {kernels} kernels");
}
