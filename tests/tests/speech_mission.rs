//! Voice, end to end through the gateway: espeak-ng speaks five instructions
//! (the paper's two worked examples among them), SubmitMission sends the WAV
//! as `audio`, ingress transcribes it with Whisper tiny.en, and the planner
//! must produce the same plan as for the typed instruction. The transcript
//! appears in the mission's events.

use std::process::Command;
use std::time::Duration;

use vlnav_e2e::{CASE_2, TestStack};
use vlnav_ingress::wer::word_error_rate;
use vlnav_proto::v1::{
    ActionStep, Audio, AudioFormat, SubmitMissionRequest, mission_event::Kind, submit_mission_request::Instruction,
    submit_mission_response::Outcome,
};

const CASE_1: &str = "Buddy go to the human statue, take a right turn and move a little ahead, then find the visitor chair \
to reach close to it, and on the right you may see a bicycle.";
/// Case 2 as a person says it: espeak-ng reads the written "4 m" as letters.
const CASE_2_SPOKEN: &str = "Buddy take left turn, move four meters ahead, then find the standing person to reach close to it, \
In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.";
/// (typed, spoken): every spoken instruction must plan exactly like the typed
/// text — the same actions, distances, turns, class ids and named people.
const SPOKEN: [(&str, &str); 5] = [
    (CASE_2, CASE_2_SPOKEN),
    (CASE_1, CASE_1),
    (
        "Move five meters forward, take a right turn, and stop near the elephant statue.",
        "Move five meters forward, take a right turn, and stop near the elephant statue.",
    ),
    (
        "Turn left and move three meters, then find the person.",
        "Turn left and move three meters, then find the person.",
    ),
    ("Turn around and go to the person.", "Turn around and go to the person."),
];

fn speak(text: &str) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("speech.wav");
    let status = Command::new("espeak-ng")
        .args(["-v", "en-us", "-s", "150", "-w"])
        .arg(&path)
        .arg(text)
        .status()
        .unwrap_or_else(|e| {
            panic!("cannot run espeak-ng ({e}): install the Debian package espeak-ng (.ci/apt/ingress.txt)")
        });
    assert!(status.success());
    std::fs::read(path).unwrap()
}

/// What must agree between the typed and the spoken plan.
fn essence(steps: &[ActionStep]) -> Vec<(i32, i32, i64, i64, String)> {
    steps
        .iter()
        .map(|s| {
            (s.action, s.class_id, (s.f_dist * 10.0).round() as i64, (s.yaw * 100.0).round() as i64, s.person.clone())
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn spoken_instructions_plan_like_typed_ones_through_the_gateway() {
    let t = TestStack::start(|a| a.no_robot = true).await;
    let mut missions = t.missions().await;
    let mut report = String::from("\nspoken instruction → transcript (WER):\n");
    let mut total = 0.0;
    for (text, said) in SPOKEN {
        let typed = missions
            .submit_mission(SubmitMissionRequest {
                robot_id: String::new(),
                instruction: Some(Instruction::Text(text.into())),
                dry_run: true,
            })
            .await
            .unwrap()
            .into_inner();
        let Some(Outcome::Plan(expected)) = typed.outcome else {
            panic!("typed '{text}' did not plan: {:?}", typed.outcome)
        };
        let audio = Audio { format: AudioFormat::Wav as i32, sample_rate: 0, data: speak(said).into() };
        let spoken = missions
            .submit_mission(SubmitMissionRequest {
                robot_id: String::new(),
                instruction: Some(Instruction::Audio(audio)),
                dry_run: true,
            })
            .await
            .unwrap()
            .into_inner();
        let w = word_error_rate(said, &spoken.transcript);
        total += w;
        report += &format!("  {w:.2}  {text}\n        → {}\n", spoken.transcript);
        assert!(w <= 0.35, "transcript too far from '{text}': '{}' (WER {w:.2})", spoken.transcript);
        let got = match spoken.outcome {
            Some(Outcome::Plan(p)) => p,
            other => panic!("spoken '{text}' (heard {:?}) did not plan: {other:?}", spoken.transcript),
        };
        assert_eq!(
            essence(&got.steps),
            essence(&expected.steps),
            "spoken and typed plans differ for {text:?} (heard {:?})\n{}\n{}",
            spoken.transcript,
            spoken.plan_json,
            typed.plan_json
        );
        assert!(!got.steps.is_empty(), "an empty plan for {text:?}");
        let (events, _) = t.follow(&spoken.mission_id, Duration::from_secs(30)).await;
        assert!(
            events.iter().any(|e| matches!(&e.kind, Some(Kind::Transcribed(x)) if x.transcript == spoken.transcript)),
            "the transcript is in the mission's events"
        );
    }
    report += &format!("  mean WER {:.3}\n", total / SPOKEN.len() as f64);
    println!("{report}");
    t.stack.shutdown().await.unwrap();
}
