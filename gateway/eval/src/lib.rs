//! vlnav-eval
