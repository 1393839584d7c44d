//! vlnav-ingress
