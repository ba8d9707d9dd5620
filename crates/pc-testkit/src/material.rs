//! Material records of the test scenes: one constructor per class.

use pc_artifact::octree::{class, MaterialRecord};

/// A grey diffuse surface of `albedo`.
pub fn diffuse(albedo: f32) -> MaterialRecord {
    MaterialRecord {
        color: [albedo; 3],
        class: class::DIFFUSE,
        ior: 1.0,
        ..Default::default()
    }
}

/// A grey emitter of `radiance` that also reflects `albedo`.
pub fn emitter(radiance: f32, albedo: f32) -> MaterialRecord {
    MaterialRecord {
        color: [albedo; 3],
        class: class::EMITTER,
        radiance: [radiance; 3],
        ior: 1.0,
        ..Default::default()
    }
}

/// A perfect mirror of reflectance `r`.
pub fn mirror(r: f32) -> MaterialRecord {
    MaterialRecord {
        color: [r; 3],
        class: class::MIRROR,
        ior: 1.0,
        ..Default::default()
    }
}

/// A clear glass of index `ior`.
pub fn glass(ior: f32) -> MaterialRecord {
    MaterialRecord {
        color: [1.0; 3],
        class: class::DIELECTRIC,
        ior,
        ..Default::default()
    }
}
