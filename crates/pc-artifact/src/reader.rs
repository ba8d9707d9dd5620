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
/// The first index `i` of `v` where `bad(i, &v[i])` holds: in parallel over runs of records,
/// each run searched in order (so the checks of a large artifact use every core, and the loop
/// inside a run stays a plain one the compiler can vectorise).
pub(crate) fn first_where<T: Sync>(
    v: &[T],
    bad: impl Fn(usize, &T) -> bool + Sync,
) -> Option<usize> {
    use rayon::prelude::*;
    const RUN: usize = 1 << 16;
    v.par_chunks(RUN).enumerate().find_map_first(|(c, run)| {
        let at = c * RUN;
        run.iter()
            .enumerate()
            .position(|(k, x)| bad(at + k, x))
            .map(|k| at + k)
    })
}

/// Whether `bad` holds for any record of `v` ([`first_where`]).
pub(crate) fn any_where<T: Sync>(v: &[T], bad: impl Fn(&T) -> bool + Sync) -> bool {
    first_where(v, |_, x| bad(x)).is_some()
}

pub(crate) fn is_csr(offsets: &[u32], rows: usize, len: usize) -> bool {
    offsets.len() == rows + 1
        && offsets.first() == Some(&0)
        && first_where(offsets, |i, &x| i > 0 && offsets[i - 1] > x).is_none()
        && offsets.last().map(|&x| x as usize) == Some(len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel search names the first bad record, whichever run it lies in, and finds
    /// none where there is none.
    #[test]
    fn first_where_names_the_first_bad_record() {
        let v: Vec<u32> = (0..300_000).collect();
        for bad in [0usize, 1, 65_535, 65_536, 200_001, 299_999] {
            let got = first_where(&v, |i, &x| {
                assert_eq!(i as u32, x);
                i >= bad && i % 7 == bad % 7
            });
            assert_eq!(got, Some(bad));
        }
        assert_eq!(first_where(&v, |_, &x| x > 300_000), None);
        assert!(any_where(&v, |&x| x == 123_456));
        assert!(!any_where(&v[..0], |_| true));
    }
}
