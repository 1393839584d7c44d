//! vlnav's gRPC contracts. `proto/vlnav/v1/*.proto` is the single source of
//! truth; this crate only exposes what `build.rs` generates from it.

pub mod coco;

// Generated code. With `bytes::Bytes` payloads a frame variant is larger than
// its siblings; it is moved once per frame, so boxing it buys nothing.
#[allow(clippy::large_enum_variant)]
pub mod v1 {
    tonic::include_proto!("vlnav.v1");
}

/// Encoded `FileDescriptorSet` of every `vlnav.v1` file, for server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/vlnav_descriptor.bin"));
