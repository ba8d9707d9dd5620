//! libFuzzer target: pc_fuzz::targets::patched(Kind::Vmap): a valid vmap artifact's sections
//! patched and written again with valid checksums.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pc_fuzz::targets::patched(pc_fuzz::targets::Kind::Vmap, data);
});
