//! vlnav-traces
