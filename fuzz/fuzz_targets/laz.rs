//! libFuzzer target: pc_fuzz::targets::scan on .laz files.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pc_fuzz::targets::scan(pc_fuzz::targets::ScanFormat::Laz, data);
});
