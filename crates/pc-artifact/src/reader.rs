//! What every kind's checked reader shares: an opened container and its decoded metadata, both
//! checked once when the file was opened (the kind's own `open` in `octree.rs`, `vmap.rs`,
//! `photons.rs`, `radiosity.rs`).

use std::path::Path;

use crate::{Artifact, ArtifactError, Key};

/// An artifact of one kind, opened and checked by its kind's reader; `M` is the kind's metadata
/// ([`crate::octree::OctreeFile`] is `Checked<OctreeMeta>`, and so on). The kind adds `view()`,
/// its checked sections.
#[derive(Debug)]
pub struct Checked<M> {
    pub(crate) art: Artifact,
    pub(crate) meta: M,
}

impl<M> Checked<M> {
    /// The decoded metadata.
    pub fn meta(&self) -> &M {
        &self.meta
    }

    /// The key in the header.
    pub fn key(&self) -> Key {
        self.art.key()
    }

    /// The file it was opened from.
    pub fn path(&self) -> &Path {
        self.art.path()
    }

    /// The container underneath, for tools that print headers and sections.
    pub fn artifact(&self) -> &Artifact {
        &self.art
    }
}

impl Artifact {
    /// [`ArtifactError::Stale`] for this artifact: made from something else than it is used
    /// with (`why`), `rerun` says what to rerun.
    pub fn stale(&self, why: impl Into<String>, rerun: &str) -> ArtifactError {
        ArtifactError::Stale {
            path: self.path().to_path_buf(),
            what: self.kind().what(),
            why: why.into(),
            rerun: rerun.to_string(),
        }
    }
}

/// Whether `offsets` is a CSR index of `rows` rows over `len` entries: one start per row plus
/// one, from 0, non-decreasing, ending at `len`.
pub(crate) fn is_csr(offsets: &[u32], rows: usize, len: usize) -> bool {
    offsets.len() == rows + 1
        && offsets.first() == Some(&0)
        && offsets.windows(2).all(|w| w[0] <= w[1])
        && offsets.last().map(|&x| x as usize) == Some(len)
}
