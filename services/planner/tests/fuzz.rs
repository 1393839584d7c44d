//! Fuzzing the instruction parser and the plan validator (seeded, see
//! `vlnav-fuzzgen`): arbitrary text and mutations of the corpus's real
//! instructions through [`Planner::plan`] (input checks, HTN parser,
//! validator) and [`Planner::replan`], and mutated plan JSON through
//! [`Validator::validate_text`]. Property: no panic; an error carries a
//! message; a plan that leaves passes the validator again unchanged; a
//! question says what it asks.
//!
//! Short by default; the full run:
//! `VLNAV_FUZZ_CASES=1000000 cargo test --release -p vlnav-planner --test fuzz -- --nocapture --test-threads 1`.
//! The bulk grounds lexically (synonyms; microseconds a case); the MiniLM
//! target runs a hundredth of the cases with the production grounder.

mod common;

use std::path::Path;
use std::sync::OnceLock;

use rand::Rng as _;
use vlnav_fuzzgen::{self as fuzz, Rng};
use vlnav_planner::grounding::Grounder;
use vlnav_planner::plan::{MAX_INSTRUCTION_BYTES, MAX_STEPS, Outcome, Plan, Planned};
use vlnav_planner::planner::{PlanError, Planner};
use vlnav_planner::validate::Validator;

/// The instructions of the corpus (`tests/corpus/*.tsv`, first column) and
/// the README's quoted examples.
fn seeds() -> &'static [String] {
    static SEEDS: OnceLock<Vec<String>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut out = Vec::new();
        let mut files: Vec<_> = std::fs::read_dir(root.join("tests/corpus"))
            .expect("tests/corpus")
            .map(|e| e.expect("corpus entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "tsv"))
            .collect();
        files.sort();
        for f in files {
            for line in std::fs::read_to_string(&f).expect("corpus file").lines() {
                let first = line.split('\t').next().unwrap_or("").trim();
                if !first.is_empty() && !first.starts_with('#') {
                    out.push(first.to_string());
                }
            }
        }
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap_or_default();
        for quoted in readme.split('"').skip(1).step_by(2) {
            if quoted.contains(' ') && quoted.len() < 300 && !quoted.contains(['{', '`']) {
                out.push(quoted.to_string());
            }
        }
        assert!(out.len() > 200, "the corpus has its instructions: {}", out.len());
        out
    })
}

fn seed_refs() -> Vec<&'static str> {
    seeds().iter().map(String::as_str).collect()
}

/// An instruction: mostly grammar-aware mutations of real ones, else arbitrary text.
fn instruction(rng: &mut Rng, seeds: &[&str]) -> String {
    match rng.random_range(0..10) {
        0 => fuzz::arbitrary_text(rng, 300),
        1 => seeds[rng.random_range(0..seeds.len())].to_string(),
        _ => fuzz::mutate_text(rng, seeds, MAX_INSTRUCTION_BYTES),
    }
}

#[derive(Debug)]
struct Case {
    instruction: String,
    /// Replan after this step of the instruction's plan failed, with this answer.
    replan: Option<(usize, String, String)>,
}

fn case(rng: &mut Rng, seeds: &[&str]) -> Case {
    let instruction = instruction(rng, seeds);
    let replan = rng.random_bool(0.1).then(|| {
        let step = if rng.random_bool(0.8) { rng.random_range(0..6) } else { fuzz::interesting_u32(rng) as usize };
        (step, fuzz::arbitrary_text(rng, 40), instruction_or_short(rng, seeds))
    });
    Case { instruction, replan }
}

fn instruction_or_short(rng: &mut Rng, seeds: &[&str]) -> String {
    const ANSWERS: &[&str] = &["yes", "no", "skip it", "the chair", "go back", "try again", "left", "stop", ""];
    if rng.random_bool(0.5) { ANSWERS[rng.random_range(0..ANSWERS.len())].to_string() } else { instruction(rng, seeds) }
}

