//! The evaluation suite's instructions (`tools/eval/scenarios/suite.toml`)
//! plan exactly as recorded in `tests/snapshots/suite_plans.tsv`
//! (instruction, tab, plan JSON), byte for byte: the evaluation's figures
//! rest on these plans, so a parser change may not move them.
//!
//! The snapshot also holds the geometric and visual texts the evaluation
//! derives from a route (`tools/eval/src/suite.rs`); vlnav-eval's test
//! `the_planner_records_a_plan_for_every_suite_text` fails when one is
//! missing (and, with `VLNAV_BLESS=1`, appends it without a plan).
//!
//! After a deliberate change: `VLNAV_BLESS=1 cargo test -p vlnav-planner --test suite_plans`
//! re-records the plan of every text written in the suite and of every text
//! already in the snapshot.

mod common;

use std::path::{Path, PathBuf};

use vlnav_planner::plan::Outcome;
use vlnav_planner::planner::Planner;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn answer(planner: &mut Planner, text: &str) -> String {
    let planned = planner.plan(text, "rules").unwrap_or_else(|e| panic!("{text:?}: {e}"));
    match &planned.outcome {
        Outcome::Plan(_) => planned.plan_json(),
        Outcome::Clarify(c) => format!("? {}", c.question),
    }
}

#[test]
fn the_evaluation_suite_plans_as_recorded() {
    let snapshot = root().join("tests/snapshots/suite_plans.tsv");
    let mut planner = Planner::from_parts(common::grounder(), None, None, &PathBuf::from("unused.gguf"));
    if std::env::var_os("VLNAV_BLESS").is_some() {
        let suite = std::fs::read_to_string(root().join("../../tools/eval/scenarios/suite.toml")).expect("suite.toml");
        let written = suite.lines().filter_map(|l| l.trim().strip_prefix("text = \"")?.strip_suffix('"'));
        let before = std::fs::read_to_string(&snapshot).unwrap_or_default();
        let derived = before.lines().filter_map(|l| Some(l.split_once('\t')?.0));
        let mut texts: Vec<&str> = Vec::new();
        for t in written.chain(derived) {
            if !texts.contains(&t) {
                texts.push(t);
            }
        }
        let mut out = String::new();
        for text in texts {
            out.push_str(&format!("{text}\t{}\n", answer(&mut planner, text)));
        }
        std::fs::write(&snapshot, out).expect("writing the snapshot");
    }
    let recorded = std::fs::read_to_string(&snapshot).expect("tests/snapshots/suite_plans.tsv");
    let mut n = 0;
    for line in recorded.lines().filter(|l| !l.trim().is_empty()) {
        let (text, want) = line.split_once('\t').expect("instruction<TAB>plan");
        assert_eq!(answer(&mut planner, text), want, "{text:?} plans differently from the recording");
        n += 1;
    }
    assert!(n >= 20, "the snapshot holds {n} instructions");
}
