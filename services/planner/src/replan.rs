//! Replanning after a failed step: the steps before it are done; the user's
//! answer to the clarification decides what replaces it.
//!
//! - "skip it", "never mind", "move on" → the steps after the failed one;
//! - "try again", "look again" → the failed step and the rest again;
//! - "go back", "come back", "return" → RETURN;
//! - a target ("it's the red chair", "try the couch", "look for Mr. David")
//!   → the failed step with that target, then the rest;
//! - a full instruction ("turn left and find the bench") → its plan, then the rest;
//! - anything that cannot be grounded → another question.

use crate::grounding::Grounder;
use crate::htn::{self, Parsed};
use crate::plan::{Action, Clarification, Outcome, Plan, Step};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplanError {
    #[error("plan: it has no steps to revise")]
    EmptyPlan,
    #[error("failed_step: {index} is outside the plan's {len} steps (0-based)")]
    FailedStepOutOfRange { index: usize, len: usize },
    #[error("answer: {0}")]
    Answer(htn::InputError),
}

const SKIP: &[&str] = &[
    "skip",
    "skip it",
    "skip that",
    "never mind",
    "nevermind",
    "forget it",
    "move on",
    "ignore it",
    "leave it",
    "carry on",
    "continue",
    "next",
];
const RETRY: &[&str] =
    &["try again", "look again", "retry", "search again", "again", "keep looking", "look more", "try once more"];
const BACK: &[&str] =
    &["go back", "come back", "return", "return to me", "come back to me", "go home", "abort", "give up"];

/// Lead-in words of an answer that names a target: "it's the red chair".
const LEAD_INS: &[&str] = &[
    "it's", "its", "it", "is", "that's", "thats", "that", "this", "try", "look", "for", "find", "search", "instead",
    "no", "actually", "i", "mean", "meant", "rather", "the", "a", "an", "please", "go", "to", "check", "maybe",
    "probably", "perhaps", "then", "oh", "sorry",
];

fn normalise(answer: &str) -> String {
    answer
        .to_lowercase()
        .chars()
        .map(|c| if c.is_alphanumeric() || c == '\'' || c == ' ' || c == '.' || c == '(' || c == ')' { c } else { ' ' })
        .collect::<String>()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .trim_end_matches('.')
        .to_string()
}

