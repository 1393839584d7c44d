//! The rule-based backend against a table of instructions and their exact
//! plans: the paper's two published examples and more, grounded with the
//! real all-MiniLM-L6-v2.

mod common;

use serde_json::Value;
use vlnav_planner::htn;
use vlnav_planner::plan::Outcome;
use vlnav_planner::validate::Validator;

/// (instruction, expected plan in the paper's JSON form; MOVE/RETURN `desc` is not compared).
/// An expected value of "?" means a clarification question.
const TABLE: &[(&str, &str)] = &[
    // The paper's published examples (docs/design.md §2).
    (
        "Buddy go to the statue (human), take a right turn and move a little ahead, then find the visitor chair to reach close to it, and on the right you may see a bicycle.",
        r#"[{"action":"FIND","target":"statue (human)","id":0},{"action":"MOVE","f_dist":2.5,"yaw":-1.57},{"action":"FIND","target":"visitor chair","id":56},{"action":"FIND","target":"bicycle","id":1}]"#,
    ),
    (
        "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.",
        r#"[{"action":"MOVE","f_dist":4.0,"yaw":1.57},{"action":"FIND","target":"standing person","id":0},{"action":"FIND","target":"visitor chair","id":56},{"action":"FIND","target":"bicycle","id":1}]"#,
    ),
    // Other instruction kinds the paper names.
    (
        "Move 5 meters forward, take a right turn, and stop near the statue (Elephant)",
        r#"[{"action":"MOVE","f_dist":5.0,"yaw":0.0},{"action":"MOVE","f_dist":0.0,"yaw":-1.57},{"action":"FIND","target":"statue (elephant)","id":20}]"#,
    ),
    (
        "Hi Buddy, please deliver this file to Mr. David and report back to me",
        r#"[{"action":"FIND","target":"mr. david","id":0,"person":"david"},{"action":"RETURN"}]"#,
    ),
    (
        "Bring a water bottle from the kitchen",
        r#"[{"action":"FIND","target":"water bottle","id":39},{"action":"RETURN"}]"#,
    ),
    ("Go ahead 10m, turn right at the Lotus statue, and proceed to the pharmacy", "?"),
    // Numbers, decimals and units.
    ("Move two meters forward", r#"[{"action":"MOVE","f_dist":2.0,"yaw":0.0}]"#),
    ("go forward one and a half metres", r#"[{"action":"MOVE","f_dist":1.5,"yaw":0.0}]"#),
    ("drive 2.5m ahead", r#"[{"action":"MOVE","f_dist":2.5,"yaw":0.0}]"#),
    ("move two point five meters", r#"[{"action":"MOVE","f_dist":2.5,"yaw":0.0}]"#),
    ("go 150 cm forward", r#"[{"action":"MOVE","f_dist":1.5,"yaw":0.0}]"#),
    ("walk 10 feet ahead", r#"[{"action":"MOVE","f_dist":3.05,"yaw":0.0}]"#),
    (
        "advance twenty five meters",
        r#"[{"action":"MOVE","f_dist":8.33,"yaw":0.0},{"action":"MOVE","f_dist":8.33,"yaw":0.0},{"action":"MOVE","f_dist":8.33,"yaw":0.0}]"#,
    ),
    ("move half a meter forward", r#"[{"action":"MOVE","f_dist":0.5,"yaw":0.0}]"#),
    ("go a few meters ahead", r#"[{"action":"MOVE","f_dist":3.0,"yaw":0.0}]"#),
    ("take three steps forward", r#"[{"action":"MOVE","f_dist":2.25,"yaw":0.0}]"#),
    ("move 4 ahead", r#"[{"action":"MOVE","f_dist":4.0,"yaw":0.0}]"#),
    // Vague distances.
    ("move a little ahead", r#"[{"action":"MOVE","f_dist":2.5,"yaw":0.0}]"#),
    ("go straight", r#"[{"action":"MOVE","f_dist":2.5,"yaw":0.0}]"#),
    ("go far ahead", r#"[{"action":"MOVE","f_dist":8.0,"yaw":0.0}]"#),
    // Turns.
    ("turn left", r#"[{"action":"MOVE","f_dist":0.0,"yaw":1.57}]"#),
    ("Turn right.", r#"[{"action":"MOVE","f_dist":0.0,"yaw":-1.57}]"#),
    ("turn around", r#"[{"action":"MOVE","f_dist":0.0,"yaw":3.14}]"#),
    ("make a U-turn", r#"[{"action":"MOVE","f_dist":0.0,"yaw":3.14}]"#),
    ("turn 45 degrees to the left", r#"[{"action":"MOVE","f_dist":0.0,"yaw":0.79}]"#),
    ("rotate 30° clockwise", r#"[{"action":"MOVE","f_dist":0.0,"yaw":-0.52}]"#),
    ("turn slightly right", r#"[{"action":"MOVE","f_dist":0.0,"yaw":-0.52}]"#),
    ("turn 270 degrees left", r#"[{"action":"MOVE","f_dist":0.0,"yaw":-1.57}]"#),
    ("turn 90 degrees", "?"),
    ("go left 3 m", r#"[{"action":"MOVE","f_dist":3.0,"yaw":1.57}]"#),
    ("turn right and go 2 meters", r#"[{"action":"MOVE","f_dist":2.0,"yaw":-1.57}]"#),
    ("go back 2 meters", r#"[{"action":"MOVE","f_dist":2.0,"yaw":3.14}]"#),
    // Sequences.
    (
        "Move 3 m forward then turn left and move 2 m, after that find the chair",
        r#"[{"action":"MOVE","f_dist":3.0,"yaw":0.0},{"action":"MOVE","f_dist":2.0,"yaw":1.57},{"action":"FIND","target":"chair","id":56}]"#,
    ),
    (
        "first go to the couch; then find the TV and finally come back",
        r#"[{"action":"FIND","target":"couch","id":57},{"action":"FIND","target":"tv","id":62},{"action":"RETURN"}]"#,
    ),
    // Landmarks and grounding.
    ("find the sofa", r#"[{"action":"FIND","target":"sofa","id":57}]"#),
    ("go to the potted plant", r#"[{"action":"FIND","target":"potted plant","id":58}]"#),
    ("look for the dining table", r#"[{"action":"FIND","target":"dining table","id":60}]"#),
    ("approach the refrigerator", r#"[{"action":"FIND","target":"refrigerator","id":72}]"#),
    ("navigate to the fridge", r#"[{"action":"FIND","target":"fridge","id":72}]"#),
    ("search for my laptop", r#"[{"action":"FIND","target":"laptop","id":63}]"#),
    ("find the elephant statue", r#"[{"action":"FIND","target":"elephant statue","id":20}]"#),
    ("stop 1.5 m before the bench", r#"[{"action":"FIND","target":"bench","id":13,"d_s":1.5}]"#),
    ("go to the television", r#"[{"action":"FIND","target":"television","id":62}]"#),
    ("find the automobile", r#"[{"action":"FIND","target":"automobile","id":2}]"#),
    ("find the houseplant", r#"[{"action":"FIND","target":"houseplant","id":58}]"#),
    ("go to the pharmacy", "?"),
    ("find the statue", "?"),
    // People.
    (
        "Hi buddy, please deliver this file to Mister David and report back to me.",
        r#"[{"action":"FIND","target":"mister david","id":0,"person":"david"},{"action":"RETURN"}]"#,
    ),
    ("find Mrs. Smith", r#"[{"action":"FIND","target":"mrs. smith","id":0,"person":"smith"}]"#),
    ("go to David", r#"[{"action":"FIND","target":"david","id":0,"person":"david"}]"#),
    ("follow the person for 30 seconds", r#"[{"action":"FOLLOW","target":"person","id":0,"duration_s":30.0}]"#),
    (
        "follow Mr. Brown for 2 minutes",
        r#"[{"action":"FOLLOW","target":"mr. brown","id":0,"person":"brown","duration_s":120.0}]"#,
    ),
    ("follow the dog", r#"[{"action":"FOLLOW","target":"dog","id":16}]"#),
    ("follow it", "?"),
    // Return.
    ("go back", r#"[{"action":"RETURN"}]"#),
    ("Return to me please", r#"[{"action":"RETURN"}]"#),
    ("turn left, move 2 m and then report back", r#"[{"action":"MOVE","f_dist":2.0,"yaw":1.57},{"action":"RETURN"}]"#),
    // Filler and nonsense.
    ("Hey buddy, please go to the chair, thanks!", r#"[{"action":"FIND","target":"chair","id":56}]"#),
    ("asdf qwerty zxcv", "?"),
    // Transcribed speech: a side set off by a comma, "followed", "the part
    // where"; a modifier naming a class does not ground another head noun.
    (
        "Buddy, take left turn, move four meters ahead, and find the standing person to reach close to it. In your right, you may see the visitor chair followed. Finally go at part where bicycle is standing.",
        r#"[{"action":"MOVE","f_dist":4.0,"yaw":1.57},{"action":"FIND","target":"standing person","id":0},{"action":"FIND","target":"visitor chair","id":56},{"action":"FIND","target":"bicycle","id":1}]"#,
    ),
    ("find the visitor care to reach close to it", "?"),
    ("then find the visitor character each close to it", "?"),
    ("dance for me", "?"),
    ("Ve a la silla y luego gira a la izquierda", "?"),
    ("请去椅子那里", "?"),
    ("12345 !!!", "?"),
];

fn strip_desc(v: &Value) -> Value {
    let mut v = v.clone();
    for s in v.as_array_mut().expect("plan array") {
        s.as_object_mut().expect("step object").remove("desc");
    }
    v
}

/// Numbers compared to 1 cm / 0.01 rad.
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => (x.as_f64().unwrap() - y.as_f64().unwrap()).abs() < 0.006,
        (Value::Array(x), Value::Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same(p, q)),
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
        }
        _ => a == b,
    }
}

#[test]
fn the_rule_backend_produces_the_expected_plan_for_every_instruction() {
    let grounder = common::grounder();
    let validator = Validator::new();
    let mut failures = Vec::new();
    for (instruction, expected) in TABLE {
        let parsed = htn::parse(instruction, &grounder);
        let got = match &parsed.outcome {
            Outcome::Clarify(c) => {
                if *expected != "?" {
                    failures
                        .push(format!("{instruction:?}: asked {:?} ({}), expected {expected}", c.question, c.reason));
                }
                continue;
            }
            Outcome::Plan(p) => {
                let checked =
                    validator.validate_plan(p).unwrap_or_else(|e| panic!("{instruction:?}: invalid plan {e:?}"));
                checked.plan.to_json()
            }
        };
        if *expected == "?" {
            failures.push(format!("{instruction:?}: expected a question, got {got}"));
            continue;
        }
        let want: Value = serde_json::from_str(expected).unwrap();
        if !same(&strip_desc(&got), &want) {
            failures.push(format!("{instruction:?}:\n   got  {}\n   want {want}", strip_desc(&got)));
        }
    }
    assert!(TABLE.len() >= 42, "the table holds the paper's two examples and at least 40 more");
    assert!(failures.is_empty(), "{} of {} instructions differ:\n{}", failures.len(), TABLE.len(), failures.join("\n"));
}

#[test]
fn the_papers_examples_match_exactly_including_the_json_form() {
    let grounder = common::grounder();
    let parsed = htn::parse(TABLE[1].0, &grounder);
    let Outcome::Plan(plan) = parsed.outcome else { panic!("asked instead of planning") };
    let got = plan.to_json();
    // Only MOVE carries a description; FIND steps have exactly the paper's keys.
    assert_eq!(got[1], serde_json::json!({"action": "FIND", "target": "standing person", "id": 0}));
    assert_eq!(got[0]["f_dist"], serde_json::json!(4.0));
    assert_eq!(got[0]["yaw"], serde_json::json!(1.57));
}
