//! `cargo xtask bench [--sizes a,b] [--runs N] [--write] [--only octree|rays|caustics|fmm|chain|render|scale|mitsuba|gpu]
//! [--peer embree]`:
//! the options and which benchmarks run; each benchmark is in its own module. With
//! `PCGI_BENCH_BIN_DIR` set, the benchmarks run the release binaries found there instead of
//! building them (a machine without a Rust toolchain, such as a lent GPU machine).

mod caustics;
mod chain;
mod fmm;
mod gpu;
mod harness;
mod mitsuba;
mod octree;
mod peer;
mod rays;
mod render;
mod scale;
mod table;

use anyhow::{bail, Context, Result};

use crate::build_release;
use table::write_bench_block;

/// The options of `cargo xtask bench`.
struct Options {
    sizes: Vec<usize>,
    runs: usize,
    write: bool,
    only: Option<String>,
    /// No `--sizes`: each benchmark picks its own default sizes.
    default_sizes: bool,
    /// `--peer embree`: with `--only rays`, trace the same rays with Embree too.
    peer: Option<String>,
}

impl Options {
    fn parse(args: &[String]) -> Result<Options> {
        let mut o = Options {
            sizes: vec![1_000_000, 4_000_000],
            runs: 3,
            write: false,
            only: None,
            default_sizes: !args.iter().any(|a| a == "--sizes"),
            peer: None,
        };
        let mut it = args.iter();
        while let Some(a) = it.next() {
            match a.as_str() {
                "--sizes" => {
                    o.sizes = it
                        .next()
                        .context("--sizes needs a list")?
                        .split(',')
                        .map(parse_count)
                        .collect::<Result<_>>()?
                }
                "--runs" => {
                    o.runs = it.next().context("--runs needs a number")?.parse()?;
                    if o.runs == 0 {
                        bail!("bench: --runs must be at least 1");
                    }
                }
                "--write" => o.write = true,
                "--peer" => match it.next().map(String::as_str) {
                    Some("embree") => o.peer = Some("embree".into()),
                    other => bail!("bench: --peer takes `embree`, not {other:?}"),
                },
                "--only" => {
                    o.only = Some(
                        it.next()
                            .context(
                                "--only needs octree, rays, caustics, fmm, chain, render, scale, mitsuba or gpu",
                            )?
                            .clone(),
                    )
                }
                other => bail!("bench: unknown option `{other}`"),
            }
        }
        Ok(o)
    }

    /// `--sizes`, or `default` when it was not given.
    fn sizes_or(&self, default: &[usize]) -> Vec<usize> {
        if self.default_sizes {
            default.to_vec()
        } else {
            self.sizes.clone()
        }
    }
}

/// `cargo xtask bench`: one benchmark (`--only`), or all of them.
pub(crate) fn bench(args: &[String]) -> Result<()> {
    let o = Options::parse(args)?;
    let (runs, write) = (o.runs, o.write);
    if o.peer.is_some() && o.only.as_deref() != Some("rays") {
        bail!("bench: --peer embree goes with --only rays");
    }
    match o.only.as_deref() {
        Some("rays") if o.peer.is_some() => {
            let bin = build_release(&["pc-sample", "pc-octree", "pc-raybench"])?;
            match peer::build_harness()? {
                Some(harness) => peer::bench(&bin, &harness, &o.sizes, runs, write),
                None => octree_or_rays("rays", &o.sizes, runs, write),
            }
        }
        Some("caustics") => caustics::bench(&o.sizes_or(&[1_000_000]), runs, write),
        Some("chain") => chain::bench(&o.sizes_or(&[1_000_000]), write),
        Some("render") => render::bench(runs, write),
        // Not part of the full run: it installs Mitsuba into a virtual environment.
        Some("mitsuba") => mitsuba::bench(write),
        Some("fmm") => fmm::bench(&o.sizes_or(&[100_000, 1_000_000, 4_000_000]), runs, write),
        Some(what @ ("octree" | "rays")) => octree_or_rays(what, &o.sizes, runs, write),
        // Not part of the full run: only a machine with a GPU has anything to measure.
        Some("gpu") => gpu::bench(&o.sizes_or(&[1_000_000]), write),
        // Not part of the full run: the 20M scan alone takes most of an hour on two cores.
        Some("scale") => scale::bench(&o.sizes_or(&[1_000_000, 4_000_000, 20_000_000]), write),
        None => {
            // Every benchmark: the stages' own (the radiosity solve at 100k, 1M and 4M), then the
            // whole chain at 1M splats and the renderer on the default scene.
            for what in ["octree", "rays"] {
                octree_or_rays(what, &o.sizes, runs, write)?;
            }
            let small = o.sizes_or(&[1_000_000]);
            caustics::bench(&small, runs, write)?;
            fmm::bench(&o.sizes_or(&[100_000, 1_000_000, 4_000_000]), runs, write)?;
            chain::bench(&small, write)?;
            render::bench(runs, write)
        }
        Some(other) => {
            bail!("bench: --only takes octree, rays, caustics, fmm, chain, render, scale, mitsuba or gpu, not `{other}`")
        }
    }
}

/// `--only octree` or `--only rays` (`what`): the one benchmark's rows, then both tables printed
/// (the other one empty), and with `write` the measured one put in BENCHMARKS.md.
fn octree_or_rays(what: &str, sizes: &[usize], runs: usize, write: bool) -> Result<()> {
    let bin = build_release(&["pc-sample", "pc-octree", "pc-raybench"])?;
    let (rows, ray_rows) = if what == "rays" {
        (Vec::new(), rays::rows(&bin, sizes, runs)?)
    } else {
        (octree::rows(&bin, sizes, runs)?, Vec::new())
    };
    let table = octree::table(sizes, runs, &rows);
    let ray_table = rays::table(sizes, runs, &ray_rows);
    println!("\n{table}\n{ray_table}");
    if write && !ray_rows.is_empty() {
        write_bench_block(
            "rays",
            "Ray traversal (pc-tree, used by pc-raytrace)",
            &ray_table,
        )?;
    }
    if write && !rows.is_empty() {
        write_bench_block("octree", "pc-octree build", &table)?;
    }
    Ok(())
}

/// A count such as `20000`, `100k` or `1.5M`.
fn parse_count(s: &str) -> Result<usize> {
    let s = s.trim();
    let (num, mul) = match s.chars().last() {
        Some('k' | 'K') => (&s[..s.len() - 1], 1_000.0),
        Some('m' | 'M') => (&s[..s.len() - 1], 1_000_000.0),
        _ => (s, 1.0),
    };
    Ok((num
        .parse::<f64>()
        .with_context(|| format!("`{s}` is not a count"))?
        * mul) as usize)
}
