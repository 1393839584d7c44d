//! The paraphrase corpus (`tests/corpus/*.tsv`): instructions as people say
//! them, one file per category, each line an instruction, a tab and the plan
//! the executor should get. Read here and scored against any backend's
//! answer, so the table-driven test and the backend comparison
//! (`examples/corpus.rs`) judge the same way.
//!
//! The expected plan is written compactly, steps separated by `;`:
//! - `MOVE <f_dist> <yaw>` (metres, radians, after the ≤ 10 m split);
//! - `FIND <id>` / `FOLLOW <id>` with optional `person=<name>`, `d=<d_s>`,
//!   `t=<duration_s>`, `ref=<reference class id>`;
//! - `RETURN`;
//! - `ungrounded <place>[, <place>]` (the places reported as not grounded);
//! - a lone `?` expects a clarification question.
//!
//! Compared: the actions in order, MOVE distances and turns (to 1 cm /
//! 0.01 rad), class ids, person, d_s, duration_s, the reference's class id
//! and the set of ungrounded places. Not compared: `desc` and the wording of
//! `target` (the class id is what the executor acts on).

use std::collections::BTreeMap;
use std::path::Path;

use crate::plan::{Action, Outcome, Planned, Step};

/// One corpus line.
#[derive(Clone, Debug, PartialEq)]
pub struct Case {
    pub category: String,
    pub instruction: String,
    pub expected: Expected,
    /// `file.tsv:line`, for messages.
    pub at: String,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Expected {
    Question,
    Plan { steps: Vec<ExpectedStep>, ungrounded: Vec<String> },
}

#[derive(Clone, Debug, PartialEq)]
pub struct ExpectedStep {
    pub action: Action,
    pub f_dist: f64,
    pub yaw: f64,
    pub class_id: i32,
    pub person: Option<String>,
    pub d_s: Option<f64>,
    pub duration_s: Option<f64>,
    pub reference: Option<i32>,
}

impl ExpectedStep {
    fn blank(action: Action) -> ExpectedStep {
        ExpectedStep {
            action,
            f_dist: 0.0,
            yaw: 0.0,
            class_id: -1,
            person: None,
            d_s: None,
            duration_s: None,
            reference: None,
        }
    }
}

/// Reads every `*.tsv` in `dir` (category = file stem), sorted by name.
pub fn load_dir(dir: &Path) -> Result<Vec<Case>, String> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "tsv"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(format!("{}: no *.tsv corpus files", dir.display()));
    }
    let mut cases = Vec::new();
    for f in files {
        let category = f.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
        let text = std::fs::read_to_string(&f).map_err(|e| format!("{}: {e}", f.display()))?;
        let name = f.file_name().and_then(|s| s.to_str()).unwrap_or_default().to_string();
        cases.extend(parse_file(&category, &name, &text)?);
    }
    Ok(cases)
}

/// Parses one corpus file's text.
pub fn parse_file(category: &str, name: &str, text: &str) -> Result<Vec<Case>, String> {
    let mut cases = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = format!("{name}:{}", i + 1);
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        let (instruction, expected) =
            line.split_once('\t').ok_or_else(|| format!("{at}: expected <instruction><TAB><plan>"))?;
        let expected = parse_expected(expected).map_err(|e| format!("{at}: {e}"))?;
        cases.push(Case { category: category.to_string(), instruction: instruction.trim().to_string(), expected, at });
    }
    Ok(cases)
}

