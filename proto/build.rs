//! Generates the Rust code of `unigait/v1/unigait.proto` with the vendored protoc (no system
//! protobuf compiler needed), plus a descriptor set for gRPC reflection.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; prost-build reads PROTOC from the environment.
    unsafe { std::env::set_var("PROTOC", protoc) };
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    tonic_prost_build::configure()
        .bytes(".")
        .file_descriptor_set_path(out.join("unigait_v1_descriptor.bin"))
        .compile_protos(&["unigait/v1/unigait.proto"], &["."])?;
    println!("cargo:rerun-if-changed=unigait/v1/unigait.proto");
    Ok(())
}
