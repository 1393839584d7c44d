//! `vlnav mission`: submit an instruction to a gateway and print the
//! mission's events as they happen, then a summary.

use std::io::Write;

use vlnav_proto::v1::{
    ActionKind, ActionStep, Audio, AudioFormat, CancelMissionRequest, GetMissionRequest, Mission, MissionEvent,
    MissionState, SubmitMissionRequest, WatchMissionRequest, mission_event::Kind,
    mission_service_client::MissionServiceClient, submit_mission_request, submit_mission_response,
};

#[derive(clap::Args, Clone, Debug)]
pub struct MissionArgs {
    /// The instruction, e.g. "take a left turn, move 4 m ahead, then find the standing person".
    pub text: Option<String>,
    /// A WAV file to send instead of text (transcribed by the ingress service).
    #[arg(long, conflicts_with = "text")]
    pub audio: Option<std::path::PathBuf>,
    #[arg(long, default_value = "husky-1")]
    pub robot: String,
    /// The gateway: https:// (what `vlnav up` serves) or http:// (`vlnav up --insecure`).
    #[arg(long, env = "VLNAV_GATEWAY", default_value = "https://127.0.0.1:50051")]
    pub gateway: String,
    #[command(flatten)]
    pub caller: vlnav_runtime::security::CallerArgs,
    /// Plan and validate only; nothing moves.
    #[arg(long)]
    pub dry_run: bool,
    /// When the robot asks a question, cancel the mission and stop instead
    /// of waiting for an answer (`AnswerClarification`) from another client.
    #[arg(long)]
    pub stop_on_question: bool,
}

/// A one-line description of a plan step, with the instruction's words it came from.
pub fn describe_step(s: &ActionStep) -> String {
    let what = describe_action(s);
    if s.source.is_empty() { what } else { format!("{what}  <- \"{}\"", s.source) }
}

fn describe_action(s: &ActionStep) -> String {
    match ActionKind::try_from(s.action).unwrap_or_default() {
        ActionKind::Move if s.f_dist.abs() < 0.1 => format!("MOVE turn {:+.2} rad", s.yaw),
        ActionKind::Move => format!("MOVE turn {:+.2} rad, then {:.2} m", s.yaw, s.f_dist),
        ActionKind::Find | ActionKind::Follow => {
            let verb = if s.action == ActionKind::Find as i32 { "FIND" } else { "FOLLOW" };
            let who = if s.person.is_empty() { String::new() } else { format!(" '{}'", s.person) };
            format!("{verb} {}{who} (class {})", s.target, s.class_id)
        }
        ActionKind::Return => "RETURN to the start".to_string(),
        ActionKind::Unspecified => "?".to_string(),
    }
}

/// A one-line description of an event.
pub fn describe_event(e: &MissionEvent) -> String {
    let what = match &e.kind {
        Some(Kind::Transcribed(t)) => format!("heard: \"{}\" ({:.1} s of speech)", t.transcript, t.audio_seconds),
        Some(Kind::Plan(p)) => format!("plan ({}): {}", p.backend, p.plan_json),
        Some(Kind::StepStarted(s)) => {
            format!("step {} started: {}", s.index + 1, s.step.as_ref().map(describe_step).unwrap_or_default())
        }
        Some(Kind::TargetSeen(t)) => {
            let p = t.target.unwrap_or_default();
            let who = if t.identity.is_empty() {
                String::new()
            } else {
                format!(" ({} {:.2})", t.identity, t.identity_similarity)
            };
            format!("step {}: target seen{who} at ({:.2}, {:.2}) m, {:.2} m away", t.index + 1, p.x, p.y, t.range_m)
        }
        Some(Kind::SubgoalReached(r)) => {
            let p = r.pose.unwrap_or_default();
            format!(
                "step {}: reached, pose ({:.2}, {:.2}, {:.2} rad), {:.2} m from the goal",
                r.index + 1,
                p.x,
                p.y,
                p.theta,
                r.error_m
            )
        }
        Some(Kind::Exploring(x)) => format!("step {}: exploring ({} #{})", x.index + 1, x.phase, x.attempt),
        Some(Kind::ClarificationNeeded(c)) => {
            format!("question: {}", c.clarification.as_ref().map(|c| c.question.as_str()).unwrap_or(""))
        }
        Some(Kind::Replanned(r)) => format!("replanned after \"{}\": {}", r.answer, r.plan_json),
        Some(Kind::StepFailed(f)) => format!("step {} failed: {}", f.index + 1, f.reason),
        Some(Kind::Finished(f)) => {
            format!("finished: {} — {}", MissionState::try_from(f.state).unwrap_or_default().as_str_name(), f.reason)
        }
        None => "(empty event)".to_string(),
    };
    format!("[{:>7.2} s] {what}", e.stamp)
}

