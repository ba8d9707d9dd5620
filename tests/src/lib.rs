//! Shared helpers for the end-to-end tests in tests/e2e/: where the stage binaries are (built
//! once per test process), temporary scenes and pipeline.toml files, and running a command to
//! capture its exit code, stdout and stderr.
//!
//! The binaries belong to other packages of the workspace, so cargo's `CARGO_BIN_EXE_<name>`
//! does not name them. They are found next to the test executable
//! (`target/<profile>/deps/e2e-<hash>` → `target/<profile>/<bin>`), and built first by one
//! `cargo build --bins -p pc-octree -p pc-inspect -p pc-sample -p pc-raytrace` with the test's own profile and
//! target folder: `cargo test -p pcgi-tests` does not build binaries of other packages, and
//! `cargo test --workspace` builds a package's binaries only when it has integration tests.
//! Set `PCGI_E2E_NO_BUILD=1` to skip that build and use the binaries as they are.

use std::fmt;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use pc_import::ply_write::{write_ply, PlyFormat, PlyPoints};

pub use glam::Vec3;

/// A command line: each argument is anything that is `AsRef<OsStr>` (`&str`, `PathBuf`, ...).
#[macro_export]
macro_rules! args {
    ($($a:expr),* $(,)?) => {
        vec![$(::std::convert::AsRef::<::std::ffi::OsStr>::as_ref(&$a).to_os_string()),*]
    };
}

/// The packages whose binaries the tests run, and the binaries.
const BIN_PACKAGES: [&str; 9] = [
    "pc-octree",
    "pc-inspect",
    "pc-sample",
    "pc-raytrace",
    "pc-vmap",
    "pc-fmm",
    "pc-caustics",
    "pc-run",
    "pc-bake",
];

/// The workspace root (the folder of the root Cargo.toml).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ lies inside the workspace")
        .to_path_buf()
}

/// The folder that holds the binaries of the profile this test was built with
/// (`target/<profile>`): the test executable lies in its `deps/` subfolder.
pub fn bin_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test executable's path");
    let mut dir = exe
        .parent()
        .expect("the test executable lies in a folder")
        .to_path_buf();
    if dir.file_name().is_some_and(|n| n == "deps") {
        dir.pop();
    }
    dir
}

/// Build the stage binaries once per test process; every caller gets the same result.
fn ensure_built() {
    static BUILT: OnceLock<Result<(), String>> = OnceLock::new();
    let result = BUILT.get_or_init(|| {
        if std::env::var_os("PCGI_E2E_NO_BUILD").is_some() {
            return Ok(());
        }
        let dir = bin_dir();
        let profile = dir
            .file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| format!("{}: cannot tell the cargo profile", dir.display()))?
            .to_string();
        let target_dir = dir
            .parent()
            .ok_or_else(|| format!("{}: no target folder above it", dir.display()))?;
        let cargo = std::env::var_os("CARGO")
            .or_else(|| option_env!("CARGO").map(Into::into))
            .unwrap_or_else(|| "cargo".into());
        let mut cmd = Command::new(&cargo);
        cmd.arg("build")
            .arg("--quiet")
            .arg("--manifest-path")
            .arg(workspace_root().join("Cargo.toml"))
            .arg("--target-dir")
            .arg(target_dir)
            .arg("--bins");
        for p in BIN_PACKAGES {
            cmd.args(["-p", p]);
        }
        match profile.as_str() {
            "debug" => {}
            "release" => {
                cmd.arg("--release");
            }
            other => {
                cmd.args(["--profile", other]);
            }
        }
        let out = cmd
            .output()
            .map_err(|e| format!("cannot run {cmd:?}: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "building the stage binaries failed ({cmd:?}, {}):\n{}",
                out.status,
                String::from_utf8_lossy(&out.stderr)
            ))
        }
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// The path of a stage binary (`pc-octree`, `pc-inspect`, `pc-sample`), built if needed.
pub fn bin(name: &str) -> PathBuf {
    ensure_built();
    let path = bin_dir().join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "{}: the `{name}` binary is missing (built by `cargo build --bins`)",
        path.display()
    );
    path
}

/// What a finished command did.
pub struct Output {
    /// The command line, for messages.
    pub cmd: String,
    /// The exit code (`None` when killed by a signal).
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

impl fmt::Debug for Output {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "`{}` exited with {:?}\n--- stdout ---\n{}--- stderr ---\n{}",
            self.cmd, self.code, self.stdout, self.stderr
        )
    }
}

