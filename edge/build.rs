//! Points rosrust's message generator at the ROS 1 message definitions the
//! `ros1` driver uses (vendored under `msg/`, copied verbatim from the Debian
//! ROS packages), so the crate builds on machines without ROS installed.
//! Directories in `CMAKE_PREFIX_PATH` (e.g. `/usr` or `/opt/ros/noetic`) are
//! still searched first by rosrust.

fn main() {
    let dir =
        std::path::Path::new(&std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR")).join("msg");
    println!("cargo:rustc-env=ROSRUST_MSG_PATH={}", dir.display());
    println!("cargo:rerun-if-changed=msg");
    println!("cargo:rerun-if-changed=build.rs");
}
