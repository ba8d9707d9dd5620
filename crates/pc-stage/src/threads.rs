//! The worker threads, started before any work so that a system that refuses them gives a
//! stage fewer threads or a clear error, not rayon's panic. Under an address-space cap
//! (`ulimit -v`) on a machine with many cores, rayon's first parallel loop used to panic with
//! `The global thread pool has not been initialized` (exit code 101): each thread reserves its
//! stack, and 16 of them did not fit where 2 did (seen on a 16-core host in the e2e test
//! `a_stage_out_of_memory_says_so_and_keeps_what_was_published`).

/// Start rayon's global pool with the threads it would start itself (`RAYON_NUM_THREADS`, else
/// one a core); where the system refuses, halve the count down to one. Returns the threads
/// started, or the system's answer to a single thread. Call it before anything uses rayon.
pub fn start() -> Result<usize, String> {
    let mut want = wanted();
    loop {
        match rayon::ThreadPoolBuilder::new()
            .num_threads(want)
            .build_global()
        {
            Ok(()) => return Ok(want),
            // Started already (rayon was used before): the pool is there.
            Err(e) if e.to_string().contains("already") => return Ok(want),
            Err(e) if want <= 1 => return Err(e.to_string()),
            Err(_) => want = (want / 2).max(1),
        }
    }
}

/// The threads rayon starts by default.
fn wanted() -> usize {
    std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}
