//! vlnav-detector
