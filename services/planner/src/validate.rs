//! The one gate every plan passes, whatever produced it: the JSON Schema
//! (draft 2020-12, `schema/action_plan.schema.json`) plus the semantic rules
//! the schema cannot say. Moves longer than [`MAX_STEP_M`] are split first,
//! so a plan that leaves here always satisfies the schema.

use serde_json::Value;

use crate::plan::{Action, MAX_STEP_M, MAX_STEPS, Plan, Step};

/// The schema document, as served by `GetPlanSchema`.
pub const PLAN_SCHEMA: &str = include_str!("../schema/action_plan.schema.json");

/// Longest single move the validator will split rather than reject, metres.
pub const MAX_SPLIT_M: f64 = MAX_STEP_M * 8.0;

/// A plan that passed, with what was changed on the way.
#[derive(Clone, Debug, PartialEq)]
pub struct Validated {
    pub plan: Plan,
    pub notes: Vec<String>,
}

pub struct Validator {
    schema: jsonschema::Validator,
}

impl std::fmt::Debug for Validator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Validator")
    }
}

impl Default for Validator {
    fn default() -> Self {
        Self::new()
    }
}

impl Validator {
    pub fn new() -> Validator {
        let doc: Value = serde_json::from_str(PLAN_SCHEMA).expect("the bundled plan schema is valid JSON");
        let schema = jsonschema::draft202012::new(&doc).expect("the bundled plan schema compiles");
        Validator { schema }
    }

    /// Validates a plan in its JSON form (text, possibly with prose or code
    /// fences around it, as language models write it).
    pub fn validate_text(&self, text: &str) -> Result<Validated, Vec<String>> {
        let json = extract_json(text).ok_or_else(|| {
            let head: String = text.chars().take(120).collect();
            vec![format!("no complete JSON array or object in the output (it begins {head:?})")]
        })?;
        let value: Value = serde_json::from_str(json).map_err(|e| vec![format!("not valid JSON: {e}")])?;
        self.validate_value(value)
    }

    /// Validates a JSON value: split long moves, then schema, then semantics.
    pub fn validate_value(&self, mut value: Value) -> Result<Validated, Vec<String>> {
        // A lone step object or an object wrapping the steps is accepted as the plan.
        if let Value::Object(o) = &value {
            if let Some(inner) = o.get("plan").or_else(|| o.get("steps")) {
                value = inner.clone();
            } else if o.contains_key("action") {
                value = Value::Array(vec![value.clone()]);
            }
        }
        let mut notes = Vec::new();
        split_long_moves(&mut value, &mut notes)?;
        let errors: Vec<String> = self
            .schema
            .iter_errors(&value)
            .map(|e| {
                let at = e.instance_path().to_string();
                if at.is_empty() { e.to_string() } else { format!("at {at}: {e}") }
            })
            .collect();
        if !errors.is_empty() {
            return Err(errors);
        }
        let plan = Plan::from_json(&value).map_err(|e| vec![e])?;
        semantic_errors(&plan).map(|()| Validated { plan, notes })
    }

    /// Validates a plan built in code (rule parser, replanning, a proto
    /// plan): through its JSON form, so the same rules apply.
    pub fn validate_plan(&self, plan: &Plan) -> Result<Validated, Vec<String>> {
        let errors: Vec<String> = finite_errors(plan);
        if !errors.is_empty() {
            return Err(errors);
        }
        let mut validated = self.validate_value(plan.to_json())?;
        // The JSON form has no sources; the validator keeps the steps' order and
        // splits a long move into consecutive parts, so each part keeps its step's words.
        let mut parts = validated.plan.steps.iter_mut();
        for s in &plan.steps {
            let n = if s.action == Action::Move && s.f_dist > MAX_STEP_M && s.f_dist <= MAX_SPLIT_M {
                (s.f_dist / MAX_STEP_M).ceil() as usize
            } else {
                1
            };
            for part in parts.by_ref().take(n) {
                part.source.clone_from(&s.source);
            }
        }
        Ok(validated)
    }
}

