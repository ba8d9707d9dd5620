//! Every WGSL file in shaders/ parses and validates with naga, composed with the common files
//! its `// requires:` first line names (no GPU needed).

use std::path::Path;

fn requires(src: &str) -> Vec<String> {
    src.lines()
        .next()
        .and_then(|l| l.strip_prefix("// requires:"))
        .map(|r| r.split_whitespace().map(str::to_string).collect())
        .unwrap_or_default()
}

#[test]
fn every_kernel_validates_with_its_common_files() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
    let mut kernels = 0;
    for dir in std::fs::read_dir(&root).unwrap() {
        let dir = dir.unwrap().path();
        if dir.file_name().unwrap() == "common" {
            continue;
        }
        for f in std::fs::read_dir(&dir).unwrap() {
            let f = f.unwrap().path();
            if f.extension().is_none_or(|e| e != "wgsl") {
                continue;
            }
            let src = std::fs::read_to_string(&f).unwrap();
            let deps = requires(&src);
            assert!(
                !deps.is_empty() || !src.contains("octree_"),
                "{}: no `// requires:` line",
                f.display()
            );
            let mut parts: Vec<String> = deps
                .iter()
                .map(|d| {
                    std::fs::read_to_string(root.join(d))
                        .unwrap_or_else(|e| panic!("{}: {d}: {e}", f.display()))
                })
                .collect();
            parts.push(src);
            let refs: Vec<&str> = parts.iter().map(String::as_str).collect();
            pc_gpu::validate_wgsl(&pc_gpu::compose(&refs))
                .unwrap_or_else(|e| panic!("{}: {e}", f.display()));
            kernels += 1;
        }
    }
    assert!(kernels >= 3, "found {kernels} kernels");
}
