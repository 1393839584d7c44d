//! The provenance check of a plan another backend proposed: every distance,
//! angle, target and return must be something the instruction's words state
//! ([`htn::stated`], the rule parser's own lexicon). The rule parser keeps
//! this invariant by construction (`tests/motion.rs`); a language model's
//! plan passes it here or is refused, so a model cannot add motion nobody
//! asked for. A plan that passes leaves with each step's `source` set to the
//! words it was matched to.

use crate::grounding::Grounder;
use crate::htn::{self, Stated};
use crate::plan::{Action, Plan, Step};

/// Distance tolerance: a leg matches a stated length within 5 cm or 2 %.
fn length_matches(leg: f64, said: f64) -> bool {
    (leg - said).abs() <= 0.05_f64.max(0.02 * said)
}

/// Angle tolerance, radians (1.57 for "left" and 1.5708 for "90 degrees").
const ANGLE_TOLERANCE: f64 = 0.05;

/// Checks `plan` against `instruction`; on success returns it with every
/// step's `source`; otherwise one message per step the words do not support.
pub fn check(plan: &Plan, instruction: &str, grounder: &Grounder) -> Result<Plan, Vec<String>> {
    let said = htn::stated(instruction);
    let mut errors = Vec::new();
    let mut steps: Vec<Step> = plan.steps.clone();
    // The validator splits a leg longer than one step may drive into pieces
    // with no turn between them: the words state the whole leg.
    let mut i = 0;
    let mut driven = 0.0;
    while i < steps.len() {
        if steps[i].action != Action::Move {
            i += 1;
            continue;
        }
        let mut end = i + 1;
        while end < steps.len() && steps[end].action == Action::Move && steps[end].yaw == 0.0 {
            end += 1;
        }
        let leg: f64 = steps[i..end].iter().map(|s| s.f_dist).sum();
        driven += leg;
        match move_source(leg, steps[i].yaw, &said) {
            Ok(source) => steps[i..end].iter_mut().for_each(|s| s.source = source.clone()),
            Err(e) => errors.push(format!("step {} ({}): {e}", i + 1, crate::validate::describe(&steps[i]))),
        }
        i = end;
    }
    let stated_total: f64 = said.lengths.iter().map(|(v, _)| v).sum();
    if driven > stated_total + 0.05 {
        errors.push(format!("the plan drives {driven:.2} m in all; the instruction states {stated_total:.2} m"));
    }
    for (k, step) in steps.iter_mut().enumerate() {
        let verdict = match step.action {
            Action::Move => continue,
            Action::Find | Action::Follow => target_source(step, &said, grounder),
            Action::Return => said.back.clone().ok_or_else(|| "no words of the instruction ask to go back".to_string()),
        };
        match verdict {
            Ok(source) => step.source = source,
            Err(e) => errors.push(format!("step {} ({}): {e}", k + 1, crate::validate::describe(step))),
        }
    }
    if errors.is_empty() { Ok(Plan::new(steps)) } else { Err(errors) }
}

/// The words a MOVE of `leg` metres after a turn of `yaw` radians comes from.
fn move_source(leg: f64, yaw: f64, said: &Stated) -> Result<String, String> {
    let mut parts: Vec<String> = Vec::new();
    if yaw.abs() > ANGLE_TOLERANCE {
        match stated_turn(&said.angles, yaw) {
            Some(words) => parts.push(words),
            None => return Err(format!("it turns {yaw:.2} rad; the instruction states no such turn")),
        }
    }
    if leg > 0.0 {
        match stated_run(&said.lengths, leg) {
            Some(words) => {
                if !parts.contains(&words) {
                    parts.push(words)
                }
            }
            None => return Err(format!("it drives {leg:.2} m; the instruction states no such distance")),
        }
    }
    if parts.is_empty() {
        return Err("it neither turns nor drives".into());
    }
    Ok(parts.join(" + "))
}

