//! vlnav-gateway
