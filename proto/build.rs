//! Compiles the .proto files with a vendored protoc, so no system package is needed.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // SAFETY: build scripts are single-threaded.
    unsafe { std::env::set_var("PROTOC", protoc_bin_vendored::protoc_bin_path()?) };
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    tonic_prost_build::configure()
        .file_descriptor_set_path(out.join("sylva_descriptor.bin"))
        .compile_protos(&["sylva/v1/worker.proto", "sylva/v1/coordinator.proto"], &["."])?;
    println!("cargo:rerun-if-changed=sylva");
    Ok(())
}
