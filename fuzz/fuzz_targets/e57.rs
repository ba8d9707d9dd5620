//! libFuzzer target: pc_fuzz::targets::scan on .e57 files.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pc_fuzz::targets::scan(pc_fuzz::targets::ScanFormat::E57, data);
});