fn finite_errors(plan: &Plan) -> Vec<String> {
    let mut errors = Vec::new();
    for (i, s) in plan.steps.iter().enumerate() {
        for (name, x) in [("f_dist", s.f_dist), ("yaw", s.yaw)] {
            if !x.is_finite() {
                errors.push(format!("step {i}: {name} must be a finite number"));
            }
        }
        for (name, x) in [("d_s", s.d_s), ("duration_s", s.duration_s)] {
            if x.is_some_and(|x| !x.is_finite()) {
                errors.push(format!("step {i}: {name} must be a finite number"));
            }
        }
    }
    errors
}

/// Rules the schema cannot express.
fn semantic_errors(plan: &Plan) -> Result<(), Vec<String>> {
    let mut errors = finite_errors(plan);
    if plan.steps.len() > MAX_STEPS {
        errors.push(format!("a plan holds at most {MAX_STEPS} steps, this one {}", plan.steps.len()));
    }
    for (i, s) in plan.steps.iter().enumerate() {
        match s.action {
            Action::Move => {
                if s.f_dist.abs() < 0.1 && s.yaw.abs() < 0.01 {
                    errors.push(format!("step {i}: MOVE neither turns nor drives"));
                }
            }
            Action::Find | Action::Follow => {
                if vlnav_proto::coco::name(s.class_id).is_none() {
                    errors.push(format!("step {i}: id {} is not a COCO-80 class id (0..=79)", s.class_id));
                }
                if s.target.trim().is_empty() {
                    errors.push(format!("step {i}: target must name what to look for"));
                }
                if s.person.is_some() && s.class_id != 0 {
                    errors.push(format!("step {i}: a named person must have id 0 (person), not {}", s.class_id));
                }
            }
            Action::Return => {}
        }
    }
    if errors.is_empty() { Ok(()) } else { Err(errors) }
}

/// Splits every MOVE with `f_dist` above [`MAX_STEP_M`] into equal parts of
/// at most that length (the turn stays on the first part). Moves beyond
/// [`MAX_SPLIT_M`] are rejected as implausible.
fn split_long_moves(value: &mut Value, notes: &mut Vec<String>) -> Result<(), Vec<String>> {
    let Some(items) = value.as_array_mut() else { return Ok(()) };
    let mut out = Vec::with_capacity(items.len());
    for (i, item) in items.drain(..).enumerate() {
        let is_move = item.get("action").and_then(Value::as_str) == Some("MOVE");
        let dist = item.get("f_dist").and_then(Value::as_f64);
        match (is_move, dist) {
            (true, Some(d)) if d > MAX_STEP_M && d <= MAX_SPLIT_M => {
                let parts = (d / MAX_STEP_M).ceil() as usize;
                let each = round_cm(d / parts as f64);
                notes.push(format!(
                    "step {i}: split a {d} m move into {parts} moves of {each} m (at most {MAX_STEP_M} m each)"
                ));
                for k in 0..parts {
                    let mut part = item.clone();
                    part["f_dist"] = serde_json::json!(each);
                    if k > 0 {
                        part["yaw"] = serde_json::json!(0.0);
                    }
                    out.push(part);
                }
            }
            (true, Some(d)) if d > MAX_SPLIT_M => {
                return Err(vec![format!(
                    "step {i}: a {d} m move is beyond the {MAX_SPLIT_M} m one instruction may cover"
                )]);
            }
            _ => out.push(item),
        }
    }
    *items = out;
    Ok(())
}

fn round_cm(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// The first balanced JSON array or object in `text` (models like to wrap
/// their answer in prose or code fences).
pub fn extract_json(text: &str) -> Option<&str> {
    let start = text.find(['[', '{'])?;
    let bytes = text.as_bytes();
    let mut depth = 0usize;
    let mut in_str = false;
    let mut escaped = false;
    for (k, &b) in bytes[start..].iter().enumerate() {
        if in_str {
            match b {
                _ if escaped => escaped = false,
                b'\\' => escaped = true,
                b'"' => in_str = false,
                _ => {}
            }
            continue;
        }
        match b {
            b'"' => in_str = true,
            b'[' | b'{' => depth += 1,
            b']' | b'}' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return Some(&text[start..start + k + 1]);
                }
            }
            _ => {}
        }
    }
    None
}

