//! The worker threads, started before any work so that a system that refuses them gives a
//! stage fewer threads or a clear error, not rayon's panic. Under an address-space cap
//! (`ulimit -v`) on a machine with many cores, rayon's first parallel loop used to panic with
//! `The global thread pool has not been initialized` (exit code 101): each thread reserves its
//! stack, and 16 of them did not fit where 2 did (seen on a 16-core host in the e2e test
//! `a_stage_out_of_memory_says_so_and_keeps_what_was_published`).
//!
//! rayon's global pool can be built once: a build that fails leaves it failed for good. So the
//! count is found first with plain threads that start and end at once, and only a count the
//! system granted goes to rayon.
//!
//! Under an address-space cap the count is first bounded by the room the cap leaves
//! ([`room_for`]: half of what the process has not yet mapped, at a stack and some slack a
//! thread): a thread that starts at the cap's edge dies in the C library, not with an error
//! this code can see (its alternative signal stack refused: a panic message and a thread
//! less; its thread-locals' destructor records refused: `Fatal glibc error`, the process
//! aborted). The probe threads themselves started at that edge, and the debug build of the
//! e2e test above failed so in 1-2 runs of 20.
//!
//! Each worker also takes, before any work, the thread-local that rayon's work stealing first
//! touches (crossbeam-epoch's handle). glibc allocates the record of a thread-local's
//! destructor with its own `calloc`, outside Rust's allocator, and ends the process with
//! `Fatal glibc error: failed to register TLS destructor: out of memory` where that fails: a
//! worker that first looked for work once the stage had used its memory up died so instead of
//! the stage's `out of memory` error (the same e2e test, now and then, on a loaded machine).

use std::sync::mpsc;

/// Start rayon's global pool with the threads it would start itself (`RAYON_NUM_THREADS`, else
/// one a core), or, where the system refuses that many, the most of the halvings it grants.
/// Returns the threads started, or `cannot start a worker thread: <the system's answer>`. Call
/// it before anything uses rayon.
pub fn start() -> anyhow::Result<usize> {
    let refused = |e: &dyn std::fmt::Display| anyhow::anyhow!("cannot start a worker thread: {e}");
    let mut want = room_for(wanted());
    loop {
        match try_spawn(want) {
            Ok(()) => break,
            Err(e) if want <= 1 => return Err(refused(&e)),
            Err(_) => want = (want / 2).max(1),
        }
    }
    match rayon::ThreadPoolBuilder::new()
        .num_threads(want)
        .start_handler(|_| {
            crossbeam_epoch::is_pinned();
        })
        .build_global()
    {
        Ok(()) => {
            // Every worker has run its start handler once it has run this.
            rayon::broadcast(|_| ());
            Ok(want)
        }
        // Started already (rayon was used before): the pool is there.
        Err(e) if e.to_string().contains("already") => Ok(rayon::current_num_threads()),
        Err(e) => Err(refused(&e)),
    }
}

/// Whether the system grants `n` threads at once (with the default stack, as rayon's): each
/// waits until all are there or one was refused, then ends.
fn try_spawn(n: usize) -> std::io::Result<()> {
    let mut held = Vec::with_capacity(n);
    let mut refused = None;
    for _ in 0..n {
        let (tx, rx) = mpsc::channel::<()>();
        match std::thread::Builder::new().spawn(move || {
            let _ = rx.recv();
        }) {
            Ok(handle) => held.push((tx, handle)),
            Err(e) => {
                refused = Some(e);
                break;
            }
        }
    }
    for (tx, handle) in held {
        drop(tx);
        let _ = handle.join();
    }
    refused.map_or(Ok(()), Err)
}

/// At most `want` threads, fewer where an address-space cap (`ulimit -v`) leaves no room for
/// them: as many as half the address space the process has yet to map holds at a stack
/// (`RUST_MIN_STACK`, else 2 MiB, as rayon's) plus [`THREAD_SLACK`] each, and at least one.
/// Without a cap, or where the cap or the mapped size cannot be read (not Linux), `want`.
fn room_for(want: usize) -> usize {
    let (Some(cap), Some(used)) = (address_space_cap(), address_space_used()) else {
        return want;
    };
    let stack = std::env::var("RUST_MIN_STACK")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .unwrap_or(2 << 20);
    let room = cap.saturating_sub(used) / 2;
    let fit = room / (stack + THREAD_SLACK);
    (fit as usize).clamp(1, want.max(1))
}

/// Per thread beyond its stack: the guard page, the alternative signal stack, the
/// thread-locals and their destructor records, the allocator's per-thread state.
const THREAD_SLACK: u64 = 256 << 10;

/// The soft limit on the address space in bytes (`Max address space` in `/proc/self/limits`),
/// or None where there is none or it cannot be read.
fn address_space_cap() -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = limits
        .lines()
        .find(|l| l.starts_with("Max address space"))?;
    line["Max address space".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The address space mapped now in bytes (`VmSize` in `/proc/self/status`).
fn address_space_used() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kb: u64 = status
        .lines()
        .find(|l| l.starts_with("VmSize:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()?;
    Some(kb << 10)
}

/// The threads rayon starts by default.
fn wanted() -> usize {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Without a cap ("unlimited" does not parse) every wanted thread is kept; the mapped size
    /// reads where /proc does.
    #[cfg(target_os = "linux")]
    #[test]
    fn the_room_is_read_from_proc() {
        assert!(address_space_used().is_some_and(|b| b > 0));
        if address_space_cap().is_none() {
            assert_eq!(room_for(64), 64);
        }
        assert_eq!(room_for(1), 1);
    }
}
