//! The provenance check ([`vlnav_planner::provenance`]) agrees with the rule
//! parser: every plan the rules make for the development corpus and the
//! held-back set passes it. The check guards plans from language models
//! (`--backend openai|gguf`, `--fallback`); a check stricter than the rules
//! would refuse right plans, a looser one is tested in its unit tests and in
//! `tests/motion.rs`'s generated sentences.

mod common;

use std::path::PathBuf;

use vlnav_planner::corpus;
use vlnav_planner::plan::Outcome;
use vlnav_planner::planner::Planner;
use vlnav_planner::provenance;

#[test]
fn every_plan_of_the_rules_passes_the_provenance_check() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut cases = corpus::load_dir(&root.join("tests/corpus")).unwrap_or_else(|e| panic!("{e}"));
    cases.extend(corpus::load_dir(&root.join("tests/heldback")).unwrap_or_else(|e| panic!("{e}")));
    let grounder = common::grounder();
    let mut planner = Planner::from_parts(common::grounder(), None, None, &PathBuf::from("unused.gguf"));
    let (mut plans, mut refused) = (0, Vec::new());
    for case in &cases {
        let planned = planner.plan(&case.instruction, "rules").unwrap_or_else(|e| panic!("{}: {e}", case.at));
        let Outcome::Plan(plan) = &planned.outcome else { continue };
        plans += 1;
        if let Err(e) = provenance::check(plan, &case.instruction, &grounder) {
            refused.push(format!(
                "{} {:?}\n    {}\n    {}",
                case.at,
                case.instruction,
                corpus::describe(&planned),
                e.join("\n    ")
            ));
        }
    }
    println!("{plans} plans checked, {} refused", refused.len());
    assert!(plans > 300, "only {plans} plans");
    assert!(refused.is_empty(), "{} of {plans} rule plans refused:\n{}", refused.len(), refused.join("\n"));
}
