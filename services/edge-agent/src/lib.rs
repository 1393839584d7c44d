//! vlnav-edge-agent
