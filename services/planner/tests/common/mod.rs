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

/// Plans every instruction of the corpus files in `dir` with the rule-based
/// planner and scores it as `tests/corpus.rs` and `tests/heldback.rs` do:
/// every plan validated, the per-category table and the misses printed;
/// fails with fewer than `min_cases` instructions or below `required`.
pub fn score_rules(dir: &std::path::Path, what: &str, min_cases: usize, required: f64) {
    use vlnav_planner::corpus::{self, Tally};
    use vlnav_planner::plan::Outcome;
    use vlnav_planner::planner::Planner;
    use vlnav_planner::validate::Validator;

    let cases = corpus::load_dir(dir).unwrap_or_else(|e| panic!("{e}"));
    assert!(cases.len() >= min_cases, "the {what} holds {} instructions; at least {min_cases} expected", cases.len());
    let mut planner = Planner::from_parts(grounder(), None, None, &PathBuf::from("unused.gguf"));
    let validator = Validator::new();
    let mut tally = Tally::default();
    let mut misses = Vec::new();
    for case in &cases {
        let planned = planner.plan(&case.instruction, "rules").unwrap_or_else(|e| panic!("{}: {e}", case.at));
        assert_eq!(planned.backend, "rules");
        if let Outcome::Plan(plan) = &planned.outcome {
            validator
                .validate_plan(plan)
                .unwrap_or_else(|e| panic!("{}: an invalid plan left the planner: {e:?}", case.at));
        }
        let verdict = corpus::judge(&case.expected, &planned);
        tally.add(&case.category, verdict.is_ok());
        if let Err(why) = verdict {
            misses.push(format!(
                "{} {:?}\n    got  {}\n    why  {why}",
                case.at,
                case.instruction,
                corpus::describe(&planned)
            ));
        }
    }
    println!("{}", tally.markdown());
    println!("{} misses:\n{}", misses.len(), misses.join("\n"));
    assert!(
        tally.accuracy() >= required,
        "accuracy {:.1} % is below {:.0} %:\n{}\n{}",
        100.0 * tally.accuracy(),
        100.0 * required,
        tally.markdown(),
        misses.join("\n")
    );
}
