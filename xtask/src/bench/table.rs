//! The benchmarks' tables: the machine and date they name, and putting them in BENCHMARKS.md.

use std::process::Command;

use anyhow::Result;

use crate::root;

/// The CPU, its cores and the memory, as the tables name the machine.
pub(super) fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            m.lines()
                .next()
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|k| k.parse::<u64>().ok())
        })
        .map(|kb| format!("{:.0} GiB", kb as f64 / 1048576.0))
        .unwrap_or_default();
    format!("{cpu}, {cores} cores, {mem}")
}

/// Today's date (UTC), `YYYY-MM-DD`.
pub(super) fn today() -> String {
    Command::new("date")
        .args(["-u", "+%Y-%m-%d"])
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// The sizes as `--sizes` takes them: `1000000,4000000`.
pub(super) fn sizes_arg(sizes: &[usize]) -> String {
    sizes
        .iter()
        .map(|n| n.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

/// Print a benchmark's table, and with `write` put it in BENCHMARKS.md ([`write_bench_block`]).
pub(super) fn publish(name: &str, heading: &str, table: &str, write: bool) -> Result<()> {
    println!("\n{table}");
    if write {
        write_bench_block(name, heading, table)?;
    }
    Ok(())
}

/// Replace the block between `<!-- bench:NAME:begin/end -->` in BENCHMARKS.md with `table`
/// (appended under `heading` the first time).
pub(super) fn write_bench_block(name: &str, heading: &str, table: &str) -> Result<()> {
    let path = root().join("BENCHMARKS.md");
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    let (begin, end) = (
        format!("<!-- bench:{name}:begin -->"),
        format!("<!-- bench:{name}:end -->"),
    );
    let new = match (text.find(&begin), text.find(&end)) {
        (Some(b), Some(e)) if b < e => format!("{}{begin}\n{table}{}", &text[..b], &text[e..]),
        _ => format!("{text}\n## {heading}\n\n{begin}\n{table}{end}\n"),
    };
    std::fs::write(&path, new)?;
    println!("xtask: updated {}", path.display());
    Ok(())
}
