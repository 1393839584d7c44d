//! vlnav-reid
