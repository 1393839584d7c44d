//! Shared by the planner's integration tests: the real models, or a loud failure.

#![allow(dead_code)]

use std::path::PathBuf;

use vlnav_planner::grounding::{DEFAULT_THRESHOLD, Grounder};
use vlnav_planner::minilm::MiniLm;

/// `$VLNAV_MODELS_DIR`, else the workspace's `models/`.
pub fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

/// The production grounder: synonyms plus all-MiniLM-L6-v2.
pub fn grounder() -> Grounder {
    let minilm = MiniLm::load(&models_dir()).unwrap_or_else(|e| panic!("{e} (models dir {})", models_dir().display()));
    Grounder::with_minilm(minilm, DEFAULT_THRESHOLD).expect("embedding the class names")
}