/// Parses the compact plan notation (see the module documentation).
pub fn parse_expected(text: &str) -> Result<Expected, String> {
    let text = text.trim();
    if text == "?" {
        return Ok(Expected::Question);
    }
    let mut steps = Vec::new();
    let mut ungrounded = Vec::new();
    for part in text.split(';').map(str::trim).filter(|p| !p.is_empty()) {
        if let Some(places) = part.strip_prefix("ungrounded ") {
            ungrounded.extend(places.split(',').map(normalise_place).filter(|p| !p.is_empty()));
            continue;
        }
        let mut words = part.split_whitespace();
        let head = words.next().unwrap_or_default();
        let action = Action::parse(head).ok_or_else(|| format!("unknown action {head:?} in {part:?}"))?;
        let num = |w: Option<&str>, what: &str| -> Result<f64, String> {
            w.ok_or_else(|| format!("{part:?}: missing {what}"))?
                .parse::<f64>()
                .map_err(|e| format!("{part:?}: {what}: {e}"))
        };
        let mut step = ExpectedStep::blank(action);
        match action {
            Action::Move => {
                step.f_dist = num(words.next(), "f_dist")?;
                step.yaw = num(words.next(), "yaw")?;
            }
            Action::Find | Action::Follow => {
                step.class_id = num(words.next(), "class id")? as i32;
                for w in words.by_ref() {
                    let (k, v) = w.split_once('=').ok_or_else(|| format!("{part:?}: {w:?} is not key=value"))?;
                    match k {
                        "person" => step.person = Some(v.to_string()),
                        "d" => step.d_s = Some(num(Some(v), "d")?),
                        "t" => step.duration_s = Some(num(Some(v), "t")?),
                        "ref" => step.reference = Some(num(Some(v), "ref")? as i32),
                        _ => return Err(format!("{part:?}: unknown key {k:?}")),
                    }
                }
            }
            Action::Return => {}
        }
        if let Some(extra) = words.next() {
            return Err(format!("{part:?}: unexpected {extra:?}"));
        }
        steps.push(step);
    }
    if steps.is_empty() {
        return Err("no steps".into());
    }
    ungrounded.sort();
    Ok(Expected::Plan { steps, ungrounded })
}

