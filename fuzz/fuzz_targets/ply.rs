//! libFuzzer target: pc_fuzz::targets::ply.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pc_fuzz::targets::ply(data);
});
