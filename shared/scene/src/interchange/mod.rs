//! Scenes that travel: a Sylva scene written for other tools (glTF 2.0
//! for Blender and viewers, pbrt-v4 for the field's reference renderer),
//! and an instanced glTF scene read back as a Sylva scene file.

pub mod gltf;
pub mod import;
pub mod pbrt;
