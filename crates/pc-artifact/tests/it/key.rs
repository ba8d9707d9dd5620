//! Artifact keys: deterministic, sensitive to every input, and stable across builds.

use pc_artifact::{Key, KeyHasher};
use serde::Serialize;

#[derive(Serialize)]
struct Params {
    max_points_per_cell: u32,
    radius: f32,
    scene: &'static str,
}

fn params() -> Params {
    Params {
        max_points_per_cell: 16,
        radius: 0.25,
        scene: "cornell",
    }
}

fn full_key(file: &std::path::Path, p: &Params, input: &Key) -> Key {
    let mut h = KeyHasher::new();
    h.update_str("pc-octree")
        .update_serialize(p)
        .update_key(input);
    h.update_file(file).unwrap();
    h.finish()
}

#[test]
fn deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("scene.ply");
    std::fs::write(&file, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
    let input = KeyHasher::new().update_str("upstream").finish();
    assert_eq!(
        full_key(&file, &params(), &input),
        full_key(&file, &params(), &input)
    );
}

#[test]
fn golden_value() {
    // Pinned: a change here changes every key and makes every existing artifact stale.
    let key = KeyHasher::new()
        .update_str("pcgi")
        .update(&[1, 2, 3])
        .finish();
    let again = KeyHasher::new()
        .update_str("pcgi")
        .update(&[1, 2, 3])
        .finish();
    assert_eq!(key, again);
    assert_eq!(key.to_string(), GOLDEN);
}

const GOLDEN: &str = "89aecf38769bb3924f980dc7a349e87c";

#[test]
fn sensitive_to_every_input() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("scene.ply");
    std::fs::write(&file, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
    let input = KeyHasher::new().update_str("upstream").finish();
    let base = full_key(&file, &params(), &input);

    let mut p = params();
    p.radius = 0.250_001;
    assert_ne!(full_key(&file, &p, &input), base, "a parameter");
    let mut p = params();
    p.scene = "cornel";
    assert_ne!(full_key(&file, &p, &input), base, "a string parameter");

    let other_input = KeyHasher::new().update_str("upstream2").finish();
    assert_ne!(
        full_key(&file, &params(), &other_input),
        base,
        "an input key"
    );

    std::fs::write(&file, b"ply\nformat ascii 1.0\nend_headex\n").unwrap();
    assert_ne!(
        full_key(&file, &params(), &input),
        base,
        "one byte of a file"
    );
    std::fs::write(&file, b"ply\nformat ascii 1.0\nend_header\n\n").unwrap();
    assert_ne!(full_key(&file, &params(), &input), base, "a file's length");
}

#[test]
fn order_and_framing_matter() {
    let a = KeyHasher::new().update_str("a").update_str("b").finish();
    let b = KeyHasher::new().update_str("b").update_str("a").finish();
    assert_ne!(a, b);
    let ab_c = KeyHasher::new().update_str("ab").update_str("c").finish();
    let a_bc = KeyHasher::new().update_str("a").update_str("bc").finish();
    assert_ne!(ab_c, a_bc);
    let s1 = KeyHasher::new().update_serialize(&("ab", "c")).finish();
    let s2 = KeyHasher::new().update_serialize(&("a", "bc")).finish();
    assert_ne!(s1, s2);
}

#[test]
fn a_file_hashes_like_its_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("big.bin");
    let bytes: Vec<u8> = (0..200_000u32).map(|i| (i * 7 % 251) as u8).collect();
    std::fs::write(&file, &bytes).unwrap();
    let mut h = KeyHasher::new();
    h.update_file(&file).unwrap();
    assert_eq!(h.finish(), KeyHasher::new().update(&bytes).finish());
}

#[test]
fn a_missing_file_is_an_error_and_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = KeyHasher::new();
    h.update_str("x");
    let before = h.finish();
    assert!(h.update_file(dir.path().join("missing")).is_err());
    assert_eq!(h.finish(), before);
}

#[test]
fn hex_and_serde() {
    let key = KeyHasher::new().update_str("k").finish();
    let hex = key.to_string();
    assert_eq!(hex.len(), 32);
    assert!(hex
        .bytes()
        .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b)));
    assert_eq!(Key::from_hex(&hex), Some(key));
    let bytes = rmp_serde::to_vec(&key).unwrap();
    assert_eq!(rmp_serde::from_slice::<Key>(&bytes).unwrap(), key);
}
