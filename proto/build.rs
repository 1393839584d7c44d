//! Compiles `vlnav/v1/*.proto` with the pure-Rust `protox` compiler (no system
//! protoc needed) and generates prost messages plus tonic clients and servers.
//! The encoded descriptor set is written too, for gRPC server reflection.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?);
    let dir = root.join("vlnav/v1");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "proto"))
        .collect();
    files.sort();
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
    }
    let fds = protox::compile(&files, [&root])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("vlnav_descriptor.bin"), prost::Message::encode_to_vec(&fds))?;
    // Image, depth, label and audio payloads are `bytes::Bytes`: a frame handed to
    // several stages is shared, not copied (docs/architecture.md, "Frames").
    tonic_prost_build::configure().bytes(".").build_server(true).build_client(true).compile_fds(fds)?;
    Ok(())
}