/// A summary of a finished mission.
pub fn summarise(m: &Mission) -> String {
    let mut out = format!(
        "mission {} on {}: {}",
        m.mission_id,
        m.robot_id,
        MissionState::try_from(m.state).unwrap_or_default().as_str_name()
    );
    if let Some(x) = &m.metrics {
        out += &format!(
            "\n  steps {}/{}, {:.1} s of robot time, {} frames, odometry path {:.2} m, replans {}",
            x.steps_completed, x.steps_total, x.duration_s, x.frames, x.odom_path_length_m, x.replans
        );
        if x.has_ground_truth {
            out += &format!(
                "\n  ground truth: path {:.2} m, hard collisions {}, soft collisions {}, final error {:.2} m",
                x.true_path_length_m, x.hard_collisions, x.soft_collisions, x.final_error_m
            );
        }
    }
    if !m.trace_id.is_empty() {
        out += &format!("\n  trace {}", m.trace_id);
    }
    for (i, file) in m.recordings.iter().enumerate() {
        let what = if i == 0 { "recording" } else { "  continued" };
        out += &format!("\n  {what} {file}");
    }
    if !m.recordings.is_empty() {
        out += &format!(
            "\n  (open it in Foxglove or Lichtblick with deploy/foxglove/vlnav-layout.json; replay: vlnav replay {})",
            m.recordings[0]
        );
    }
    out
}

/// A failed call as a person can act on it: an unreachable gateway, or a
/// plaintext client talking to a TLS gateway, says what to do.
fn call_error(gateway: &str, s: &tonic::Status) -> anyhow::Error {
    match s.code() {
        tonic::Code::Unavailable => {
            anyhow::anyhow!("cannot reach the gateway at {gateway}: {} (is `vlnav up` running?)", s.message())
        }
        tonic::Code::Unknown | tonic::Code::Internal
            if gateway.starts_with("http://")
                && ["transport", "h2 protocol"].iter().any(|m| s.message().contains(m)) =>
        {
            anyhow::anyhow!(
                "the gateway at {gateway} does not answer plaintext gRPC ({}); `vlnav up` serves TLS unless started \
                 with --insecure: use https://",
                s.message()
            )
        }
        _ => anyhow::anyhow!("{}: {}", s.code(), s.message()),
    }
}

/// Submits, prints every event until the mission ends, returns the mission.
pub async fn run_mission(args: &MissionArgs, out: &mut (impl Write + Send)) -> anyhow::Result<Mission> {
    let security = args.caller.load()?;
    let channel = vlnav_runtime::client::channel_with(&args.gateway, &security)
        .map_err(|e| anyhow::anyhow!("gateway {}: {e}", args.gateway))?;
    let mut client =
        MissionServiceClient::new(channel).max_decoding_message_size(64 << 20).max_encoding_message_size(64 << 20);
    let instruction = match (&args.text, &args.audio) {
        (_, Some(path)) => submit_mission_request::Instruction::Audio(Audio {
            format: AudioFormat::Wav as i32,
            sample_rate: 0,
            data: std::fs::read(path).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?.into(),
        }),
        (Some(t), None) => submit_mission_request::Instruction::Text(t.clone()),
        (None, None) => anyhow::bail!("give an instruction, or --audio FILE.wav"),
    };
    let resp = client
        .submit_mission(SubmitMissionRequest {
            robot_id: args.robot.clone(),
            instruction: Some(instruction),
            dry_run: args.dry_run,
        })
        .await
        .map_err(|s| call_error(&args.gateway, &s))?
        .into_inner();
    writeln!(out, "mission {} ({} planner)", resp.mission_id, resp.planner_backend)?;
    match &resp.outcome {
        Some(submit_mission_response::Outcome::Plan(p)) => {
            writeln!(out, "plan: {}", resp.plan_json)?;
            for (i, s) in p.steps.iter().enumerate() {
                writeln!(out, "  {}. {}", i + 1, describe_step(s))?;
            }
        }
        Some(submit_mission_response::Outcome::Clarification(c)) => writeln!(out, "question: {}", c.question)?,
        None => {}
    }
    let mut events =
        client.watch_mission(WatchMissionRequest { mission_id: resp.mission_id.clone() }).await?.into_inner();
    while let Some(e) = events.message().await? {
        writeln!(out, "{}", describe_event(&e))?;
        out.flush()?;
        if args.stop_on_question && matches!(e.kind, Some(Kind::ClarificationNeeded(_))) {
            writeln!(out, "(nobody here to answer: cancelling the mission)")?;
            client.cancel_mission(CancelMissionRequest { mission_id: resp.mission_id.clone() }).await?;
        }
    }
    let mission = client.get_mission(GetMissionRequest { mission_id: resp.mission_id }).await?.into_inner();
    writeln!(out, "{}", summarise(&mission))?;
    Ok(mission)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_calls_say_what_to_do() {
        let down = call_error("https://127.0.0.1:50051", &tonic::Status::unavailable("tcp connect error"));
        assert!(down.to_string().contains("is `vlnav up` running?"), "{down}");
        let plain = call_error("http://127.0.0.1:50051", &tonic::Status::internal("h2 protocol error: http2 error"));
        assert!(plain.to_string().contains("use https://"), "{plain}");
        let other = call_error("https://x:1", &tonic::Status::permission_denied("needs the operator role"));
        assert!(other.to_string().contains("needs the operator role"), "{other}");
    }
}
