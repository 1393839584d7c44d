//! vlnav-runtime
