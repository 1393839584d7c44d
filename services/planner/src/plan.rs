//! The closed action set and its JSON form (the paper's keys: `action`,
//! `desc`, `f_dist`, `yaw`, `target`, `id`, plus `person`, `d_s`,
//! `duration_s` and `ref` where used). Plain Rust types; no proto.

use serde_json::{Map, Value, json};

/// Longest drive of one MOVE step, metres: the depth camera limits a subgoal to 10 m.
pub const MAX_STEP_M: f64 = 10.0;
/// Most steps a plan may hold.
pub const MAX_STEPS: usize = 32;
/// Longest accepted instruction, bytes.
pub const MAX_INSTRUCTION_BYTES: usize = 4096;

/// The closed action set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Action {
    Move,
    Find,
    Follow,
    Return,
}

impl Action {
    pub const ALL: [Action; 4] = [Action::Move, Action::Find, Action::Follow, Action::Return];

    pub fn as_str(self) -> &'static str {
        match self {
            Action::Move => "MOVE",
            Action::Find => "FIND",
            Action::Follow => "FOLLOW",
            Action::Return => "RETURN",
        }
    }

    pub fn parse(s: &str) -> Option<Action> {
        Action::ALL.into_iter().find(|a| a.as_str() == s)
    }
}

/// One step of a plan. Fields that do not apply to the action are left at
/// their defaults (empty, 0, `None`) and are not written to JSON.
#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub action: Action,
    pub desc: String,
    /// MOVE: metres to drive after turning.
    pub f_dist: f64,
    /// MOVE: radians to turn first, counter-clockwise positive (left).
    pub yaw: f64,
    /// FIND / FOLLOW: the target phrase as spoken.
    pub target: String,
    /// FIND / FOLLOW: COCO-80 class id.
    pub class_id: i32,
    /// FIND / FOLLOW: identity of a named person.
    pub person: Option<String>,
    /// FIND / FOLLOW: stopping distance, metres.
    pub d_s: Option<f64>,
    /// FOLLOW: how long, seconds.
    pub duration_s: Option<f64>,
    /// FIND / FOLLOW: the object the target was described by ("the chair
    /// next to the table"); the executor prefers the instance nearest it.
    pub reference: Option<Reference>,
    /// The instruction's words this step came from ("turn right 90 degrees",
    /// "a little ahead"): every distance and angle of a MOVE is read from
    /// them, or is the documented default of a vague phrase among them.
    /// Empty for a plan that did not come from the rule parser. Not part of
    /// the JSON form (the paper's keys); proto `ActionStep.source`.
    pub source: String,
}

/// A target described by its relation to another object (JSON key `ref`).
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// As spoken: "next to", "on", "behind".
    pub relation: String,
    /// The reference object's phrase and COCO-80 class id.
    pub target: String,
    pub class_id: i32,
}

impl Reference {
    pub fn to_json(&self) -> Value {
        json!({"relation": self.relation, "target": self.target, "id": self.class_id})
    }

    fn from_json(v: &Value) -> Option<Reference> {
        let o = v.as_object()?;
        Some(Reference {
            relation: o.get("relation").and_then(Value::as_str).unwrap_or_default().to_string(),
            target: o.get("target").and_then(Value::as_str).unwrap_or_default().to_string(),
            class_id: o.get("id").and_then(as_integer).map(|x| x.clamp(-1, i32::MAX as i64) as i32).unwrap_or(-1),
        })
    }
}

/// An integer as the schema counts one: `3`, or a number with no fraction
/// (`3.0`, `-0.0`), which JSON Schema's "integer" accepts too.
fn as_integer(v: &Value) -> Option<i64> {
    v.as_i64().or_else(|| v.as_f64().filter(|x| x.fract() == 0.0 && x.abs() < 9.0e18).map(|x| x as i64))
}

impl Step {
    pub fn moving(desc: impl Into<String>, f_dist: f64, yaw: f64) -> Step {
        Step { desc: desc.into(), f_dist, yaw, ..Step::blank(Action::Move) }
    }

    pub fn find(target: impl Into<String>, class_id: i32) -> Step {
        Step { target: target.into(), class_id, ..Step::blank(Action::Find) }
    }

    pub fn follow(target: impl Into<String>, class_id: i32) -> Step {
        Step { target: target.into(), class_id, ..Step::blank(Action::Follow) }
    }

    pub fn go_back(desc: impl Into<String>) -> Step {
        Step { desc: desc.into(), ..Step::blank(Action::Return) }
    }

    pub fn blank(action: Action) -> Step {
        Step {
            action,
            desc: String::new(),
            f_dist: 0.0,
            yaw: 0.0,
            target: String::new(),
            class_id: 0,
            person: None,
            d_s: None,
            duration_s: None,
            reference: None,
            source: String::new(),
        }
    }

    pub fn with_source(mut self, source: impl Into<String>) -> Step {
        self.source = source.into();
        self
    }

    pub fn with_person(mut self, person: impl Into<String>) -> Step {
        self.person = Some(person.into());
        self
    }

    pub fn with_d_s(mut self, d_s: f64) -> Step {
        self.d_s = Some(d_s);
        self
    }

    pub fn with_duration(mut self, s: f64) -> Step {
        self.duration_s = Some(s);
        self
    }

    pub fn with_desc(mut self, desc: impl Into<String>) -> Step {
        self.desc = desc.into();
        self
    }

