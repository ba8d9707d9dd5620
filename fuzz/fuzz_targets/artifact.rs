//! libFuzzer target: pc_fuzz::targets::artifact.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pc_fuzz::targets::artifact(data);
});
