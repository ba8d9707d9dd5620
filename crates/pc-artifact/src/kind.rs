//! The kinds of artifact the pipeline stages write, as recorded in every artifact header.

use std::fmt;

use serde::{Deserialize, Serialize};

/// What an artifact holds, stored as a `u32` in the header so that a stage refuses to read
/// another stage's output as its own.
///
/// The numbers are part of the file format: never renumber a kind, only add new ones.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u32)]
pub enum ArtifactKind {
    /// The point-cloud octree.
    Octree = 1,
    /// The visibility map between octree cells.
    Vmap = 2,
    /// The photon map.
    Photons = 3,
    /// The solved radiosity per cell.
    Radiosity = 4,
}

impl ArtifactKind {
    /// Every kind, in the order of their numbers.
    pub const ALL: [ArtifactKind; 4] = [
        ArtifactKind::Octree,
        ArtifactKind::Vmap,
        ArtifactKind::Photons,
        ArtifactKind::Radiosity,
    ];

    /// The lowercase name used in messages and file names ("octree", "vmap", ...).
    pub fn name(self) -> &'static str {
        match self {
            ArtifactKind::Octree => "octree",
            ArtifactKind::Vmap => "vmap",
            ArtifactKind::Photons => "photons",
            ArtifactKind::Radiosity => "radiosity",
        }
    }

    /// The stage that makes this kind ("pc-octree", ...).
    pub fn stage(self) -> &'static str {
        match self {
            ArtifactKind::Octree => "pc-octree",
            ArtifactKind::Vmap => "pc-vmap",
            ArtifactKind::Photons => "pc-caustics",
            ArtifactKind::Radiosity => "pc-fmm",
        }
    }

    /// What the kind holds, in words for messages ("octree", "V-map", "photon map",
    /// "radiosity").
    pub fn what(self) -> &'static str {
        match self {
            ArtifactKind::Octree => "octree",
            ArtifactKind::Vmap => "V-map",
            ArtifactKind::Photons => "photon map",
            ArtifactKind::Radiosity => "radiosity",
        }
    }

    /// The number stored in the header.
    pub fn as_u32(self) -> u32 {
        self as u32
    }

    /// The kind with the given header number, or `None` for a number this build does not know.
    pub fn from_u32(value: u32) -> Option<ArtifactKind> {
        ArtifactKind::ALL.into_iter().find(|k| k.as_u32() == value)
    }

    /// The kind with the given lowercase name, or `None`.
    pub fn from_name(name: &str) -> Option<ArtifactKind> {
        ArtifactKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

impl fmt::Display for ArtifactKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_and_names_round_trip() {
        for kind in ArtifactKind::ALL {
            assert_eq!(ArtifactKind::from_u32(kind.as_u32()), Some(kind));
            assert_eq!(ArtifactKind::from_name(kind.name()), Some(kind));
            assert_eq!(kind.to_string(), kind.name());
        }
        assert_eq!(ArtifactKind::from_u32(0), None);
        assert_eq!(ArtifactKind::from_u32(5), None);
        assert_eq!(ArtifactKind::Octree as u32, 1);
        assert_eq!(ArtifactKind::Radiosity as u32, 4);
    }

    #[test]
    fn serde_uses_the_lowercase_name() {
        let bytes = rmp_serde::to_vec(&ArtifactKind::Photons).unwrap();
        let name: String = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(name, "photons");
        let back: ArtifactKind = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(back, ArtifactKind::Photons);
    }
}