    /// The paper's JSON object for this step.
    pub fn to_json(&self) -> Value {
        let mut m = Map::new();
        m.insert("action".into(), json!(self.action.as_str()));
        if !self.desc.is_empty() {
            m.insert("desc".into(), json!(self.desc));
        }
        match self.action {
            Action::Move => {
                m.insert("f_dist".into(), number(self.f_dist));
                m.insert("yaw".into(), number(self.yaw));
            }
            Action::Find | Action::Follow => {
                m.insert("target".into(), json!(self.target));
                m.insert("id".into(), json!(self.class_id));
                if let Some(p) = &self.person {
                    m.insert("person".into(), json!(p));
                }
                if let Some(d) = self.d_s {
                    m.insert("d_s".into(), number(d));
                }
                if let (Action::Follow, Some(t)) = (self.action, self.duration_s) {
                    m.insert("duration_s".into(), number(t));
                }
                if let Some(r) = &self.reference {
                    m.insert("ref".into(), r.to_json());
                }
            }
            Action::Return => {}
        }
        Value::Object(m)
    }
}

/// Non-finite numbers have no JSON form; they become `null`, which the
/// schema rejects, so they can never pass validation silently.
fn number(x: f64) -> Value {
    serde_json::Number::from_f64(x).map(Value::Number).unwrap_or(Value::Null)
}

/// An ordered plan.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Plan {
    pub steps: Vec<Step>,
}

impl Plan {
    pub fn new(steps: Vec<Step>) -> Plan {
        Plan { steps }
    }

    pub fn to_json(&self) -> Value {
        Value::Array(self.steps.iter().map(Step::to_json).collect())
    }

    pub fn to_json_string(&self) -> String {
        self.to_json().to_string()
    }

    /// Reads a plan from its JSON form without judging it (the validator
    /// does); fails only when the shape cannot be read at all.
    pub fn from_json(v: &Value) -> Result<Plan, String> {
        let items = v.as_array().ok_or("a plan is a JSON array of steps")?;
        let mut steps = Vec::with_capacity(items.len());
        for (i, item) in items.iter().enumerate() {
            let o = item.as_object().ok_or(format!("step {i}: not a JSON object"))?;
            let action = o
                .get("action")
                .and_then(Value::as_str)
                .and_then(Action::parse)
                .ok_or(format!("step {i}: action must be one of MOVE, FIND, FOLLOW, RETURN"))?;
            let s = |k: &str| o.get(k).and_then(Value::as_str).map(str::to_string);
            let f = |k: &str| o.get(k).and_then(Value::as_f64);
            steps.push(Step {
                action,
                desc: s("desc").unwrap_or_default(),
                f_dist: f("f_dist").unwrap_or(0.0),
                yaw: f("yaw").unwrap_or(0.0),
                target: s("target").unwrap_or_default(),
                class_id: o
                    .get("id")
                    .and_then(as_integer)
                    .map(|x| x.clamp(i32::MIN as i64, i32::MAX as i64) as i32)
                    .unwrap_or(if matches!(action, Action::Find | Action::Follow) { -1 } else { 0 }),
                person: s("person"),
                d_s: f("d_s"),
                duration_s: f("duration_s"),
                reference: o.get("ref").and_then(Reference::from_json),
                source: String::new(),
            });
        }
        Ok(Plan { steps })
    }
}

/// What the planner returns instead of a plan when it must ask.
#[derive(Clone, Debug, PartialEq)]
pub struct Clarification {
    pub question: String,
    pub reason: String,
    pub options: Vec<String>,
}

/// A plan or a question back to the user.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Plan(Plan),
    Clarify(Clarification),
}

/// The planner's answer: the outcome, the backend whose output was accepted,
/// notes on what happened on the way, and the places named that no
/// detectable class covers (the plan goes without them).
#[derive(Clone, Debug, PartialEq)]
pub struct Planned {
    pub outcome: Outcome,
    pub backend: String,
    pub notes: Vec<String>,
    pub ungrounded: Vec<String>,
}

impl Planned {
    pub fn plan_json(&self) -> String {
        match &self.outcome {
            Outcome::Plan(p) => p.to_json_string(),
            Outcome::Clarify(_) => String::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_uses_the_papers_keys_and_omits_unused_ones() {
        let plan = Plan::new(vec![
            Step::find("statue (human)", 0),
            Step::moving("turn right", 2.5, -1.57),
            Step::follow("david", 0).with_person("david").with_duration(30.0),
            Step::go_back(""),
            Step {
                reference: Some(Reference { relation: "next to".into(), target: "table".into(), class_id: 60 }),
                ..Step::find("chair", 56)
            },
        ]);
        let j = plan.to_json_string();
        let expected: Value = serde_json::from_str(
            r#"[{"action":"FIND","target":"statue (human)","id":0},{"action":"MOVE","desc":"turn right","f_dist":2.5,"yaw":-1.57},{"action":"FOLLOW","target":"david","id":0,"person":"david","duration_s":30.0},{"action":"RETURN"},{"action":"FIND","target":"chair","id":56,"ref":{"relation":"next to","target":"table","id":60}}]"#,
        )
        .unwrap();
        assert_eq!(serde_json::from_str::<Value>(&j).unwrap(), expected);
        let back = Plan::from_json(&serde_json::from_str(&j).unwrap()).unwrap();
        assert_eq!(back, plan);
    }

    #[test]
    fn non_finite_numbers_become_null() {
        let v = Step::moving("", f64::NAN, 0.0).to_json();
        assert!(v["f_dist"].is_null());
    }

    #[test]
    fn unreadable_shapes_are_reported() {
        assert!(Plan::from_json(&json!({"action": "MOVE"})).is_err());
        assert!(Plan::from_json(&json!([{"action": "JUMP"}])).unwrap_err().contains("step 0"));
    }
}