/// A stated length equal to `leg`, or a run of consecutive stated lengths
/// that adds up to it ("forward 2 m, then 3 more metres" as one 5 m leg).
fn stated_run(lengths: &[(f64, String)], leg: f64) -> Option<String> {
    for start in 0..lengths.len() {
        let mut total = 0.0;
        for end in start..lengths.len() {
            total += lengths[end].0;
            if length_matches(leg, total) {
                let words: Vec<&str> = lengths[start..=end].iter().map(|(_, w)| w.as_str()).collect();
                return Some(words.join(" + "));
            }
            if total > leg + 0.1 {
                break;
            }
        }
    }
    None
}

/// A stated turn equal to `yaw`, or a run of consecutive stated turns that
/// composes to it ("left, then left again" as an about-turn; "left, then
/// around" as a right turn), compared modulo a full turn, so an about-turn
/// is the same either way round.
fn stated_turn(angles: &[(f64, String)], yaw: f64) -> Option<String> {
    let close = |a: f64| {
        let d = (a - yaw).rem_euclid(std::f64::consts::TAU);
        d.min(std::f64::consts::TAU - d) <= ANGLE_TOLERANCE
    };
    for start in 0..angles.len() {
        let mut total = 0.0;
        for end in start..angles.len().min(start + 4) {
            total += angles[end].0;
            if close(total) {
                let words: Vec<&str> = angles[start..=end].iter().map(|(_, w)| w.as_str()).collect();
                return Some(words.join(" + "));
            }
        }
    }
    None
}

/// Words a phrase may leave out of the instruction: articles and the like.
const FUNCTION_WORDS: &[&str] =
    &["the", "a", "an", "to", "of", "my", "your", "that", "this", "mr", "mrs", "ms", "dr", "miss", "mister", "missus"];

/// A word without the punctuation around it: "(human)" → "human", "mr." → "mr".
fn bare_word(w: &str) -> &str {
    w.trim_matches(|c: char| !c.is_alphanumeric() && c != '\'' && c != '-')
}

/// Whether `word` (lower case) is among the instruction's words, allowing a
/// plural or possessive ending.
fn said_word(said: &Stated, word: &str) -> bool {
    let stem = |w: &str| bare_word(w).trim_end_matches("'s").trim_end_matches('s').to_string();
    said.words.iter().any(|w| bare_word(w) == word || stem(w) == stem(word))
}

