//! The lighting methods, one module each. A method declares here what it
//! prepares before tracing and which render kernel draws it; `prepare`
//! and the strip renderer read only these declarations, and the WGSL
//! constants that name the methods are generated from them.
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
pub mod reference;

use sylva_scene::LightingMode;

/// The render kernel a method runs: one WGSL source, specialized per
/// kernel by the `LIGHTING_FAMILY` override, so a pipeline compiles only
/// the code it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// One pass of direct light plus a per-frame indirect term.
    Direct = 0,
    /// One path per invocation, each sample to its own slot: the
    /// reference, and the gathers (its paths, truncated).
    Reference = 1,
    /// The direct kernel with Boulanger's envelope terms compiled in.
    Boulanger = 2,
}

impl Kernel {
    /// Every kernel, by its index.
    pub const ALL: [Kernel; 3] = [Kernel::Direct, Kernel::Reference, Kernel::Boulanger];

    fn wgsl_name(self) -> &'static str {
        match self {
            Kernel::Direct => "KERNEL_DIRECT",
            Kernel::Reference => "KERNEL_REFERENCE",
            Kernel::Boulanger => "KERNEL_BOULANGER",
        }
    }
}

/// What a method needs prepared before it can trace: the one statement of
/// it. Methods that need the same share a prepared scene (the worker's
/// cache is keyed on this).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Needs {
    /// The LB light of each model and of the forest.
    pub lb: bool,
    /// Boulanger's leaf envelopes.
    pub envelopes: bool,
    /// The clouds' density and LB light.
    pub clouds: bool,
}

/// One lighting method as the worker runs it.
#[derive(Clone, Copy, Debug)]
pub struct Method {
    /// Which method.
    pub mode: LightingMode,
    /// The value of `frame.lighting` the render kernel branches on: the
    /// method's number on the wire (`pb::Lighting`), so there is one numbering.
    pub code: u32,
    /// The WGSL constant naming `code`.
    pub wgsl: &'static str,
    /// The kernel that draws it.
    pub kernel: Kernel,
    /// What it prepares.
    pub needs: Needs,
}

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
