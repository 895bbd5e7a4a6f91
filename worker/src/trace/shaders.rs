//! Assembles the tracer's WGSL: the scene and traversal code shared by
//! every entry point, with the traversal template instantiated per level.

const SCENE: &str = include_str!("../../../shaders/trace/scene.wgsl");
const TRAVERSE: &str = include_str!("../../../shaders/trace/traverse.wgsl");

/// The full module for an entry-point file's source.
pub fn tracer_source(entry: &str) -> String {
    let mut s = String::with_capacity(SCENE.len() + 2 * TRAVERSE.len() + entry.len());
    s.push_str(SCENE);
    for level in ["top", "model"] {
        s.push('\n');
        s.push_str(&TRAVERSE.replace("LEVEL", level));
    }
    s.push('\n');
    s.push_str(entry);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parses and validates a module; panics with naga's message.
    pub fn validate(src: &str) -> naga::Module {
        let module = naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("{}", e.emit_to_string(src)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}", e.emit_to_string(src)));
        module
    }

    #[test]
    fn ray_casting_module_is_valid_wgsl() {
        validate(&tracer_source(include_str!("../../../shaders/trace/rays.wgsl")));
    }
}
