//! `vlnav replay FILE.mcap`: a mission recording's frames, fed through a
//! fresh gateway and stage services in lockstep, and the commands they give
//! compared with the recorded ones (docs/observability.md, "Replay").
//!
//! The replay stack is `vlnav up` without a robot, on loopback ports chosen
//! by the OS, with the recording's perception mode (its `vlnav.mission`
//! metadata) unless `--perception` says otherwise. The replay attaches as the
//! recorded robot, submits the recorded instruction, then sends each recorded
//! frame and waits for its command. Simulated perception draws are a pure
//! function of (seed, robot, frame), so a replay of a simulated mission
//! reproduces its commands exactly, and any change of behaviour shows up as a
//! difference.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use prost::Message;
use tokio_stream::wrappers::ReceiverStream;
use vlnav_gateway::config::ExecutorParams;
use vlnav_proto::v1::{
    ActionPlan, EdgeHello, EdgeMessage, GetMissionRequest, MissionState, SensorFrame, SubmitMissionRequest,
    VelocityCommand, edge_message, fleet_service_client::FleetServiceClient, gateway_command,
    mission_service_client::MissionServiceClient, submit_mission_request::Instruction,
};
use vlnav_runtime::perception::PerceptionMode;
use vlnav_runtime::security::ClientSecurity;

use crate::up::{UpArgs, up};

#[derive(clap::Args, Clone, Debug)]
pub struct ReplayArgs {
    /// The recording: its first file. Its continuations (`<id>.part2.mcap`,
    /// …) beside it are read too.
    pub file: PathBuf,
    /// Perception of the replay's stages (default: the recording's own).
    #[arg(long, value_enum)]
    pub perception: Option<PerceptionMode>,
    /// Differing frames to list (all are counted).
    #[arg(long, default_value_t = 10)]
    pub show: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Executor parameters of the replay (defaults: the gateway's). Change
    /// one to see what the change would have done on this mission.
    #[command(flatten)]
    pub executor: ExecutorParams,
}

/// What a recording holds for a replay.
#[derive(Debug, Default)]
pub struct Recording {
    pub files: Vec<PathBuf>,
    pub mission_id: String,
    pub robot_id: String,
    pub instruction: String,
    pub metadata: BTreeMap<String, String>,
    pub plan: Option<ActionPlan>,
    pub frames: Vec<SensorFrame>,
    pub commands: Vec<VelocityCommand>,
}

/// The recording's file and its continuations, in order.
pub fn recording_files(first: &Path) -> Vec<PathBuf> {
    let mut files = vec![first.to_path_buf()];
    let stem = first.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    for part in 2.. {
        let next = first.with_file_name(format!("{stem}.part{part}.mcap"));
        if !next.exists() {
            break;
        }
        files.push(next);
    }
    files
}

/// Reads a recording (and its continuations).
pub fn read_recording(first: &Path) -> anyhow::Result<Recording> {
    let rec = read_messages(first, None)?;
    if rec.frames.len() != rec.commands.len() {
        anyhow::bail!(
            "{} holds {} frames but {} commands: frames were dropped from it while it was recorded, so it cannot \
             be replayed exactly (the gateway's log says how many)",
            first.display(),
            rec.frames.len(),
            rec.commands.len()
        );
    }
    Ok(rec)
}

/// The first `max` sensor frames of a recording (and its continuations), for
/// a load generator that sends them again (`vlnav bench fleet --replay`).
pub fn read_frames(first: &Path, max: usize) -> anyhow::Result<Vec<SensorFrame>> {
    anyhow::ensure!(max > 0, "at least one frame must be read");
    Ok(read_messages(first, Some(max))?.frames)
}

/// A recording's metadata, plan, commands and frames (at most `max_frames`).
fn read_messages(first: &Path, max_frames: Option<usize>) -> anyhow::Result<Recording> {
    let files = recording_files(first);
    let mut rec = Recording { files: files.clone(), ..Default::default() };
    'files: for file in &files {
        let bytes = std::fs::read(file).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", file.display()))?;
        let bad = |e: mcap::McapError| anyhow::anyhow!("{} is not a readable MCAP file: {e}", file.display());
        for record in mcap::read::LinearReader::new(&bytes).map_err(bad)? {
            if let mcap::records::Record::Metadata(m) = record.map_err(bad)?
                && m.name == "vlnav.mission"
            {
                rec.metadata.extend(m.metadata);
            }
        }
        for message in mcap::MessageStream::new(&bytes).map_err(bad)? {
            let message = message.map_err(bad)?;
            let topic = message.channel.topic.as_str();
            let decode = |what: &str| anyhow::anyhow!("{}: a {what} on {topic} does not decode", file.display());
            if topic.ends_with("/sensor_frame") {
                if max_frames.is_some_and(|m| rec.frames.len() >= m) {
                    break 'files;
                }
                rec.frames.push(SensorFrame::decode(&message.data[..]).map_err(|_| decode("SensorFrame"))?);
            } else if topic.ends_with("/cmd_vel") {
                rec.commands.push(VelocityCommand::decode(&message.data[..]).map_err(|_| decode("VelocityCommand"))?);
            } else if topic.ends_with("/mission/plan") {
                rec.plan = Some(ActionPlan::decode(&message.data[..]).map_err(|_| decode("ActionPlan"))?);
            }
        }
    }
    let field = |k: &str| rec.metadata.get(k).cloned().unwrap_or_default();
    rec.mission_id = field("mission_id");
    rec.robot_id = field("robot_id");
    rec.instruction = field("instruction");
    if rec.robot_id.is_empty() || rec.instruction.is_empty() {
        anyhow::bail!("{} has no vlnav.mission metadata: is it a vlnav mission recording?", first.display());
    }
    if rec.frames.is_empty() {
        anyhow::bail!("{} holds no sensor frames to replay", first.display());
    }
    Ok(rec)
}

