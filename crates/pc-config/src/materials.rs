//! Materials as the artifacts hold them: the table of [`MaterialRecord`]s that the renderer and
//! the solvers read, and the check that a config's materials are those an octree was built
//! with.

use pc_artifact::octree::{class, MaterialRecord, OctreeFile};

use crate::{Albedo, ConfigError, LoadedConfig, MaterialConfig};

/// The artifact material table of `materials` (in the config's order, sorted by name), one
/// record each. Per-point colors multiply `color`.
pub fn material_table<'a>(
    materials: impl IntoIterator<Item = &'a MaterialConfig>,
) -> Vec<MaterialRecord> {
    materials
        .into_iter()
        .map(|m| match m {
            MaterialConfig::Diffuse { albedo } => MaterialRecord {
                color: match albedo {
                    Albedo::Rgb(c) => *c,
                    Albedo::Source(_) => [1.0; 3],
                },
                class: class::DIFFUSE,
                ior: 1.0,
                per_point_color: matches!(albedo, Albedo::Source(_)) as u32,
                ..Default::default()
            },
            MaterialConfig::Emitter { radiance, albedo } => MaterialRecord {
                color: albedo.unwrap_or([0.0; 3]),
                class: class::EMITTER,
                radiance: *radiance,
                ior: 1.0,
                ..Default::default()
            },
            MaterialConfig::Mirror { reflectance, phong } => MaterialRecord {
                color: *reflectance,
                class: class::MIRROR,
                ior: 1.0,
                phong: phong.unwrap_or(0.0),
                ..Default::default()
            },
            MaterialConfig::Dielectric { ior, tint, phong } => MaterialRecord {
                color: tint.unwrap_or([1.0; 3]),
                class: class::DIELECTRIC,
                ior: *ior,
                phong: phong.unwrap_or(0.0),
                ..Default::default()
            },
        })
        .collect()
}

impl LoadedConfig {
    /// The config's material table, unchecked: what a stage's key hashes. A run takes it from
    /// [`LoadedConfig::materials_for`], which returns this same table once it matches the
    /// octree's.
    pub fn material_records(&self) -> Vec<MaterialRecord> {
        material_table(self.config.materials.values())
    }

    /// The config's material table, checked against the octree's: names and classes must match
    /// (colors, radiance and indices of refraction may change without rebuilding the octree).
    pub fn materials_for(&self, octree: &OctreeFile) -> Result<Vec<MaterialRecord>, ConfigError> {
        let names: Vec<&String> = self.config.materials.keys().collect();
        let built = &octree.meta().material_names;
        let err = |msg: String| ConfigError::OctreeMaterials {
            octree: octree.path().to_path_buf(),
            msg,
        };
        if names.iter().copied().ne(built.iter()) {
            return Err(err(format!(
                "the octree was built with materials [{}] but {} now defines [{}]",
                built.join(", "),
                self.path.display(),
                names
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )));
        }
        let table = self.material_records();
        for ((m, b), name) in table.iter().zip(octree.materials()).zip(&names) {
            if m.class != b.class || m.per_point_color != b.per_point_color {
                return Err(err(format!(
                    "material `{name}` changed class since the octree was built"
                )));
            }
        }
        Ok(table)
    }
}