impl Output {
    /// Panics (showing everything) unless the command exited with 0.
    #[track_caller]
    pub fn success(self) -> Self {
        assert_eq!(self.code, Some(0), "expected success: {self:?}");
        self
    }

    /// Panics unless the command exited with 2 and printed `<bin>: error: ` and every one of
    /// `needles` on stderr; returns the stderr.
    #[track_caller]
    pub fn error(self, needles: &[&str]) -> String {
        // Shown by `cargo test -- --nocapture`, to review the messages users get.
        eprintln!("{}", self.stderr.trim_end());
        assert_eq!(self.code, Some(2), "expected exit code 2: {self:?}");
        let bin = self.cmd.split_whitespace().next().unwrap_or("");
        let bin = Path::new(bin)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let prefix = format!("{bin}: error: ");
        assert!(
            self.stderr.starts_with(&prefix),
            "stderr should start with {prefix:?}: {self:?}"
        );
        for n in needles {
            assert!(
                self.stderr.contains(n),
                "stderr should mention {n:?}: {self:?}"
            );
        }
        self.stderr
    }
}

/// Run `bin` with `args` in `cwd` (or the current folder), capturing everything.
pub fn run_in<I, S>(cwd: Option<&Path>, bin: &Path, args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let args: Vec<std::ffi::OsString> = args.into_iter().map(|a| a.as_ref().into()).collect();
    let mut cmd = Command::new(bin);
    cmd.args(&args);
    if let Some(dir) = cwd {
        cmd.current_dir(dir);
    }
    capture(cmd, bin, &args)
}

/// A resource limit for [`run_limited`].
#[cfg(unix)]
#[derive(Clone, Copy, Debug)]
pub enum Limit {
    /// Files may grow to this many bytes (`RLIMIT_FSIZE`, with `SIGXFSZ` ignored so a write
    /// past it fails with EFBIG, "File too large"): what a full disk looks like to a writer.
    FileSize(u64),
    /// The address space may grow to this many bytes (`RLIMIT_AS`): allocations past it fail,
    /// as on a machine without overcommit.
    AddressSpace(u64),
}

/// `setrlimit`'s resource type (glibc names it; elsewhere an int).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
type Resource = libc::__rlimit_resource_t;
#[cfg(all(unix, not(all(target_os = "linux", target_env = "gnu"))))]
type Resource = libc::c_int;

/// Run `bin` with `args` as a process under `limit`.
#[cfg(unix)]
pub fn run_limited<I, S>(bin: &Path, args: I, limit: Limit) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    run_limited_env(bin, args, limit, &[])
}