/// The revised plan for the remaining steps.
pub fn replan(
    plan: &Plan,
    failed_step: usize,
    failure: &str,
    answer: &str,
    grounder: &Grounder,
) -> Result<Parsed, ReplanError> {
    if plan.steps.is_empty() {
        return Err(ReplanError::EmptyPlan);
    }
    if failed_step >= plan.steps.len() {
        return Err(ReplanError::FailedStepOutOfRange { index: failed_step, len: plan.steps.len() });
    }
    htn::check_input(answer).map_err(ReplanError::Answer)?;
    let failed = &plan.steps[failed_step];
    let rest = &plan.steps[failed_step + 1..];
    let a = normalise(answer);
    let mut notes = vec![format!("step {failed_step} ({}) failed: {}", failed.action.as_str(), failure.trim())];

    let done = |steps: Vec<Step>, mut notes: Vec<String>, why: &str| -> Result<Parsed, ReplanError> {
        notes.push(why.to_string());
        if steps.is_empty() {
            return Ok(Parsed {
                outcome: Outcome::Clarify(Clarification {
                    question: "Nothing is left to do. Should I go back?".into(),
                    reason: "the revised plan is empty".into(),
                    options: vec!["go back".into()],
                }),
                notes,
                ungrounded: vec![],
            });
        }
        Ok(Parsed { outcome: Outcome::Plan(Plan::new(steps)), notes, ungrounded: vec![] })
    };

    if SKIP.contains(&a.as_str()) || a.starts_with("skip ") {
        return done(rest.to_vec(), notes, "skipped the failed step");
    }
    if RETRY.contains(&a.as_str()) {
        return done(plan.steps[failed_step..].to_vec(), notes, "retrying the failed step");
    }
    if BACK.contains(&a.as_str()) {
        return done(vec![Step::go_back("return to the start")], notes, "returning to the start");
    }

    let targeted = matches!(failed.action, Action::Find | Action::Follow);
    // A bare target phrase: strip lead-ins and ground what is left.
    if targeted {
        let words: Vec<&str> = a.split_whitespace().collect();
        let start = words.iter().position(|w| !LEAD_INS.contains(w)).unwrap_or(words.len());
        let phrase = words[start..].join(" ");
        let phrase = phrase.trim_end_matches(" instead").to_string();
        if !phrase.is_empty()
            && !phrase.split_whitespace().any(|w| {
                matches!(w, "turn" | "move" | "left" | "right" | "meters" | "metres" | "m" | "then" | "and" | "follow")
            })
        {
            let probe = format!("find {phrase}");
            let parsed = htn::parse(&probe, grounder);
            if let Outcome::Plan(p) = &parsed.outcome
                && let [found] = p.steps.as_slice()
                && found.action == Action::Find
            {
                let mut replaced = failed.clone();
                replaced.target = found.target.clone();
                replaced.class_id = found.class_id;
                replaced.person = found.person.clone();
                let mut steps = vec![replaced];
                steps.extend_from_slice(rest);
                notes.extend(parsed.notes);
                return done(
                    steps,
                    notes,
                    &format!("replaced the target of step {failed_step} with \"{}\"", found.target),
                );
            }
            if let Outcome::Clarify(_) = parsed.outcome
                && !phrase.contains(' ')
            {
                return Ok(Parsed { outcome: parsed.outcome, notes, ungrounded: parsed.ungrounded });
            }
        }
    }

    // A full instruction: its plan, then what was left.
    let parsed = htn::parse(answer, grounder);
    match parsed.outcome {
        Outcome::Plan(p) => {
            let mut steps = p.steps;
            if !steps.iter().any(|s| s.action == Action::Return) {
                steps.extend_from_slice(rest);
            }
            notes.extend(parsed.notes);
            done(steps, notes, "replaced the failed step with the answer's plan")
        }
        Outcome::Clarify(c) => {
            notes.extend(parsed.notes);
            Ok(Parsed { outcome: Outcome::Clarify(c), notes, ungrounded: vec![] })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> Plan {
        Plan::new(vec![Step::moving("ahead", 2.0, 0.0), Step::find("visitor chair", 56), Step::find("bicycle", 1)])
    }

    fn steps(p: &Parsed) -> Vec<Step> {
        match &p.outcome {
            Outcome::Plan(p) => p.steps.clone(),
            Outcome::Clarify(c) => panic!("asked: {c:?}"),
        }
    }

    #[test]
    fn skip_retry_and_go_back() {
        let g = Grounder::lexical_only();
        assert_eq!(steps(&replan(&plan(), 1, "not found", "skip it", &g).unwrap()), vec![Step::find("bicycle", 1)]);
        assert_eq!(steps(&replan(&plan(), 1, "not found", "Try again!", &g).unwrap()).len(), 2);
        assert_eq!(
            steps(&replan(&plan(), 1, "not found", "go back", &g).unwrap()),
            vec![Step::go_back("return to the start")]
        );
    }

    #[test]
    fn a_named_target_replaces_the_failed_one() {
        let g = Grounder::lexical_only();
        let s = steps(&replan(&plan(), 1, "not found", "it's the red chair", &g).unwrap());
        assert_eq!(s[0], Step::find("red chair", 56));
        assert_eq!(s[1], Step::find("bicycle", 1));
        let s = steps(&replan(&plan(), 1, "not found", "try the couch", &g).unwrap());
        assert_eq!(s[0], Step::find("couch", 57));
    }

    #[test]
    fn bad_indices_and_unknown_targets() {
        let g = Grounder::lexical_only();
        assert!(matches!(replan(&plan(), 3, "", "skip", &g), Err(ReplanError::FailedStepOutOfRange { .. })));
        assert!(matches!(replan(&Plan::default(), 0, "", "skip", &g), Err(ReplanError::EmptyPlan)));
        let r = replan(&plan(), 1, "not found", "the pharmacy", &g).unwrap();
        assert!(matches!(r.outcome, Outcome::Clarify(_)));
    }
}