/// The property of one answer; returns the outcome's name.
fn check_answer(validator: &Validator, input: &str, answer: Result<Planned, PlanError>) -> &'static str {
    match answer {
        Err(e) => {
            assert!(!e.to_string().trim().is_empty(), "{input:?}: an error without a message: {e:?}");
            "error"
        }
        Ok(planned) => match &planned.outcome {
            Outcome::Plan(plan) => {
                assert!(!plan.steps.is_empty() && plan.steps.len() <= MAX_STEPS, "{input:?}: {plan:?}");
                let again = validator
                    .validate_plan(plan)
                    .unwrap_or_else(|e| panic!("{input:?} gave a plan the validator refuses: {e:?}\n{plan:?}"));
                assert_eq!(&again.plan, plan, "{input:?}: a validated plan is a fixed point of the validator");
                "plan"
            }
            Outcome::Clarify(c) => {
                assert!(!c.question.trim().is_empty(), "{input:?}: a question without words");
                "question"
            }
        },
    }
}

fn planner_with(grounder: Grounder) -> Planner {
    Planner::from_parts(grounder, None, None, Path::new("/nonexistent/gemma.gguf"))
}

fn run_plans(target: &str, cases: u64, planner: &mut Planner) -> fuzz::Report {
    let seeds = seed_refs();
    let validator = Validator::new();
    fuzz::run_exact(
        target,
        cases,
        |rng| case(rng, &seeds),
        |c| {
            let answer = planner.plan(&c.instruction, "rules");
            let plan = match &answer {
                Ok(Planned { outcome: Outcome::Plan(p), .. }) => Some(p.clone()),
                _ => None,
            };
            let mut outcome = check_answer(&validator, &c.instruction, answer).to_string();
            if let Some((step, failure, reply)) = &c.replan {
                let plan = plan.unwrap_or_else(|| Plan::new(vec![]));
                let answer = planner.replan(&plan, *step, failure, reply, "");
                outcome = format!("{outcome}, replan {}", check_answer(&validator, reply, answer));
            }
            outcome
        },
    )
}

#[test]
fn instructions_give_a_validated_plan_a_question_or_an_error() {
    let mut planner = planner_with(Grounder::lexical_only());
    let report = run_plans("planner (lexical grounding)", fuzz::cases(3_000), &mut planner);
    report.assert_no_panics();
    assert!(report.count("plan") > report.cases / 10, "the mutations keep many instructions readable: {report}");
}

#[test]
fn instructions_with_minilm_grounding_give_a_validated_plan_a_question_or_an_error() {
    let mut planner = planner_with(common::grounder());
    let default = 150;
    // A hundredth of the cases: MiniLM embeds every phrase the synonyms miss (milliseconds each).
    let cases = fuzz::cases(default * 100) / 100;
    let report = run_plans("planner (MiniLM grounding)", cases.max(1), &mut planner);
    report.assert_no_panics();
}

/// Plan JSON as a language model might write it: valid plans mutated at the
/// byte level, inside prose or code fences, with odd numbers and keys.
fn plan_text(rng: &mut Rng, plans: &[String]) -> String {
    let base = &plans[rng.random_range(0..plans.len())];
    let mut text = match rng.random_range(0..4) {
        0 => base.clone(),
        1 => {
            let mut bytes = base.clone().into_bytes();
            let donors: Vec<&[u8]> = plans.iter().map(|p| p.as_bytes()).collect();
            fuzz::mutate_bytes(rng, &mut bytes, &donors, 8192);
            String::from_utf8_lossy(&bytes).into_owned()
        }
        2 => {
            // Replace a number with an odd one.
            let odd = fuzz::NUMBERS[rng.random_range(0..fuzz::NUMBERS.len())];
            let digits: Vec<usize> = base.match_indices(|c: char| c.is_ascii_digit()).map(|(i, _)| i).collect();
            match digits.get(rng.random_range(0..digits.len().max(1))) {
                Some(&i) => format!("{}{odd}{}", &base[..i], &base[i + 1..]),
                None => base.clone(),
            }
        }
        _ => {
            const STEPS: &[&str] = &[
                r#"{"action":"MOVE","f_dist":1e308,"yaw":0}"#,
                r#"{"action":"MOVE","f_dist":-80,"yaw":-1e-320}"#,
                r#"{"action":"MOVE","f_dist":79.99,"yaw":1e300}"#,
                r#"{"action":"FIND","target":"","id":0}"#,
                r#"{"action":"FIND","target":"chair","id":56,"d_s":-1}"#,
                r#"{"action":"FOLLOW","target":"me","id":0,"duration_s":1e308,"person":"x"}"#,
                r#"{"action":"FIND","target":"cup","id":41,"ref":{"relation":"on","target":"table","id":999}}"#,
                r#"{"action":"RETURN","extra":[[[[[[]]]]]]}"#,
                r#"{"action":"MOVE","f_dist":"2","yaw":null}"#,
                r#"{"action":"MOVE","f_dist":80,"yaw":0}"#,
                r#"{"action":"MOVE","f_dist":10.000000001,"yaw":0}"#,
                r#"{"action":"FIND","target":"chair","id":-2147483648}"#,
                r#"{"action":"FIND","target":"chair","id":1.5}"#,
                r#"{"action":"FIND","target":"chair","id":18446744073709551616}"#,
                r#"{}"#,
                r#"[]"#,
                r#"null"#,
            ];
            let n = rng.random_range(0..40);
            let steps: Vec<&str> = (0..n).map(|_| STEPS[rng.random_range(0..STEPS.len())]).collect();
            let list = format!("[{}]", steps.join(","));
            match rng.random_range(0..3) {
                0 => list,
                1 => format!("{{\"plan\":{list}}}"),
                _ => format!("{{\"steps\":{list}}}"),
            }
        }
    };
    if rng.random_bool(0.2) {
        text = format!("Here is the plan:\n```json\n{text}\n```\nDone.");
    }
    if rng.random_bool(0.01) {
        text = "[".repeat(rng.random_range(1..5000));
    }
    text
}

