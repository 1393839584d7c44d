//! vlnav-sim
