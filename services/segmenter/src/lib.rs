//! vlnav-segmenter
