//! Where a process's GPU time goes: building kernels, uploading buffers, running dispatches and
//! reading results back. Counted process-wide (a stage process holds one [`crate::GpuContext`]),
//! so pc-stage can add them to any stage's summary without the stage passing them along.
//!
//! Each [`crate::Kernel::run`] waits for its dispatch, so its time is the kernel's own (with any
//! upload the driver still had queued); a readback's time is the copy and the mapping.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

/// The process's counters: nanoseconds and bytes.
static KERNEL_BUILD_NS: AtomicU64 = AtomicU64::new(0);
static KERNELS_BUILT: AtomicU64 = AtomicU64::new(0);
static UPLOAD_NS: AtomicU64 = AtomicU64::new(0);
static UPLOAD_BYTES: AtomicU64 = AtomicU64::new(0);
static DISPATCH_NS: AtomicU64 = AtomicU64::new(0);
static DISPATCHES: AtomicU64 = AtomicU64::new(0);
static READ_NS: AtomicU64 = AtomicU64::new(0);
static READ_BYTES: AtomicU64 = AtomicU64::new(0);
static KERNEL_NS: AtomicU64 = AtomicU64::new(0);
static KERNELS_TIMED: AtomicU64 = AtomicU64::new(0);

/// What a process spent on the GPU so far.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuTimes {
    /// Kernels built (WGSL to pipeline, the driver's compile included) and their seconds.
    pub kernels_built: u64,
    pub build_seconds: f64,
    /// Bytes copied into new buffers and the seconds it took on the host.
    pub upload_bytes: u64,
    pub upload_seconds: f64,
    /// Dispatches run, and their seconds from submission to completion.
    pub dispatches: u64,
    pub dispatch_seconds: f64,
    /// Bytes read back and the seconds of the copies and mappings.
    pub read_bytes: u64,
    pub read_seconds: f64,
    /// Dispatches timed on the GPU's own clock (where the adapter writes timestamps) and the
    /// seconds their kernels ran: `dispatch_seconds` less this is the host's side of them.
    pub kernels_timed: u64,
    pub kernel_seconds: f64,
}

/// The counters so far; `None` when this process ran no dispatch.
pub fn times() -> Option<GpuTimes> {
    let s = |a: &AtomicU64| a.load(Relaxed) as f64 * 1e-9;
    let t = GpuTimes {
        kernels_built: KERNELS_BUILT.load(Relaxed),
        build_seconds: s(&KERNEL_BUILD_NS),
        upload_bytes: UPLOAD_BYTES.load(Relaxed),
        upload_seconds: s(&UPLOAD_NS),
        dispatches: DISPATCHES.load(Relaxed),
        dispatch_seconds: s(&DISPATCH_NS),
        read_bytes: READ_BYTES.load(Relaxed),
        read_seconds: s(&READ_NS),
        kernels_timed: KERNELS_TIMED.load(Relaxed),
        kernel_seconds: s(&KERNEL_NS),
    };
    (t.dispatches > 0).then_some(t)
}

impl GpuTimes {
    /// The counters as JSON, for `--stats-json` and `--report`.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "kernels_built": self.kernels_built,
            "build_seconds": self.build_seconds,
            "upload_bytes": self.upload_bytes,
            "upload_seconds": self.upload_seconds,
            "dispatches": self.dispatches,
            "dispatch_seconds": self.dispatch_seconds,
            "read_bytes": self.read_bytes,
            "read_seconds": self.read_seconds,
            "kernels_timed": self.kernels_timed,
            "kernel_seconds": self.kernel_seconds,
        })
    }
}

impl std::fmt::Display for GpuTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mb = |b: u64| b as f64 / 1e6;
        write!(
            f,
            "GPU: {} kernels built in {:.2} s, {:.0} MB up in {:.2} s, {} dispatches {:.2} s, {:.0} MB back in {:.2} s",
            self.kernels_built,
            self.build_seconds,
            mb(self.upload_bytes),
            self.upload_seconds,
            self.dispatches,
            self.dispatch_seconds,
            mb(self.read_bytes),
            self.read_seconds
        )?;
        if self.kernels_timed > 0 {
            write!(
                f,
                ", kernels {:.2} s on the GPU's clock",
                self.kernel_seconds
            )?;
        }
        Ok(())
    }
}

/// What one counted operation adds when it ends.
pub(crate) enum Op {
    Build,
    Upload(u64),
    Dispatch,
    Read(u64),
}

/// Adds the time since `started` (and the bytes) to `op`'s counters.
pub(crate) fn count(op: Op, started: Instant) {
    let ns = started.elapsed().as_nanos() as u64;
    let (time, n, by) = match op {
        Op::Build => (&KERNEL_BUILD_NS, &KERNELS_BUILT, 1),
        Op::Upload(b) => (&UPLOAD_NS, &UPLOAD_BYTES, b),
        Op::Dispatch => (&DISPATCH_NS, &DISPATCHES, 1),
        Op::Read(b) => (&READ_NS, &READ_BYTES, b),
    };
    time.fetch_add(ns, Relaxed);
    n.fetch_add(by, Relaxed);
}

/// Adds one dispatch's kernel time, measured on the GPU's clock.
pub(crate) fn count_kernel(ns: f64) {
    KERNEL_NS.fetch_add(ns as u64, Relaxed);
    KERNELS_TIMED.fetch_add(1, Relaxed);
}