/// One step's JSON for messages (the first error quoting it).
pub fn describe(step: &Step) -> String {
    step.to_json().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v() -> Validator {
        Validator::new()
    }

    #[test]
    fn accepts_the_papers_plan() {
        let text = r#"[{"action":"FIND","target":"statue (human)","id":0},{"action":"MOVE","desc":"turn right...","f_dist":2.5,"yaw":-1.57},{"action":"FIND","target":"visitor chair","id":56},{"action":"FIND","target":"bicycle","id":1}]"#;
        let ok = v().validate_text(text).unwrap();
        assert_eq!(ok.plan.steps.len(), 4);
        assert_eq!(ok.plan.steps[2].class_id, 56);
        assert!(ok.notes.is_empty());
    }

    #[test]
    fn rejects_actions_outside_the_closed_set() {
        let err = v().validate_text(r#"[{"action":"SHUTDOWN"}]"#).unwrap_err();
        assert!(!err.is_empty());
        let err = v().validate_text(r#"[{"action":"MOVE","f_dist":1,"yaw":0,"cmd":"rm -rf /"}]"#).unwrap_err();
        assert!(err.iter().any(|e| e.contains("/0")), "{err:?}");
    }

    #[test]
    fn rejects_unknown_class_ids_and_missing_fields() {
        assert!(v().validate_text(r#"[{"action":"FIND","target":"x","id":80}]"#).is_err());
        assert!(v().validate_text(r#"[{"action":"FIND","target":"chair"}]"#).is_err());
        assert!(v().validate_text(r#"[{"action":"FIND","target":"dog","id":16,"person":"david"}]"#).is_err());
        assert!(v().validate_text(r#"[]"#).is_err());
        assert!(v().validate_text("no json here").is_err());
    }

    #[test]
    fn splits_long_moves_into_steps_of_at_most_ten_metres() {
        let ok = v().validate_text(r#"[{"action":"MOVE","f_dist":25,"yaw":1.57}]"#).unwrap();
        let d: Vec<(f64, f64)> = ok.plan.steps.iter().map(|s| (s.f_dist, s.yaw)).collect();
        assert_eq!(d, vec![(8.33, 1.57), (8.33, 0.0), (8.33, 0.0)]);
        assert_eq!(ok.notes.len(), 1);
        assert!(v().validate_text(r#"[{"action":"MOVE","f_dist":500,"yaw":0}]"#).is_err());
    }

    #[test]
    fn rejects_non_finite_and_no_op_steps() {
        let plan = Plan::new(vec![Step::moving("", f64::INFINITY, 0.0)]);
        assert!(v().validate_plan(&plan).unwrap_err()[0].contains("finite"));
        let plan = Plan::new(vec![Step::moving("", 0.0, 0.0)]);
        assert!(v().validate_plan(&plan).unwrap_err()[0].contains("neither"));
    }

    #[test]
    fn bounds_the_step_count() {
        let plan = Plan::new(vec![Step::go_back(""); MAX_STEPS + 1]);
        assert!(v().validate_plan(&plan).is_err());
    }

    #[test]
    fn finds_json_inside_prose_and_fences() {
        assert_eq!(extract_json("Plan:\n```json\n[{\"a\":\"]\"}]\n```"), Some("[{\"a\":\"]\"}]"));
        assert_eq!(extract_json("nothing"), None);
        let ok = v().validate_text("```json\n{\"plan\":[{\"action\":\"RETURN\"}]}\n```").unwrap();
        assert_eq!(ok.plan.steps[0].action, Action::Return);
    }
}
