//! What a frame is made of, before any light is computed: the scene file
//! ([`format`](mod@format)) and its loading and checks ([`Scene`]), the file sandbox a
//! scene reads through ([`sandbox`]) and its size caps ([`caps`]), models
//! ([`model`]: meshes, glTF) and procedural [`trees`] with their
//! [`leaf`] optics and textures, the [`camera`], what one frame asks for
//! ([`frame`]) and a [`sequence`] of frames, the bundle that carries a scene
//! to workers ([`bundle`]), scenes for other tools ([`interchange`]), the
//! Table-2 forest generator ([`table2`]), and the film a frame is written to
//! ([`film`]).
//!
//! ```
//! let text = r#"{ "models": { "maple": { "tree": { "species": "red_maple", "triangles": 2000 } } },
//!                "instances": [ { "model": "maple" } ],
//!                "camera": { "position": [0, 5, -30], "look_at": [0, 5, 0] },
//!                "sun": { "elevation_deg": 40, "azimuth_deg": 30 } }"#;
//! let file = sylva_scene::parse(text, "inline.json").unwrap();
//! let scene = sylva_scene::Scene::build(file, std::path::Path::new("."), "inline.json").unwrap();
//! assert_eq!(scene.instances.len(), 1);
//! ```

pub mod bundle;
pub mod camera;
pub mod caps;
pub mod color;
mod error;
pub mod film;
pub mod format;
pub mod frame;
pub mod interchange;
pub mod leaf;
mod load;
pub mod model;
pub mod passes;
pub mod rng;
pub mod sandbox;
pub mod sequence;
pub mod table2;
pub mod trees;

pub use error::{Error, Result};
pub use load::*;