/// One frame whose replayed command differs from the recorded one.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Difference {
    pub index: usize,
    pub seq: u64,
    pub stamp: f64,
    /// (v m/s, ω rad/s, idle)
    pub recorded: (f64, f64, bool),
    pub replayed: (f64, f64, bool),
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ReplayReport {
    pub file: String,
    pub mission_id: String,
    pub perception: String,
    pub frames: usize,
    pub differing: usize,
    pub first: Vec<Difference>,
    pub plan_matches: bool,
    /// The state the replayed mission ended in (or reached at the last frame).
    pub replayed_state: String,
}

impl ReplayReport {
    pub fn identical(&self) -> bool {
        self.differing == 0 && self.plan_matches
    }
}

impl std::fmt::Display for ReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "replay of {} (mission {}, {} perception)", self.file, self.mission_id, self.perception)?;
        if !self.plan_matches {
            writeln!(f, "  the planner now plans this instruction differently from the recorded plan")?;
        }
        writeln!(
            f,
            "  {} frames, {} commands differ; the replayed mission ended {}",
            self.frames, self.differing, self.replayed_state
        )?;
        for d in &self.first {
            writeln!(
                f,
                "  frame {} (seq {}, t {:.2} s): recorded v {:+.4} ω {:+.4}{}, replayed v {:+.4} ω {:+.4}{}",
                d.index,
                d.seq,
                d.stamp,
                d.recorded.0,
                d.recorded.1,
                if d.recorded.2 { " idle" } else { "" },
                d.replayed.0,
                d.replayed.1,
                if d.replayed.2 { " idle" } else { "" },
            )?;
        }
        if self.differing > self.first.len() {
            writeln!(f, "  … and {} more", self.differing - self.first.len())?;
        }
        write!(f, "{}", if self.identical() { "record == replay" } else { "record != replay" })
    }
}

fn triple(c: &VelocityCommand) -> (f64, f64, bool) {
    let t = c.twist.unwrap_or_default();
    (t.linear, t.angular, c.idle)
}

