//! Out of memory as a clear error instead of a bare abort. Rust's default answer to an
//! allocation that fails is `memory allocation of N bytes failed` and SIGABRT, without the
//! program's name or what to do (a 100M-point octree under `ulimit -v` ended so after 25
//! minutes). Every stage binary installs [`ReportOom`] as its global allocator with
//! [`report_oom!`](crate::report_oom): it is the system allocator, except that an allocation the system refuses
//! prints `NAME: error: out of memory: …` and exits with code 2, the code of every other
//! error. Nothing half written is published: artifacts are written to a temporary file and
//! renamed only when complete, the output folder's lock dies with the process, and the next
//! run removes the temporary file (docs/artifacts.md, "Guarantees").
//!
//! Where the system overcommits memory (Linux by default) it refuses nothing and its OOM
//! killer ends the process instead; the message appears where memory is capped (`ulimit -v`,
//! a container without overcommit, a 32-bit address space).

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

/// The system allocator, with a clear error when it refuses (see the module).
pub struct ReportOom {
    name: &'static str,
}

impl ReportOom {
    /// The allocator of the binary `name` (its messages start with it).
    pub const fn new(name: &'static str) -> ReportOom {
        ReportOom { name }
    }

    #[cold]
    fn fail(&self, bytes: usize) -> ! {
        // One message: a second thread refused at the same time waits for the first's exit.
        static FAILED: AtomicBool = AtomicBool::new(false);
        if FAILED.swap(true, Ordering::SeqCst) {
            loop {
                std::thread::park();
            }
        }
        // No allocation from here on: the message is assembled on the stack.
        let mut buf = [0u8; 512];
        let mut at = 0;
        let mut put = |s: &[u8]| {
            let n = s.len().min(buf.len() - at);
            buf[at..at + n].copy_from_slice(&s[..n]);
            at += n;
        };
        put(self.name.as_bytes());
        put(b": error: out of memory: the system refused ");
        put(digits(bytes as u64, &mut [0u8; 20]));
        put(b" bytes (");
        let (unit, shift): (&[u8], u32) = if bytes >= 1 << 30 {
            (b" GiB", 30)
        } else {
            (b" MiB", 20)
        };
        let tenths = (bytes as u64).saturating_mul(10) >> shift;
        put(digits(tenths / 10, &mut [0u8; 20]));
        put(b".");
        put(digits(tenths % 10, &mut [0u8; 20]));
        put(unit);
        put(
            b" more); nothing was published (the previous output, if any, is intact). Give \
the run more memory or split the scene; BENCHMARKS.md lists each stage's memory per splat.\n",
        );
        let _ = std::io::stderr().write_all(&buf[..at]);
        std::process::exit(2)
    }
}

/// `x` in decimal, in `buf`.
fn digits(mut x: u64, buf: &mut [u8; 20]) -> &[u8] {
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (x % 10) as u8;
        x /= 10;
        if x == 0 {
            return &buf[i..];
        }
    }
}

// SAFETY: every method forwards to `System` with the same arguments and returns its result
// unchanged, so `System`'s guarantees hold; a null result (refusal) never returns but ends the
// process.
unsafe impl GlobalAlloc for ReportOom {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if p.is_null() {
            self.fail(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if p.is_null() {
            self.fail(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if p.is_null() {
            self.fail(new_size);
        }
        p
    }
}

/// Install [`ReportOom`] as the binary's global allocator: `pc_stage::report_oom!("pc-octree");`
/// at the top level of its main file.
#[macro_export]
macro_rules! report_oom {
    ($name:expr) => {
        #[global_allocator]
        static GLOBAL: $crate::oom::ReportOom = $crate::oom::ReportOom::new($name);
    };
}

#[cfg(test)]
mod tests {
    use super::digits;

    #[test]
    fn digits_are_decimal() {
        for x in [0u64, 7, 10, 1_600_000_000, u64::MAX] {
            assert_eq!(digits(x, &mut [0; 20]), x.to_string().as_bytes());
        }
    }
}
