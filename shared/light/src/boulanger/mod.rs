//! CPU side of the Boulanger, Bouatouch & Pattanaik (2008) tree-lighting
//! model, "Rendering Trees with Indirect Lighting in Real Time": per-leaf
//! envelope distances `s_max(P, ω_j)` for eight directions, per-sun
//! constants (G1 split in two geometric factors, G2, G3), and a plain CPU
//! evaluation of the three lighting terms (sky, sun, one-bounce indirect
//! sun) that a GPU shader is tested against.
//!
//! # How `s_max` is computed
//!
//! Eqs. 6 and 23 integrate e^{−τ s(P, ω)} over each direction's bin (an
//! octant): what they need from the precomputation is the bin's *mean*
//! transmittance T_j, and `s_max(P, ω_j) = −ln T_j / τ` states it so that
//! e^{−τ s_max} = T_j. The paper (§6) estimates T_j as Π(1 − o) over the
//! neighbours in the bin, each occluding o = Ω_leaf / Ω_bin, which is the
//! mean transmittance only if the occluders are spread independently over
//! the bin: in a crown they are not. A leaf near the crown's surface has
//! open sky over part of its bin and the whole crown over the rest; the
//! product gives e^{−mean optical depth}, far below the mean of e^{−depth}
//! (Jensen), and every visible leaf came out darker than its direct sun
//! alone (issue 26: whole-image means 0.46–0.90 of the reference's). Here
//! T_j is measured: 16 rays per bin from the leaf's centre, on a 4 × 4
//! grid of equal solid angle over the octant (turned per leaf), through
//! the model's own triangles with the alpha test, counting those that
//! escape. A bin with no open ray gets half a ray's worth (T = 1/32), the
//! estimate's resolution. Everything downstream (eqs. 6–8, 11, 18–25) is
//! the paper's, unchanged; the renderer takes the direct sun from its own
//! shadow ray rather than eq. 8, and lets the sun light the ground below
//! the horizon (docs/lighting.md, "Boulanger et al.").
//!
//! τ = ρ A / 2 with ρ = leaves / envelope volume, the volume being the
//! occupied cells of a coarse grid of leaf centres (24 cells on the
//! longest side, made coarser until cells hold ≥ 8 leaves on average, so
//! the volume does not collapse to "one cell per leaf" on sparse trees).
//! Only the product τ s_max and the ratio ρ/τ = 2/A enter the lighting, so
//! the choice mostly matters for reading `s_max` as a distance.
//!
//! Leaves are "cards": two consecutive leaf triangles that share an edge
//! (the generator's quads) count as one leaf, with the summed area and the
//! area-weighted centre; both triangles get the same `s_max`.
//!
//! Wood (trunk and branches) receives the same sky and one bounce: the
//! paper shades leaves only, and a bark surface left at its direct sun is
//! black wherever the sun does not reach it, where the reference shows
//! the sky and the leaves' light on it (on `examples/tree.json` the
//! branches are a large share of the tree's pixels). Its cards are its
//! triangles (paired like the leaves'), its transmittance is measured the
//! same way, and the neighbours that scatter sun light onto it are the
//! model's leaves, of their mean albedo ([`LeafEnvelope::leaf_albedo`]).
//!
//! Directions: the paper's eq. 26 lists ω_0..ω_3 (all with y = −1/√3) and
//! ω_j = −ω_{7−j}; here ω_{j+4} = −ω_j instead, so a shader recovers the
//! upper four by negating the lower four in order. y is up.
//!
//! The per-leaf precomputation is in `envelope.rs`; the per-sun constants and
//! the lighting terms in `shade.rs`.

mod envelope;
mod shade;
#[cfg(test)]
mod tests;

pub use envelope::{LeafEnvelope, precompute};
pub use shade::{
    ChannelLight, SunTerms, bsdf, lo_sample, normal_average, shade, shade_wood,
    sky_radiance_per_direction, sun_distance, sun_terms,
};

use glam::Vec3;

/// Number of sample directions ω_j.
pub const N_DIR: usize = 8;

/// 1/√3: the cube diagonals' coordinates.
const XI: f32 = 0.577_350_26;

/// The eight sample directions: cube diagonals, ω_0..ω_3 below the horizon
/// (y < 0), and ω_{j+4} = −ω_j.
pub fn directions() -> [Vec3; N_DIR] {
    let low = [
        Vec3::new(-XI, -XI, -XI),
        Vec3::new(XI, -XI, -XI),
        Vec3::new(-XI, -XI, XI),
        Vec3::new(XI, -XI, XI),
    ];
    [low[0], low[1], low[2], low[3], -low[0], -low[1], -low[2], -low[3]]
}

/// The index of the direction nearest to `d` (its octant), by signs only.
pub fn bin_of(d: Vec3) -> usize {
    if d.y < 0.0 {
        (d.x > 0.0) as usize + 2 * (d.z > 0.0) as usize
    } else {
        4 + (d.x < 0.0) as usize + 2 * (d.z < 0.0) as usize
    }
}

/// M(x) = max(x, 0).
#[inline]
pub(crate) fn m(x: f32) -> f32 {
    x.max(0.0)
}