/// The words a FIND or FOLLOW comes from: its target phrase must be said, and
/// ground to the step's class; a named person's name must be said.
fn target_source(step: &Step, said: &Stated, grounder: &Grounder) -> Result<String, String> {
    let phrase = step.target.trim().to_lowercase();
    let missing: Vec<&str> = phrase
        .split_whitespace()
        .map(bare_word)
        .filter(|w| !w.is_empty() && !FUNCTION_WORDS.contains(w) && !said_word(said, w))
        .collect();
    if phrase.is_empty() {
        return Err("it names no target".into());
    }
    if !missing.is_empty() {
        return Err(format!("the instruction does not say \"{}\"", missing.join(" ")));
    }
    if let Some(person) = &step.person {
        if !said_word(said, &person.to_lowercase()) {
            return Err(format!("the instruction names no \"{person}\""));
        }
        if step.class_id != 0 {
            return Err(format!("a named person is class 0 (person), not {}", step.class_id));
        }
    } else {
        match htn::class_of(grounder, &phrase) {
            Some(id) if id == step.class_id => {}
            Some(id) => {
                return Err(format!(
                    "\"{phrase}\" is {} (id {id}), not id {}",
                    vlnav_proto::coco::CLASSES[id as usize],
                    step.class_id
                ));
            }
            None => return Err(format!("\"{phrase}\" names none of the classes the robot can see")),
        }
    }
    if let Some(t) = step.duration_s
        && !said.durations.iter().any(|d| (d - t).abs() <= 0.5)
    {
        return Err(format!("it follows for {t} s; the instruction states no such duration"));
    }
    if let Some(r) = &step.reference {
        let target = r.target.to_lowercase();
        let words: Vec<&str> =
            target.split_whitespace().map(bare_word).filter(|w| !FUNCTION_WORDS.contains(w)).collect();
        if let Some(w) = words.iter().find(|w| !w.is_empty() && !said_word(said, w)) {
            return Err(format!("the instruction does not say \"{w}\" (the reference)"));
        }
    }
    Ok(phrase)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Step;

    fn check_json(plan: &[Step], text: &str) -> Result<Plan, Vec<String>> {
        check(&Plan::new(plan.to_vec()), text, &Grounder::lexical_only())
    }

    #[test]
    fn stated_distances_and_turns_pass_with_their_words() {
        let plan = [Step::moving("", 3.0, -1.57), Step::find("chair", 56)];
        let ok = check_json(&plan, "turn right and go 3 meters, then find the chair").unwrap();
        assert!(ok.steps[0].source.contains("3 meters"), "{:?}", ok.steps[0].source);
        assert_eq!(ok.steps[1].source, "chair");
    }

    #[test]
    fn a_leg_longer_than_said_is_refused() {
        let e = check_json(&[Step::moving("", 8.0, 0.0)], "move forward 1 m").unwrap_err();
        assert!(e.iter().any(|m| m.contains("no such distance")), "{e:?}");
        assert!(e.iter().any(|m| m.contains("drives 8.00 m in all")), "{e:?}");
    }

    #[test]
    fn motion_from_no_words_is_refused() {
        let e = check_json(&[Step::moving("", 2.5, 0.0), Step::find("chair", 56)], "find the chair").unwrap_err();
        assert!(e.iter().any(|m| m.contains("step 1")), "{e:?}");
    }

    #[test]
    fn a_destination_is_not_a_vague_drive() {
        assert!(check_json(&[Step::moving("", 2.5, 0.0)], "go to the chair").is_err());
        assert!(check_json(&[Step::moving("", 8.0, 0.0)], "go to the chair, then the far lamp").is_err());
        check_json(&[Step::moving("", 2.5, 1.57)], "go left").unwrap();
        check_json(&[Step::moving("", 8.0, 0.0)], "drive far ahead").unwrap();
    }

    #[test]
    fn a_turn_to_the_side_not_said_is_refused() {
        let e = check_json(&[Step::moving("", 0.0, 1.57)], "turn right").unwrap_err();
        assert!(e[0].contains("no such turn"), "{e:?}");
        check_json(&[Step::moving("", 0.0, -1.57)], "turn right").unwrap();
        check_json(&[Step::moving("", 0.0, htn::HALF_TURN)], "turn around").unwrap();
    }

    #[test]
    fn a_split_long_leg_counts_as_one() {
        let plan = [Step::moving("", 10.0, 0.0), Step::moving("", 2.0, 0.0)];
        check_json(&plan, "drive 12 metres forward").unwrap();
    }

    #[test]
    fn consecutive_distances_may_make_one_leg() {
        check_json(&[Step::moving("", 5.0, 0.0)], "go forward 2 m and then 3 more metres").unwrap();
    }

    #[test]
    fn targets_must_be_said_and_ground_to_their_class() {
        let e = check_json(&[Step::find("bicycle", 1)], "find the chair").unwrap_err();
        assert!(e[0].contains("does not say \"bicycle\""), "{e:?}");
        let e = check_json(&[Step::find("chair", 0)], "find the chair").unwrap_err();
        assert!(e[0].contains("not id 0"), "{e:?}");
        check_json(&[Step::find("chairs", 56)], "go to the chair").unwrap();
        let e = check_json(&[Step::find("sarah", 0).with_person("sarah")], "find Tom").unwrap_err();
        assert!(e[0].contains("does not say"), "{e:?}");
        check_json(&[Step::follow("sarah", 0).with_person("sarah")], "stay with Sarah").unwrap();
        check_json(&[Step::follow("dog", 16).with_duration(20.0)], "follow the dog for 20 seconds").unwrap();
        let e = check_json(&[Step::follow("dog", 16).with_duration(20.0)], "follow the dog").unwrap_err();
        assert!(e[0].contains("no such duration"), "{e:?}");
    }

    #[test]
    fn a_return_needs_words_that_ask_for_it() {
        check_json(&[Step::go_back("")], "then come back").unwrap();
        assert!(check_json(&[Step::go_back("")], "find the chair").is_err());
    }
}
