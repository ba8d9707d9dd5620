//! The artifact container: every on-disk format of pcgi, validated before any cast and written atomically.
//!
//! One file per artifact: a fixed header (magic, format version, artifact kind, producing stage
//! and version, the key hashed from the inputs and parameters that made it), 64-byte aligned
//! sections of plain little-endian arrays (uploadable to a GPU buffer as they are), MessagePack
//! metadata, and a section table with a checksum per section. The byte layout is documented in
//! [`container`].

pub mod atomic;
pub mod build_id;
pub mod container;
pub mod error;
pub mod key;
pub mod kind;
pub mod light;
pub mod octree;
pub mod params;
pub mod photons;
pub mod radiosity;
pub mod reader;
pub mod specular;
pub mod vmap;
pub mod walk;
pub mod writer;

pub use atomic::write_file_atomically;
pub use build_id::build_id;
pub use container::{
    is_valid_section_name, Artifact, HeaderInfo, SectionInfo, FORMAT_VERSION, HEADER_SIZE, MAGIC,
    MAX_SECTION_NAME, MAX_STAGE_NAME, MAX_STAGE_VERSION, SECTION_ALIGN, TABLE_ENTRY_SIZE,
};
pub use error::{ArtifactError, METADATA_REGION, TABLE_REGION};
pub use key::{Key, KeyHasher};
pub use kind::ArtifactKind;
pub use light::PointLight;
pub use writer::ArtifactWriter;
