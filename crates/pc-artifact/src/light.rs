//! The point light: one record for pipeline.toml's `[[lights]]`, the artifacts' metadata, the
//! stages' keys, the solvers and the GPU (WGSL twin `PointLight` in `shaders/raytrace/render.wgsl`).

use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

/// An isotropic point light. 32 bytes, laid out as the WGSL record (each `vec3<f32>` padded to
/// 16 bytes); the padding is private, always zero, and not part of the TOML or the metadata.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointLight {
    /// World position.
    pub position: [f32; 3],
    #[serde(skip)]
    _pad0: f32,
    /// Radiant intensity, W/sr, linear RGB.
    pub intensity: [f32; 3],
    #[serde(skip)]
    _pad1: f32,
}

impl PointLight {
    pub fn new(position: [f32; 3], intensity: [f32; 3]) -> PointLight {
        PointLight {
            position,
            intensity,
            ..Default::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gpu_layout_and_serde_shape() {
        assert_eq!(std::mem::size_of::<PointLight>(), 32);
        assert_eq!(std::mem::offset_of!(PointLight, intensity), 16);
        let l = PointLight::new([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]);
        let bytes = rmp_serde::to_vec_named(&l).unwrap();
        let back: PointLight = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(back, l);
        #[derive(Deserialize)]
        struct Fields {
            position: [f32; 3],
            intensity: [f32; 3],
        }
        let f: Fields = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!((f.position, f.intensity), (l.position, l.intensity));
    }
}
