//! pc-inspect's library: open any artifact through its kind's checked reader, describe it,
//! verify it, export debug views as PLY.

mod export;
mod stats;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use pc_artifact::octree::OctreeFile;
use pc_artifact::photons::PhotonsFile;
use pc_artifact::radiosity::RadiosityFile;
use pc_artifact::vmap::VmapFile;
use pc_artifact::{Artifact, ArtifactError, ArtifactKind};

pub use export::{export_ply, export_vmap_links, View};

/// What pc-inspect can fail on; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum InspectError {
    #[error(transparent)]
    Artifact(#[from] ArtifactError),
    /// A debug view could not be written.
    #[error("{}: cannot write the file", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// What was asked does not apply (a node outside the octree, a V-map of another octree).
    #[error("{0}")]
    Usage(String),
}

/// An artifact of any kind, opened and checked by its kind's reader (checksums, structure).
pub enum Opened {
    Octree(OctreeFile),
    Vmap(VmapFile),
    Photons(PhotonsFile),
    Radiosity(RadiosityFile),
}

impl Opened {
    /// Open the artifact at `path`, whatever its kind, and check it.
    pub fn open(path: &Path) -> Result<Opened, ArtifactError> {
        let a = Artifact::open(path)?;
        Ok(match a.kind() {
            ArtifactKind::Octree => Opened::Octree(OctreeFile::from_artifact(a)?),
            ArtifactKind::Vmap => Opened::Vmap(VmapFile::from_artifact(a)?),
            ArtifactKind::Photons => Opened::Photons(PhotonsFile::from_artifact(a)?),
            ArtifactKind::Radiosity => Opened::Radiosity(RadiosityFile::from_artifact(a)?),
        })
    }

    /// The container underneath.
    pub fn artifact(&self) -> &Artifact {
        match self {
            Opened::Octree(f) => f.artifact(),
            Opened::Vmap(f) => f.artifact(),
            Opened::Photons(f) => f.artifact(),
            Opened::Radiosity(f) => f.artifact(),
        }
    }
}

/// The header, provenance (metadata as JSON), and the section table.
pub fn describe(a: &Artifact) -> String {
    let h = a.header();
    let mut s = String::new();
    let _ = writeln!(s, "file        {}", a.path().display());
    let _ = writeln!(
        s,
        "kind        {} (format version {})",
        h.kind, h.format_version
    );
    let _ = writeln!(s, "made by     {} {}", h.stage, h.stage_version);
    let _ = writeln!(s, "key         {}", h.key);
    let _ = writeln!(s, "created     {} (unix seconds)", h.created_unix);
    let _ = writeln!(s, "size        {} bytes", h.file_len);
    let _ = writeln!(
        s,
        "sections    {:<12} {:>12} {:>14} {:>6} {:>18}",
        "name", "offset", "bytes", "elem", "checksum"
    );
    for sec in a.sections() {
        let _ = writeln!(
            s,
            "            {:<12} {:>12} {:>14} {:>6} {:>18}",
            sec.name,
            sec.offset,
            sec.len,
            sec.elem_size,
            format!("{:016x}", sec.checksum)
        );
    }
    s
}

/// The metadata blob as pretty JSON (every kind stores MessagePack with named fields).
pub fn metadata_json(a: &Artifact) -> Result<String, ArtifactError> {
    let v: serde_json::Value =
        rmp_serde::from_slice(a.metadata_bytes()).map_err(|e| ArtifactError::Metadata {
            path: a.path().to_path_buf(),
            msg: format!("not readable MessagePack: {e}"),
        })?;
    Ok(serde_json::to_string_pretty(&v).unwrap_or_default())
}

/// Kind-specific statistics.
pub fn statistics(o: &Opened) -> String {
    match o {
        Opened::Octree(f) => stats::octree(f),
        Opened::Vmap(f) => stats::vmap(f),
        Opened::Photons(f) => stats::photons(f),
        Opened::Radiosity(f) => stats::radiosity(f),
    }
}

/// Full verification: the checksums and the kind's structure (checked when it was opened) and,
/// for an octree, point location of every splat, which must find the leaf that owns it.
pub fn verify(o: &Opened) -> Result<String, ArtifactError> {
    let path = o.artifact().path().display();
    Ok(match o {
        Opened::Octree(f) => {
            let v = f.view();
            for (i, sp) in v.splats.iter().enumerate() {
                let loc = v.locate(sp.position).ok_or_else(|| {
                    f.artifact()
                        .invalid(format!("splat {i} lies outside the root cube"))
                })?;
                if loc.slot != v.splat_leaf[i] {
                    return Err(f.artifact().invalid(format!(
                        "splat {i}: point location finds node {}, the table says {}",
                        loc.slot, v.splat_leaf[i]
                    )));
                }
                if !v.leaf(loc.node).0.contains(&(i as u32)) {
                    return Err(f
                        .artifact()
                        .invalid(format!("splat {i} is not in its leaf's own range")));
                }
            }
            format!(
                "{path}: ok (checksums, structure, {} splats located)",
                v.splats.len()
            )
        }
        Opened::Vmap(f) => format!(
            "{path}: ok (checksums, CSR structure, {} links)",
            f.view().links.len()
        ),
        Opened::Photons(f) => {
            let v = f.view();
            format!(
                "{path}: ok (checksums, {} photons, deposit on {} splats)",
                v.photons.len(),
                v.deposit.len()
            )
        }
        Opened::Radiosity(f) => {
            let v = f.view();
            format!(
                "{path}: ok (checksums, {} splats finite and non-negative, {} residuals)",
                v.radiance.len(),
                v.residuals.len()
            )
        }
    })
}