/// [`run_limited`] with these environment variables set for the child.
pub fn run_limited_env<I, S>(bin: &Path, args: I, limit: Limit, env: &[(&str, &str)]) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    let (resource, limit): (Resource, u64) = match limit {
        Limit::FileSize(n) => (libc::RLIMIT_FSIZE, n),
        Limit::AddressSpace(n) => (libc::RLIMIT_AS, n),
    };
    use std::os::unix::process::CommandExt;
    let args: Vec<std::ffi::OsString> = args.into_iter().map(|a| a.as_ref().into()).collect();
    let mut cmd = Command::new(bin);
    cmd.args(&args).envs(env.iter().copied());
    // SAFETY: between fork and exec the closure only makes two async-signal-safe calls.
    unsafe {
        cmd.pre_exec(move || {
            let lim = libc::rlimit {
                rlim_cur: limit as libc::rlim_t,
                rlim_max: limit as libc::rlim_t,
            };
            if libc::setrlimit(resource, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    capture(cmd, bin, &args)
}

/// Run `cmd` (which is `bin` with `args`) to the end and keep everything it printed.
fn capture(mut cmd: Command, bin: &Path, args: &[std::ffi::OsString]) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}", bin.display()));
    let line = std::iter::once(bin.as_os_str())
        .chain(args.iter().map(|a| a.as_os_str()))
        .map(|a| a.to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join(" ");
    Output {
        cmd: line,
        code: out.status.code(),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// Run a stage binary by name (see [`bin`]).
pub fn run<I, S>(name: &str, args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    run_in(None, &bin(name), args)
}

/// `pc-octree ARGS`.
pub fn pc_octree<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    run("pc-octree", args)
}

/// `pc-inspect ARGS`.
pub fn pc_inspect<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    run("pc-inspect", args)
}

/// `pc-sample ARGS`.
pub fn pc_sample<I, S>(args: I) -> Output
where
    I: IntoIterator<Item = S>,
    S: AsRef<std::ffi::OsStr>,
{
    run("pc-sample", args)
}

/// `pc-sample cornell` (with the glass and mirror spheres when `specular`) at `points` splats
/// into `dir/scene`, and `dir/pipeline.toml` including it, writing to `dir/out`, with `extra`
/// TOML after; returns the config's path.
pub fn sampled_cornell(dir: &Path, points: usize, specular: bool, extra: &str) -> PathBuf {
    let mut a = args![
        "cornell",
        "--points",
        points.to_string(),
        "--out",
        dir.join("scene")
    ];
    if specular {
        a.push("--with-specular".into());
    }
    pc_sample(a).success();
    let cfg = dir.join("pipeline.toml");
    let text = format!("include = [\"scene/scene.toml\"]\n[output]\ndir = \"out\"\n{extra}");
    std::fs::write(&cfg, text).unwrap_or_else(|e| panic!("{}: {e}", cfg.display()));
    cfg
}

/// A fresh temporary folder, removed when dropped.
pub fn temp_dir() -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix("pcgi-e2e-")
        .tempdir()
        .expect("a temporary folder")
}

/// A small valid model: a `side × side` grid of splats on the plane y = 0 (x, z in [-1, 1]),
/// normals +y, radii covering the grid.
pub struct Grid {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub radii: Vec<f32>,
}

impl Grid {
    pub fn new(side: usize) -> Grid {
        let step = 2.0 / side as f32;
        let mut positions = Vec::with_capacity(side * side);
        for i in 0..side {
            for j in 0..side {
                positions.push(Vec3::new(
                    -1.0 + (i as f32 + 0.5) * step,
                    0.0,
                    -1.0 + (j as f32 + 0.5) * step,
                ));
            }
        }
        let n = positions.len();
        Grid {
            positions,
            normals: vec![Vec3::Y; n],
            radii: vec![step; n],
        }
    }

    /// Write it with normals and radii, binary little-endian unless `format` says otherwise.
    pub fn write(&self, path: &Path, format: PlyFormat) {
        let pts = PlyPoints {
            positions: &self.positions,
            normals: Some(&self.normals),
            radii: Some(&self.radii),
            colors: None,
        };
        write_ply(path, &pts, format, &["pcgi e2e test model".to_string()])
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

/// Write `pipeline.toml` in `dir`: one diffuse material `white`, one model per entry of
/// `models` (paths as written, relative to `dir`), `[output] dir = "out"`, then `extra`.
pub fn write_pipeline(dir: &Path, models: &[&str], extra: &str) -> PathBuf {
    let mut text = String::from(
        "[output]\ndir = \"out\"\n\n[materials.white]\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n\n",
    );
    for m in models {
        text.push_str(&format!(
            "[[models]]\nfile = {}\nmaterial = \"white\"\n\n",
            toml_string(m)
        ));
    }
    text.push_str(extra);
    let path = dir.join("pipeline.toml");
    std::fs::write(&path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    path
}

/// A TOML basic string holding `s`.
pub fn toml_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// Every file under `dir` (recursively), relative to it, sorted; empty if `dir` is absent.
pub fn files_under(dir: &Path) -> Vec<PathBuf> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                out.push(p.strip_prefix(root).unwrap_or(&p).to_path_buf());
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// Panics if any file under `dir` is an artifact (`*.pcgi`) or a leftover `*.tmp`.
#[track_caller]
pub fn assert_nothing_written(dir: &Path) {
    let bad: Vec<PathBuf> = files_under(dir)
        .into_iter()
        .filter(|p| {
            let name = p.to_string_lossy();
            name.ends_with(".pcgi") || name.ends_with(".tmp")
        })
        .collect();
    assert!(
        bad.is_empty(),
        "{}: a failed run left files behind: {bad:?}",
        dir.display()
    );
}

/// The number just before `word` in `text` (`"1087 leaves"` → 1087).
pub fn count_before(text: &str, word: &str) -> Option<u64> {
    let words: Vec<&str> = text
        .split(|c: char| c.is_whitespace() || c == ',' || c == '(' || c == ')')
        .filter(|w| !w.is_empty())
        .collect();
    words
        .windows(2)
        .find(|w| w[1] == word)
        .and_then(|w| w[0].parse().ok())
}

/// The decoded 8-bit pixels of a PNG file (what it shows, whatever chunks it carries besides).
pub fn png_pixels(path: &Path) -> Vec<u8> {
    let file = std::io::BufReader::new(
        std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    );
    let mut reader = png::Decoder::new(file)
        .read_info()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buf = vec![0; reader.output_buffer_size().expect("a sized image")];
    let info = reader
        .next_frame(&mut buf)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    buf.truncate(info.buffer_size());
    buf
}
