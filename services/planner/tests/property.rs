//! Arbitrary text never panics the planner, and every answer is a valid plan
//! or a question (rule backend, real MiniLM grounding).

mod common;

use std::sync::OnceLock;

use proptest::prelude::*;
use vlnav_planner::grounding::Grounder;
use vlnav_planner::htn;
use vlnav_planner::plan::Outcome;
use vlnav_planner::validate::Validator;

fn grounder() -> &'static Grounder {
    static G: OnceLock<Grounder> = OnceLock::new();
    G.get_or_init(common::grounder)
}

fn check(text: &str) {
    let validator = Validator::new();
    if htn::check_input(text).is_err() {
        return;
    }
    match htn::parse(text, grounder()).outcome {
        Outcome::Plan(p) => {
            validator.validate_plan(&p).unwrap_or_else(|e| panic!("{text:?} gave an invalid plan: {e:?}"));
        }
        Outcome::Clarify(c) => assert!(!c.question.is_empty()),
    }
}

const WORDS: &[&str] = &[
    "move",
    "go",
    "turn",
    "left",
    "right",
    "around",
    "find",
    "follow",
    "the",
    "chair",
    "then",
    "and",
    "finally",
    "back",
    "2",
    "2.5m",
    "ten",
    "meters",
    "cm",
    "feet",
    "degrees",
    "90",
    "-3",
    "1e9",
    "it",
    "you",
    "may",
    "see",
    "Mr.",
    "David",
    "(human)",
    "statue",
    ",",
    ".",
    "stop",
    "near",
    "for",
    "seconds",
    "a",
    "little",
    "half",
    "point",
    "five",
    "report",
    "bring",
    "to",
    "deliver",
    "hundred",
    "and",
    "a half",
    "NaN",
    "inf",
    "999999999999",
    "step",
    "steps",
    "at",
    "spot",
    "where",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_strings_never_panic(text in ".{0,300}") {
        check(&text);
    }

    #[test]
    fn instruction_like_word_salad_gives_valid_plans_or_questions(words in proptest::collection::vec(proptest::sample::select(WORDS), 0..30)) {
        check(&words.join(" "));
    }
}
