//! The WGSL files of `shaders/`, embedded at build time (`build.rs`), and the one place a kernel's
//! source is put together.
//!
//! A file's first line names the files it needs: `// requires: common/octree.wgsl
//! common/traverse.wgsl`. [`source`] composes a kernel from that line alone: its requirements
//! (each one's own requirements first, every file once, in the order named), then the kernel.
//! No Rust code lists a shader's common files again. Paths are relative to `shaders/`.

mod embedded {
    include!(concat!(env!("OUT_DIR"), "/shaders.rs"));
}

use crate::GpuError;

/// Every embedded file: (path below `shaders/`, text), sorted by path.
pub fn files() -> &'static [(&'static str, &'static str)] {
    embedded::FILES
}

/// The text of one file, `None` when `shaders/` has no such file.
pub fn file(path: &str) -> Option<&'static str> {
    embedded::FILES
        .iter()
        .find(|(p, _)| *p == path)
        .map(|(_, text)| *text)
}

/// The files a shader's `// requires:` first line names (empty without one).
pub fn requires(text: &str) -> Vec<&str> {
    text.lines()
        .next()
        .and_then(|l| l.strip_prefix("// requires:"))
        .map(|r| r.split_whitespace().collect())
        .unwrap_or_default()
}

/// The source of the kernel in `shaders/<kernel>`: its requirements, then the kernel, each
/// file followed by a newline.
pub fn source(kernel: &str) -> Result<String, GpuError> {
    source_with(kernel, &[])
}

/// [`source`] with some files replaced by generated text: `(path, text)` pairs. The FMM's
/// kernels replace `fmm/basis.wgsl` (a stand-in that lets the file validate alone) by the basis
/// of the run's order.
pub fn source_with(kernel: &str, replace: &[(&str, &str)]) -> Result<String, GpuError> {
    let mut order = Vec::new();
    visit(kernel, replace, &mut Vec::new(), &mut order)?;
    let mut s = String::new();
    for (_, text) in order {
        s.push_str(text);
        s.push('\n');
    }
    Ok(s)
}

/// Depth-first: a file's requirements before the file, each file once; `path` is the chain of
/// files being visited, to report a cycle.
fn visit<'a>(
    name: &'a str,
    replace: &[(&'a str, &'a str)],
    path: &mut Vec<&'a str>,
    order: &mut Vec<(&'a str, &'a str)>,
) -> Result<(), GpuError> {
    if order.iter().any(|(n, _)| *n == name) {
        return Ok(());
    }
    let err = |msg: String| GpuError::Shader {
        label: path.first().copied().unwrap_or(name).to_string(),
        msg,
    };
    if path.contains(&name) {
        return Err(err(format!(
            "the `// requires:` lines form a cycle: {} -> {name}",
            path.join(" -> ")
        )));
    }
    let own = file(name).ok_or_else(|| err(format!("shaders/{name} does not exist")))?;
    let text = replace
        .iter()
        .find(|(p, _)| *p == name)
        .map_or(own, |(_, t)| *t);
    path.push(name);
    for dep in requires(own) {
        visit(dep, replace, path, order)?;
    }
    path.pop();
    order.push((name, text));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_shader_file_is_embedded() {
        let names: Vec<&str> = files().iter().map(|(p, _)| *p).collect();
        for f in ["common/octree.wgsl", "raytrace/render.wgsl", "fmm/fmm.wgsl"] {
            assert!(names.contains(&f), "{f} missing from {names:?}");
        }
    }

    #[test]
    fn requirements_come_first_and_once() {
        let s = source("raytrace/render.wgsl").unwrap();
        let parts = [
            "common/octree.wgsl",
            "common/traverse.wgsl",
            "common/optics.wgsl",
            "raytrace/render.wgsl",
        ];
        let expected: String = parts
            .iter()
            .map(|p| format!("{}\n", file(p).unwrap()))
            .collect();
        assert_eq!(
            s, expected,
            "octree.wgsl, required by three files, comes once and first"
        );
    }

    #[test]
    fn replacements_and_unknown_files() {
        let s = source_with("fmm/fmm.wgsl", &[("fmm/basis.wgsl", "// generated")]).unwrap();
        assert!(s.starts_with("// generated\n"));
        assert!(s.ends_with(&format!("{}\n", file("fmm/fmm.wgsl").unwrap())));
        let e = source("nope/missing.wgsl").unwrap_err().to_string();
        assert!(
            e.contains("shaders/nope/missing.wgsl does not exist"),
            "{e}"
        );
    }
}
