//! The fuzzing targets in `cargo test`: a bounded number of inputs per target, derived from the
//! seeds with a fixed seed, so every run tries the same cases. `PC_FUZZ_CASES=N` tries N per
//! target (and `PC_FUZZ_SEED` another sequence); a failing case is printed so it can be kept.

use pc_fuzz::mutate::Mutator;
use pc_fuzz::seeds::seeds;
use pc_fuzz::targets::{self, Kind};

fn cases() -> usize {
    std::env::var("PC_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200)
}

fn seed(target: u64) -> u64 {
    let base: u64 = std::env::var("PC_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x5eed);
    base ^ target.wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// Runs `target` on `cases()` inputs; on a panic, prints the case's input first. Returns how
/// many inputs the target accepted (a fuzzer whose inputs are all refused never reaches the
/// code behind the readers).
fn run(
    name: &str,
    target_seed: u64,
    mut input: impl FnMut(&mut Mutator) -> Vec<u8>,
    target: impl Fn(&[u8]) -> bool,
) -> usize {
    let mut m = Mutator::new(seed(target_seed));
    let mut accepted = 0;
    for case in 0..cases() {
        let data = input(&mut m);
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| target(&data)));
        match r {
            Ok(a) => accepted += a as usize,
            Err(e) => {
                eprintln!(
                    "{name}: case {case} failed; input ({} bytes): {:02x?}",
                    data.len(),
                    &data[..data.len().min(4096)]
                );
                std::panic::resume_unwind(e);
            }
        }
    }
    println!("{name}: {accepted} of {} inputs accepted", cases());
    accepted
}

#[test]
fn ply_models() {
    let s = seeds();
    let accepted = run(
        "ply",
        1,
        |m| {
            let base = &s.plys[m.below(s.plys.len())];
            m.bytes(base)
        },
        targets::ply,
    );
    assert!(accepted > 0, "no mutated model was accepted");
}

/// The scan readers: mutated real files of each format.
#[test]
fn scan_models() {
    use pc_fuzz::seeds::scans;
    use targets::ScanFormat;
    for (i, (format, ext)) in [
        (ScanFormat::Las, ".las"),
        (ScanFormat::Laz, ".laz"),
        (ScanFormat::E57, ".e57"),
    ]
    .into_iter()
    .enumerate()
    {
        let bases = scans(ext);
        let accepted = run(
            ext,
            20 + i as u64,
            |m| {
                let base = bases[m.below(bases.len())];
                m.bytes(base)
            },
            |d| targets::scan(format, d),
        );
        assert!(accepted > 0, "no mutated {ext} file was accepted");
    }
}

/// The checksums the E57 target recomputes are the ones real files carry.
#[test]
fn e57_checksums_are_those_of_real_files() {
    for (name, bytes) in pc_fuzz::seeds::SCANS {
        if name.ends_with(".e57") {
            assert_eq!(&targets::e57_checksums(bytes)[..], *bytes, "{name}");
        }
    }
}

#[test]
fn pipeline_configs() {
    let s = seeds();
    let accepted = run(
        "config",
        2,
        |m| m.text(&s.config).into_bytes(),
        targets::config,
    );
    assert!(accepted > 0, "no mutated config was accepted");
}

#[test]
fn artifact_files_as_bytes() {
    let s = seeds();
    let all = [&s.octree, &s.vmap, &s.photons, &s.radiosity];
    run(
        "artifact",
        3,
        |m| {
            let base = all[m.below(all.len())];
            m.bytes(base)
        },
        targets::artifact,
    );
}

fn patches(m: &mut Mutator) -> Vec<u8> {
    let n = 1 + m.below(6);
    (0..n * 6).map(|_| m.below(256) as u8).collect()
}

#[test]
fn octree_sections_patched() {
    let accepted = run("octree", 4, patches, |d| targets::patched(Kind::Octree, d));
    assert!(accepted > 0, "no patched octree was accepted");
}

#[test]
fn vmap_sections_patched() {
    let accepted = run("vmap", 5, patches, |d| targets::patched(Kind::Vmap, d));
    assert!(accepted > 0, "no patched vmap was accepted");
}

#[test]
fn photon_map_sections_patched() {
    let accepted = run("photons", 6, patches, |d| {
        targets::patched(Kind::Photons, d)
    });
    assert!(accepted > 0, "no patched photons was accepted");
}

#[test]
fn radiosity_sections_patched() {
    let accepted = run("radiosity", 7, patches, |d| {
        targets::patched(Kind::Radiosity, d)
    });
    assert!(accepted > 0, "no patched radiosity was accepted");
}
