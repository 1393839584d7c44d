//! vlnav-planner
