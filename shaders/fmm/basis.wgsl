// requires:
// Stand-in for the generated basis code of the FMM kernels (shaders/fmm/fmm.wgsl), so that they
// validate standalone: the sizes for order 4 and empty bodies of the generated functions.
// crates/pc-fmm/src/gpu.rs (`basis_wgsl`) composes in its place the constants and functions of
// the run's order, written out term by term from pc_fmm::expansion::Basis: every loop over
// multi-indices or translation terms unrolled, so that the expansions live in registers and the
// kernels stay within llvmpipe's budget of 65535 loop iterations per shader invocation group.
// A test there holds this file's declarations to the generated ones.
//
// What each generated function computes (CPU twin in pc_fmm::expansion), on the private arrays
// of fmm.wgsl (`pw` monomials, `ka`/`kg` kernel coefficients, `ex` the expansion accumulated):
//   gen_monomials      pw = v^α                                      Basis::monomials
//   gen_kernel_coeffs  ka, kg = a_γ, g_γ of G about r                kernel_coeffs
//   gen_p2m            ex[α] += pw[α] q                              p2m
//   gen_m2m            ex += shift of the child moments at src       m2m
//   gen_m2l            ex[β] += c f g_{α+β} M[α], M at src           m2l
//   gen_p2l            ex[β] += (−1)^{|β|} f g_β q                   CpuFmm::interact (P2L)
//   gen_l2l            ex += re-expansion of the parent local at src l2l
//   gen_l2p            Σ pw[α] L[α], L at src                        l2p
//   gen_m2p            Σ g_α M[α], M at src                          CpuFmm::downward (M2P)
//   gen_load_locals, gen_store_locals, gen_store_multipole, gen_add_spare, gen_store_spare:
//                      ex from or to the local/multipole expansion at src/dst, ex plus or to
//                      the spare expansion at src/dst.

const ORDER: u32 = 4u;
const NP: u32 = 35u;
const NP9: u32 = 315u;

fn gen_monomials(v: vec3<f32>) {}
fn gen_kernel_coeffs(r: vec3<f32>) {}
fn gen_p2m(q: mat3x3<f32>) {}
fn gen_m2m(src: u32) {}
fn gen_m2l(src: u32, f: f32) {}
fn gen_p2l(q: mat3x3<f32>, f: f32) {}
fn gen_l2l(src: u32) {}
fn gen_l2p(src: u32) -> mat3x3<f32> { return mat3x3<f32>(); }
fn gen_m2p(src: u32) -> mat3x3<f32> { return mat3x3<f32>(); }
fn gen_load_locals(src: u32) {}
fn gen_store_locals(dst: u32) {}
fn gen_store_multipole(dst: u32) {}
fn gen_add_spare(src: u32) {}
fn gen_store_spare(dst: u32) {}
