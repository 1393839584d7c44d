//! vlnav-subgoal
