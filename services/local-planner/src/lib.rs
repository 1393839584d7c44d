//! vlnav-local-planner
