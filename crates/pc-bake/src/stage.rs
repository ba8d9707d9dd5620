//! The pc-bake stage: config + octree + radiosity (+ photon map) → the lit cloud.
//!
//! Its key covers the input artifacts' keys, the materials, the caustic estimate's parameters
//! and `[bake]`; it is written into the lit cloud, which is published whole (atomic rename).

use std::path::{Path, PathBuf};

use glam::DVec3;
use pc_artifact::octree::OctreeFile;
use pc_artifact::photons::PhotonMapFile;
use pc_artifact::radiosity::RadiosityFile;
use pc_artifact::{Artifact, ArtifactKind, Key, KeyHasher};
use pc_config::LoadedConfig;
use pc_raytrace::caustic::Caustics;
use pc_raytrace::stage::caustic_radius;
use pc_stage::{OptionalInput, Progress, Stage};

use crate::lit::lit_points;
use crate::write::{existing_key, write_lit};
use crate::BakeError;

pub const STAGE: &str = "pc-bake";
pub const STAGE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// pc-bake as its binary runs it.
pub struct BakeStage {
    pub cfg: LoadedConfig,
    pub octree: PathBuf,
    pub radiosity: PathBuf,
    pub photons: OptionalInput,
    pub output: PathBuf,
}

/// What one run made.
pub struct Summary {
    pub points: usize,
    pub origin: DVec3,
    /// Whether caustics were added.
    pub caustics: bool,
}

fn key_of(cfg: &LoadedConfig, octree: &Key, radiosity: &Key, photons: Option<&Key>) -> Key {
    let c = &cfg.config;
    let mut h = KeyHasher::new();
    h.update_str(STAGE)
        .update_str(STAGE_VERSION)
        .update_key(&pc_artifact::build_id())
        .update_key(octree)
        .update_key(radiosity);
    if let Some(k) = photons {
        h.update_str("photons").update_key(k);
    }
    h.update_serialize(&c.materials)
        .update_serialize(&(c.raytrace.caustic_radius, c.raytrace.caustic_k))
        .update_serialize(&c.bake);
    h.finish()
}

impl BakeStage {
    fn key_now(&self) -> Result<Key, BakeError> {
        let input = |path: &Path, kind| Artifact::input_key(path, kind);
        let photons = match self.photons.wanted() {
            true => Some(input(self.photons.path(), ArtifactKind::Photons)?),
            false => None,
        };
        Ok(key_of(
            &self.cfg,
            &input(&self.octree, ArtifactKind::Octree)?,
            &input(&self.radiosity, ArtifactKind::Radiosity)?,
            photons.as_ref(),
        ))
    }

    fn bake(&self, progress: &dyn Progress) -> Result<Summary, BakeError> {
        let octree = OctreeFile::open_without_walk(&self.octree)?;
        let materials = self.cfg.materials_for(&octree)?;
        let radiosity = RadiosityFile::open(&self.radiosity, &octree.id())?;
        let photons = match self.photons.wanted() {
            true => Some(PhotonMapFile::open(self.photons.path(), &octree.id())?),
            false => None,
        };
        let key = key_of(
            &self.cfg,
            &octree.key(),
            &radiosity.key(),
            photons.as_ref().map(|p| p.key()).as_ref(),
        );
        let view = octree.view();
        let rt = &self.cfg.config.raytrace;
        let caustics = photons
            .as_ref()
            .map(|p| p.view().photons)
            .filter(|p| !p.is_empty())
            .map(|p| Caustics::new(p, caustic_radius(rt, &view), rt.caustic_k));
        progress.phase("lighting the points");
        let origin = DVec3::from(octree.meta().origin);
        let points = lit_points(
            &view,
            origin,
            &materials,
            radiosity.view().radiance,
            caustics.as_ref(),
        );
        progress.phase("writing");
        write_lit(&self.output, &points, self.cfg.config.bake.exposure, &key).map_err(
            |source| BakeError::Write {
                path: self.output.clone(),
                source,
            },
        )?;
        Ok(Summary {
            points: points.len(),
            origin,
            caustics: caustics.is_some(),
        })
    }
}

impl Stage for BakeStage {
    const NAME: &'static str = STAGE;
    const DOING: &'static str = "baking the lit cloud";
    const KIND: Option<ArtifactKind> = None;
    type Made = Summary;
    type Error = BakeError;

    fn output(&self) -> &Path {
        &self.output
    }

    fn key(&self) -> Result<Key, BakeError> {
        self.key_now()
    }

    fn existing_key(&self) -> Option<Key> {
        existing_key(&self.output)
    }

    fn run(&self, progress: &dyn Progress) -> Result<Summary, BakeError> {
        self.bake(progress)
    }

    fn summary(&self, s: &Summary, seconds: f64) -> String {
        let caustics = if s.caustics { " with caustics" } else { "" };
        let o = s.origin;
        format!(
            "{STAGE}: wrote {} ({} lit points{caustics}, origin ({}, {}, {}) added back) in {seconds:.2} s",
            self.output.display(),
            s.points,
            o.x,
            o.y,
            o.z
        )
    }
}
