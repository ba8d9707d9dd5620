//! CPU against GPU (filled in with the WGSL twin).
