//! The lighting methods, one module each. Each declares (through the
//! interface in [`method`](mod@method)) what it prepares before tracing
//! and which render kernel draws it; [`method()`] picks one by mode.
//! `prepare` and the strip renderer read only these declarations, and the
//! WGSL constants that name the methods are generated from them. The frame
//! layer (`crate::frame`) drives them: a method never runs the renderer.
//!
//! - [`local`]: the direct sun alone.
//! - [`ambient`]: direct sun plus a constant matched to the LB light.
//! - [`lb`]: direct sun plus the LB light of each species and of the forest.
//! - [`boulanger`]: Boulanger et al. 2008's closed forms over leaf envelopes.
//! - [`gather`]: a final gather over the LB: the first bounces traced, the
//!   rest read from the lattice (or from the matched constant).
//! - [`reference`](mod@reference): the path tracer every method is measured against.
//! - [`clouds`]: the clouds' LB light, which the LB methods read and the
//!   reference's clouds are drawn from.

pub mod ambient;
pub mod boulanger;
pub mod clouds;
pub mod gather;
pub mod lb;
pub mod local;
pub mod method;
pub mod reference;

pub use method::{Kernel, Method, Needs};
use sylva_scene::LightingMode;

/// The method that renders `mode`.
pub fn method(mode: LightingMode) -> &'static Method {
    match mode {
        LightingMode::Local => &local::METHOD,
        LightingMode::Ambient => &ambient::METHOD,
        LightingMode::Lb => &lb::METHOD,
        LightingMode::LbVisualize => &lb::VISUALIZE,
        LightingMode::Reference => &reference::METHOD,
        LightingMode::Boulanger => &boulanger::METHOD,
        LightingMode::Gather => &gather::METHOD,
        LightingMode::GatherAmbient => &gather::AMBIENT,
    }
}

/// The WGSL constants naming every method and kernel, generated from the
/// declarations above so the kernel and the host cannot disagree.
pub fn wgsl_constants() -> String {
    let methods = LightingMode::ALL
        .iter()
        .map(|&m| method(m))
        .map(|m| format!("const {}: u32 = {}u;\n", m.wgsl, m.code));
    let kernels =
        Kernel::ALL.iter().map(|&k| format!("const {}: u32 = {}u;\n", k.wgsl_name(), k as u32));
    methods.chain(kernels).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_method_has_its_own_code_and_declares_its_own_mode() {
        let mut codes: Vec<u32> = LightingMode::ALL.iter().map(|&m| method(m).code).collect();
        codes.sort();
        codes.dedup();
        assert_eq!(codes.len(), LightingMode::ALL.len(), "codes collide");
        for m in LightingMode::ALL {
            assert_eq!(method(m).mode, m);
            assert_eq!(
                method(m).code as i32,
                sylva_proto::convert::lighting_to_wire(Some(m)) as i32
            );
        }
        let w = wgsl_constants();
        assert!(
            w.contains("const LIGHTING_REFERENCE: u32 = 5u;")
                && w.contains("const KERNEL_BOULANGER: u32 = 2u;"),
            "{w}"
        );
    }
}