#[test]
fn plan_text_is_validated_or_refused_with_reasons() {
    // Real plans of the corpus, in their JSON form.
    let mut planner = planner_with(Grounder::lexical_only());
    let plans: Vec<String> = seed_refs()
        .into_iter()
        .filter_map(|s| match planner.plan(s, "rules").ok()?.outcome {
            Outcome::Plan(p) => Some(p.to_json_string()),
            Outcome::Clarify(_) => None,
        })
        .collect();
    assert!(plans.len() > 100, "{} plans", plans.len());
    let validator = Validator::new();
    let report = fuzz::run(
        "validator",
        3_000,
        |rng| plan_text(rng, &plans),
        |text| match validator.validate_text(text) {
            Ok(v) => {
                assert!(!v.plan.steps.is_empty(), "{text:?}: an empty plan passed");
                let again = validator.validate_plan(&v.plan).unwrap_or_else(|e| panic!("{text:?}: {e:?}"));
                assert_eq!(again.plan, v.plan, "{text:?}: validation is idempotent");
                "valid".into()
            }
            Err(errors) => {
                assert!(!errors.is_empty() && errors.iter().all(|e| !e.trim().is_empty()), "{text:?}: {errors:?}");
                "refused".into()
            }
        },
    );
    report.assert_no_panics();
    assert!(report.count("valid") > 0 && report.count("refused") > 0, "{report}");
}

/// Inputs the fuzzer found that once crashed the parser, each with the
/// answer it must give now.
#[test]
fn fuzz_findings_stay_fixed() {
    let mut planner = planner_with(Grounder::lexical_only());
    let validator = Validator::new();
    // A clause that begins with "until" and holds a negation once recursed on itself until the stack overflowed.
    for text in ["until you don't stop", "move 2 m, then until not the chair", "until until never"] {
        check_answer(&validator, text, planner.plan(text, "rules"));
    }
    // Ids written as numbers with no fraction pass the schema ("integer"); they were read as
    // -1, so a reference class -1 left the validator (and a FIND id 56.0 was refused).
    for (text, id, ref_id) in [
        (r#"[{"action":"FIND","id":41,"ref":{"id":3.0,"relation":"on","target":"table"},"target":"cup"}]"#, 41, 3),
        (r#"[{"action":"FIND","id":56.0,"ref":{"id":-0.00,"relation":"near","target":"x"},"target":"chair"}]"#, 56, 0),
        (
            r#"[{"action":"FIND","id":15,"ref":{"id":1e-4007,"relation":"behind","target":"couch"},"target":"cat"}]"#,
            15,
            0,
        ),
    ] {
        let v = validator.validate_text(text).unwrap_or_else(|e| panic!("{text}: {e:?}"));
        let step = &v.plan.steps[0];
        assert_eq!((step.class_id, step.reference.as_ref().unwrap().class_id), (id, ref_id), "{text}");
        assert_eq!(validator.validate_plan(&v.plan).unwrap().plan, v.plan, "{text}");
    }
}