/// "the Kitchen " → "kitchen": places compare without determiners or case.
pub fn normalise_place(p: &str) -> String {
    p.split_whitespace()
        .map(str::to_lowercase)
        .filter(|w| !matches!(w.as_str(), "the" | "a" | "an" | "my" | "your" | "our" | "this" | "that"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 0.006
}

fn close_opt(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => close(x, y),
        _ => false,
    }
}

/// The compact notation of an answer, for messages.
pub fn describe(planned: &Planned) -> String {
    let mut parts: Vec<String> = match &planned.outcome {
        Outcome::Clarify(c) => return format!("? ({})", c.reason),
        Outcome::Plan(p) => p.steps.iter().map(describe_step).collect(),
    };
    if !planned.ungrounded.is_empty() {
        parts.push(format!("ungrounded {}", planned.ungrounded.join(", ")));
    }
    parts.join("; ")
}

fn describe_step(s: &Step) -> String {
    match s.action {
        Action::Move => format!("MOVE {} {}", s.f_dist, s.yaw),
        Action::Return => "RETURN".into(),
        Action::Find | Action::Follow => {
            let mut out = format!("{} {}", s.action.as_str(), s.class_id);
            if let Some(p) = &s.person {
                out.push_str(&format!(" person={p}"));
            }
            if let Some(d) = s.d_s {
                out.push_str(&format!(" d={d}"));
            }
            if let Some(t) = s.duration_s {
                out.push_str(&format!(" t={t}"));
            }
            if let Some(r) = &s.reference {
                out.push_str(&format!(" ref={}", r.class_id));
            }
            out
        }
    }
}

/// `Ok` when the answer is the expected one; otherwise what differs.
pub fn judge(expected: &Expected, got: &Planned) -> Result<(), String> {
    let (want, want_ungrounded) = match (expected, &got.outcome) {
        (Expected::Question, Outcome::Clarify(_)) => return Ok(()),
        (Expected::Question, Outcome::Plan(_)) => return Err("expected a question".into()),
        (Expected::Plan { .. }, Outcome::Clarify(c)) => return Err(format!("asked: {}", c.question)),
        (Expected::Plan { steps, ungrounded }, Outcome::Plan(_)) => (steps, ungrounded),
    };
    let Outcome::Plan(plan) = &got.outcome else { unreachable!("matched above") };
    if plan.steps.len() != want.len() {
        return Err(format!("{} steps, expected {}", plan.steps.len(), want.len()));
    }
    for (i, (s, w)) in plan.steps.iter().zip(want).enumerate() {
        let same = s.action == w.action
            && match s.action {
                Action::Move => close(s.f_dist, w.f_dist) && close(s.yaw, w.yaw),
                Action::Return => true,
                Action::Find | Action::Follow => {
                    s.class_id == w.class_id
                        && s.person == w.person
                        && close_opt(s.d_s, w.d_s)
                        && close_opt(s.duration_s, w.duration_s)
                        && s.reference.as_ref().map(|r| r.class_id) == w.reference
                }
            };
        if !same {
            return Err(format!("step {i} is {}", describe_step(s)));
        }
    }
    let mut got_ungrounded: Vec<String> = got.ungrounded.iter().map(|p| normalise_place(p)).collect();
    got_ungrounded.sort();
    if &got_ungrounded != want_ungrounded {
        return Err(format!("ungrounded {got_ungrounded:?}, expected {want_ungrounded:?}"));
    }
    Ok(())
}

/// Passed / total per category, in file order.
#[derive(Clone, Debug, Default)]
pub struct Tally {
    pub per_category: BTreeMap<String, (usize, usize)>,
}

impl Tally {
    pub fn add(&mut self, category: &str, passed: bool) {
        let e = self.per_category.entry(category.to_string()).or_default();
        e.0 += passed as usize;
        e.1 += 1;
    }

    pub fn total(&self) -> (usize, usize) {
        self.per_category.values().fold((0, 0), |(p, n), (a, b)| (p + a, n + b))
    }

    pub fn accuracy(&self) -> f64 {
        let (p, n) = self.total();
        if n == 0 { 0.0 } else { p as f64 / n as f64 }
    }

    /// A Markdown table: category, passed, total, accuracy; then the total.
    pub fn markdown(&self) -> String {
        let mut s = String::from("| category | passed | of | accuracy |\n|---|---:|---:|---:|\n");
        for (c, (p, n)) in &self.per_category {
            s.push_str(&format!("| {c} | {p} | {n} | {:.1} % |\n", 100.0 * *p as f64 / (*n).max(1) as f64));
        }
        let (p, n) = self.total();
        s.push_str(&format!("| **all** | **{p}** | **{n}** | **{:.1} %** |\n", 100.0 * self.accuracy()));
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{Clarification, Plan, Reference};

    fn planned(steps: Vec<Step>, ungrounded: &[&str]) -> Planned {
        Planned {
            outcome: Outcome::Plan(Plan::new(steps)),
            backend: "rules".into(),
            notes: vec![],
            ungrounded: ungrounded.iter().map(|s| s.to_string()).collect(),
        }
    }

    #[test]
    fn reads_the_notation() {
        let e = parse_expected(
            "MOVE 2 1.57; FIND 56 ref=60 d=1; FOLLOW 0 person=david t=30; RETURN; ungrounded the Kitchen",
        )
        .unwrap();
        let Expected::Plan { steps, ungrounded } = e else { panic!() };
        assert_eq!(steps.len(), 4);
        assert_eq!((steps[0].f_dist, steps[0].yaw), (2.0, 1.57));
        assert_eq!((steps[1].class_id, steps[1].reference, steps[1].d_s), (56, Some(60), Some(1.0)));
        assert_eq!(steps[2].person.as_deref(), Some("david"));
        assert_eq!(ungrounded, vec!["kitchen".to_string()]);
        assert_eq!(parse_expected("?").unwrap(), Expected::Question);
        assert!(parse_expected("JUMP 3").is_err());
        assert!(parse_expected("FIND 56 colour=red").is_err());
        assert!(parse_expected("MOVE 2").is_err());
    }

    #[test]
    fn judges_every_compared_field() {
        let e = parse_expected("FIND 56 ref=60; ungrounded kitchen").unwrap();
        let mut chair = Step::find("chair", 56);
        assert!(judge(&e, &planned(vec![chair.clone()], &["kitchen"])).is_err(), "the reference is missing");
        chair.reference = Some(Reference { relation: "next to".into(), target: "table".into(), class_id: 60 });
        assert!(judge(&e, &planned(vec![chair.clone()], &["the kitchen"])).is_ok());
        assert!(judge(&e, &planned(vec![chair.clone()], &[])).is_err(), "the place is not reported");
        let e = parse_expected("MOVE 3 -1.57").unwrap();
        assert!(judge(&e, &planned(vec![Step::moving("", 3.0, -1.57)], &[])).is_ok());
        assert!(judge(&e, &planned(vec![Step::moving("", 3.0, 1.57)], &[])).is_err());
        let ask = Planned {
            outcome: Outcome::Clarify(Clarification { question: "q".into(), reason: "r".into(), options: vec![] }),
            backend: "rules".into(),
            notes: vec![],
            ungrounded: vec![],
        };
        assert!(judge(&Expected::Question, &ask).is_ok());
        assert!(judge(&e, &ask).is_err());
    }

    #[test]
    fn tallies_per_category() {
        let mut t = Tally::default();
        t.add("a", true);
        t.add("a", false);
        t.add("b", true);
        assert_eq!(t.total(), (2, 3));
        assert!(t.markdown().contains("| a | 1 | 2 | 50.0 % |"));
    }
}
