//! The species presets: sizes, branching and colours.

use crate::leaf::LeafShape;
use serde::{Deserialize, Serialize};

/// The paper's five species (Geist & Steele 2008, Table 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Species {
    /// Acer rubrum: rounded crown, lobed leaves with a red tint.
    RedMaple,
    /// Aesculus glabra: compact rounded crown, palmate compound leaves.
    OhioBuckeye,
    /// Betula papyrifera: tall narrow crown, white bark, small ovate leaves.
    PaperBirch,
    /// Catalpa bignonioides: broad irregular crown, very large heart-shaped leaves.
    SouthernCatalpa,
    /// Fagus grandifolia: wide spreading dense crown, grey bark, elliptic leaves.
    AmericanBeech,
}

/// The outline a species' branch lengths follow up the crown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CrownShape {
    /// Widest in the middle.
    Ellipsoid,
    /// Widest at the bottom.
    Cone,
    /// Widest at the bottom, rounded on top.
    Dome,
}

impl CrownShape {
    /// Relative branch length at height `t` ∈ [0, 1] up the crown.
    pub fn profile(self, t: f32) -> f32 {
        let t = t.clamp(0.0, 1.0);
        match self {
            CrownShape::Ellipsoid => (1.0 - (2.0 * t - 1.0).powi(2)).max(0.0).sqrt().max(0.15),
            CrownShape::Cone => (1.0 - t).max(0.08),
            CrownShape::Dome => (1.0 - t * t).max(0.0).sqrt().max(0.12),
        }
    }
}

/// Everything the generator needs to know about a species.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeciesShape {
    /// Total height, metres.
    pub height: f32,
    /// Trunk radius at the ground, metres.
    pub trunk_radius: f32,
    /// Where branching starts, as a fraction of the height.
    pub crown_base: f32,
    /// Longest branch, metres.
    pub crown_radius: f32,
    /// How branch length varies up the crown.
    pub crown: CrownShape,
    /// First-order branches.
    pub branches: u32,
    /// Branch angle from the vertical, degrees.
    pub branch_pitch_deg: f32,
    /// How much branches bend down (negative) or up (positive) along their length.
    pub branch_bend: f32,
    /// Twigs per branch at full detail.
    pub twigs: u32,
    /// Leaf length, metres.
    pub leaf_size: f32,
    /// Leaf outline.
    pub leaf_shape: LeafShape,
    /// Leaf colour, sRGB.
    pub leaf_rgb: [u8; 3],
    /// Bark colour, linear RGB.
    pub bark: [f32; 3],
    /// Triangles per instance in the paper's forest (Table 2).
    pub paper_triangles: u32,
    /// Instances in the paper's forest (Table 2).
    pub paper_instances: u32,
}

impl Species {
    /// All five, in the paper's Table 2 order.
    pub const ALL: [Species; 5] = [
        Species::RedMaple,
        Species::OhioBuckeye,
        Species::PaperBirch,
        Species::SouthernCatalpa,
        Species::AmericanBeech,
    ];

    /// The name scene files use.
    pub fn name(self) -> &'static str {
        match self {
            Species::RedMaple => "red_maple",
            Species::OhioBuckeye => "ohio_buckeye",
            Species::PaperBirch => "paper_birch",
            Species::SouthernCatalpa => "southern_catalpa",
            Species::AmericanBeech => "american_beech",
        }
    }

    /// The species' preset.
    pub fn shape(self) -> SpeciesShape {
        match self {
            Species::RedMaple => SpeciesShape {
                height: 17.0,
                trunk_radius: 0.32,
                crown_base: 0.3,
                crown_radius: 6.0,
                crown: CrownShape::Ellipsoid,
                branches: 14,
                branch_pitch_deg: 50.0,
                branch_bend: 0.15,
                twigs: 10,
                leaf_size: 0.14,
                leaf_shape: LeafShape::Lobed,
                leaf_rgb: [112, 118, 42],
                bark: [0.16, 0.13, 0.11],
                paper_triangles: 115_529,
                paper_instances: 12,
            },
            Species::OhioBuckeye => SpeciesShape {
                height: 12.0,
                trunk_radius: 0.28,
                crown_base: 0.3,
                crown_radius: 5.0,
                crown: CrownShape::Ellipsoid,
                branches: 12,
                branch_pitch_deg: 58.0,
                branch_bend: 0.1,
                twigs: 8,
                leaf_size: 0.24,
                leaf_shape: LeafShape::Palmate,
                leaf_rgb: [52, 92, 30],
                bark: [0.18, 0.16, 0.14],
                paper_triangles: 168_520,
                paper_instances: 285,
            },
            Species::PaperBirch => SpeciesShape {
                height: 20.0,
                trunk_radius: 0.2,
                crown_base: 0.35,
                crown_radius: 3.6,
                crown: CrownShape::Cone,
                branches: 18,
                branch_pitch_deg: 38.0,
                branch_bend: -0.25,
                twigs: 10,
                leaf_size: 0.08,
                leaf_shape: LeafShape::Ovate,
                leaf_rgb: [128, 150, 50],
                bark: [0.75, 0.73, 0.68],
                paper_triangles: 372_896,
                paper_instances: 291,
            },
            Species::SouthernCatalpa => SpeciesShape {
                height: 12.0,
                trunk_radius: 0.38,
                crown_base: 0.25,
                crown_radius: 6.5,
                crown: CrownShape::Dome,
                branches: 9,
                branch_pitch_deg: 66.0,
                branch_bend: 0.2,
                twigs: 7,
                leaf_size: 0.3,
                leaf_shape: LeafShape::Cordate,
                leaf_rgb: [106, 150, 58],
                bark: [0.22, 0.18, 0.14],
                paper_triangles: 155_342,
                paper_instances: 206,
            },
            Species::AmericanBeech => SpeciesShape {
                height: 22.0,
                trunk_radius: 0.42,
                crown_base: 0.2,
                crown_radius: 8.0,
                crown: CrownShape::Dome,
                branches: 16,
                branch_pitch_deg: 72.0,
                branch_bend: -0.05,
                twigs: 12,
                leaf_size: 0.11,
                leaf_shape: LeafShape::Elliptic,
                leaf_rgb: [58, 98, 36],
                bark: [0.42, 0.42, 0.4],
                paper_triangles: 496_719,
                paper_instances: 168,
            },
        }
    }
}
