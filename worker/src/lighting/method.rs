//! What a lighting method is, as the worker runs it: the interface every
//! method's module fills in (pbrt-v4's `base/light.h`), apart from the
//! factory in `lighting/mod.rs` that picks one by mode, so a method's file
//! and the factory never import each other.

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

    pub(super) fn wgsl_name(self) -> &'static str {
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