/// Replays a recording through a fresh stack.
pub async fn replay(args: &ReplayArgs) -> anyhow::Result<ReplayReport> {
    let rec = read_recording(&args.file)?;
    let perception = match (args.perception, rec.metadata.get("perception")) {
        (Some(p), _) => p,
        (None, Some(p)) => <PerceptionMode as clap::ValueEnum>::from_str(p, true)
            .map_err(|_| anyhow::anyhow!("the recording names an unknown perception mode '{p}'; pass --perception"))?,
        (None, None) => anyhow::bail!("the recording does not say which perception it ran with; pass --perception"),
    };
    let data = std::env::temp_dir().join(format!("vlnav-replay-{}-{}", std::process::id(), rec.mission_id));
    let up_args = UpArgs {
        no_robot: true,
        ephemeral_ports: true,
        insecure: true,
        data_dir: data.clone(),
        perception,
        executor: args.executor.clone(),
        ..UpArgs::default()
    };
    let stack = up(&up_args).await?;
    let result = drive(&stack.gateway_uri(), &rec, args.show).await;
    stack.shutdown().await?;
    let _ = std::fs::remove_dir_all(&data);
    let (differing, first, plan, state) = result?;
    Ok(ReplayReport {
        file: args.file.display().to_string(),
        mission_id: rec.mission_id.clone(),
        perception: perception.as_str().into(),
        frames: rec.frames.len(),
        differing,
        first,
        plan_matches: rec.plan.is_none_or(|p| Some(p) == plan),
        replayed_state: state.as_str_name().trim_start_matches("MISSION_STATE_").to_lowercase(),
    })
}

type Driven = (usize, Vec<Difference>, Option<ActionPlan>, MissionState);

/// Attaches as the recorded robot, submits the instruction, feeds the frames.
async fn drive(uri: &str, rec: &Recording, show: usize) -> anyhow::Result<Driven> {
    let channel = vlnav_runtime::client::channel_with(uri, &ClientSecurity::none())?;
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    let hello =
        EdgeHello { robot_id: rec.robot_id.clone(), driver: "replay".into(), lockstep: true, ..Default::default() };
    tx.send(EdgeMessage { kind: Some(edge_message::Kind::Hello(hello)) }).await?;
    let mut inbound = FleetServiceClient::new(channel.clone()).attach(ReceiverStream::new(rx)).await?.into_inner();
    let mut missions = MissionServiceClient::new(channel);
    let submitted = missions
        .submit_mission(SubmitMissionRequest {
            robot_id: rec.robot_id.clone(),
            instruction: Some(Instruction::Text(rec.instruction.clone())),
            dry_run: false,
        })
        .await?
        .into_inner();
    let plan = match submitted.outcome {
        Some(vlnav_proto::v1::submit_mission_response::Outcome::Plan(p)) => Some(p),
        _ => None,
    };
    let mut differing = 0;
    let mut first = Vec::new();
    for (index, (frame, recorded)) in rec.frames.iter().zip(&rec.commands).enumerate() {
        tx.send(EdgeMessage { kind: Some(edge_message::Kind::Frame(frame.clone())) }).await?;
        let replayed = loop {
            match inbound.message().await? {
                Some(c) => match c.kind {
                    Some(gateway_command::Kind::Velocity(v)) => break v,
                    _ => continue,
                },
                None => anyhow::bail!("the gateway ended the robot's stream at frame {index}"),
            }
        };
        if triple(&replayed) != triple(recorded) {
            differing += 1;
            if first.len() < show {
                let f = frame.frame.as_ref();
                first.push(Difference {
                    index,
                    seq: f.map_or(0, |f| f.seq),
                    stamp: f.map_or(0.0, |f| f.stamp),
                    recorded: triple(recorded),
                    replayed: triple(&replayed),
                });
            }
        }
    }
    let mission = missions.get_mission(GetMissionRequest { mission_id: submitted.mission_id }).await?.into_inner();
    Ok((differing, first, plan, MissionState::try_from(mission.state).unwrap_or_default()))
}
