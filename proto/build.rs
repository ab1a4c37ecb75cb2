//! Generates the Rust code of `unigait/v1/unigait.proto` with the vendored protoc (no system
//! protobuf compiler needed), plus a descriptor set for gRPC reflection.
//!
//! Two passes: the messages and the client with tonic's prost codec, then the server alone
//! (messages taken from the first pass) with [`RequestCodec`](src/codec.rs), so that a request
//! that does not decode is the client's error (INVALID_ARGUMENT) rather than tonic's INTERNAL,
//! while a client still reports a reply that does not decode as the server's fault.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protoc = protoc_bin_vendored::protoc_bin_path()?;
    // SAFETY: build scripts are single-threaded; prost-build reads PROTOC from the environment.
    unsafe { std::env::set_var("PROTOC", protoc) };
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    tonic_prost_build::configure()
        .bytes(".")
        .build_server(false)
        .file_descriptor_set_path(out.join("unigait_v1_descriptor.bin"))
        .compile_protos(&["unigait/v1/unigait.proto"], &["."])?;
    let server = out.join("server");
    std::fs::create_dir_all(&server)?;
    tonic_prost_build::configure()
        .build_client(false)
        .out_dir(&server)
        .extern_path(".unigait.v1", "crate::v1")
        .codec_path("crate::codec::RequestCodec")
        .compile_protos(&["unigait/v1/unigait.proto"], &["."])?;
    println!("cargo:rerun-if-changed=unigait/v1/unigait.proto");
    Ok(())
}
