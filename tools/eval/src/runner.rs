//! Runs trials through the real stack: per trial, an edge agent with the
//! `sim` driver in lockstep attaches to the gateway under a fresh robot id,
//! the instruction goes in through `MissionService.SubmitMission`,
//! `WatchMission` is followed to the end, and the agent's per-frame ground
//! truth becomes the trial's record. Nothing is short-cut: planning,
//! detection, subgoal estimation and local planning all happen in the
//! services behind the gateway.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc;
use vlnav_edge_agent::{DriverKind, EdgeOptions, Hooks, IdleGate, StepRecord};
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::mission_service_client::MissionServiceClient;
use vlnav_runtime::CancellationToken;
use vlnav_sim::World;
use vlnav_sim::geometry::{OrientedRect, Shape};

use crate::metrics::{ContactAccount, Outcome, Point2, Pose, TrialRecord, TruthSample};
use crate::plot::{PlotObject, PlotScene, PlotZone};
use crate::suite::{Suite, TrialSpec};

/// A footprint this close to a solid counts as touching it (the simulator's
/// own contact margin).
const CONTACT_MARGIN_M: f64 = 0.02;

/// How trials are run (everything but the suite and the trial plan).
#[derive(Clone, Debug)]
pub struct TrialSettings {
    pub gateway_uri: String,
    /// What the mission client brings (CA, operator token).
    pub caller: vlnav_runtime::security::ClientSecurity,
    /// Issues each trial robot's certificate when the gateway wants them.
    pub pki: Option<vlnav_runtime::security::DevPki>,
    pub camera_width: u32,
    pub camera_height: u32,
    /// Camera frames per second of sensor time (one control cycle each).
    pub frame_rate_hz: f64,
    /// Wall-clock seconds a trial may go without a new frame or event before
    /// it is abandoned as an error (a stuck service, not a slow robot).
    pub stall_timeout_s: f64,
    /// Per-trial world files are written here (and removed after the trial).
    pub work_dir: PathBuf,
    /// How the trial robots send their images (raw unless the run measures
    /// a compressed link).
    pub codecs: vlnav_edge_agent::Codecs,
}

/// A scenario's world, loaded once: the file's text (rewritten per trial
/// with the trial's start pose) and the validated world.
pub struct LoadedWorld {
    pub path: PathBuf,
    pub text: String,
    pub world: World,
}

pub fn load_world(path: &Path) -> anyhow::Result<LoadedWorld> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read world file {}", path.display()))?;
    let world = vlnav_sim::scenario::parse(&text).map_err(|e| anyhow::anyhow!("world file {}: {e}", path.display()))?;
    Ok(LoadedWorld { path: path.to_path_buf(), text, world })
}

/// The world file's text with the robot's start replaced by `start`.
pub fn with_start(text: &str, start: Pose) -> anyhow::Result<String> {
    let mut doc: toml::Table = toml::from_str(text).context("world file is not valid TOML")?;
    let robot = doc
        .get_mut("robot")
        .and_then(|r| r.as_table_mut())
        .ok_or_else(|| anyhow::anyhow!("world file has no [robot] table"))?;
    robot.insert("start".into(), toml::Value::Array(vec![start.x.into(), start.y.into(), start.theta.into()]));
    Ok(toml::to_string(&doc)?)
}

/// Whether the footprint at `pose` touches structure (hard) or lies in a
/// no-go marking (soft), pedestrians on their scripted routes at time `t`
/// (exact at t = 0, before anyone has reacted to the robot: used to check
/// start poses; during a trial the simulator's own contact state counts).
pub fn contact_at(world: &World, pose: Pose, t: f64) -> (bool, bool) {
    let params = vlnav_sim::HuskyParams::default();
    let rect = OrientedRect::new(pose, params.length, params.width);
    let near = rect.inflate(CONTACT_MARGIN_M);
    let hard = world.solids.iter().any(|s| near.overlaps(&s.shape))
        || world.pedestrians.iter().any(|p| near.overlaps(&p.shape_at(t)));
    let soft = world
        .markings
        .iter()
        .filter(|m| world.entity(m.entity).is_some_and(|e| e.semantic.is_no_go()))
        .any(|m| m.shapes.iter().any(|s| rect.overlaps(s)));
    (hard, soft)
}

/// What the mission's event stream told us.
#[derive(Debug, Default)]
struct Watched {
    outcome: Option<Outcome>,
    reason: String,
    steps_total: u32,
    metrics: Option<pb::MissionMetrics>,
    subgoals: Vec<(f64, pb::Pose2D)>,
    targets: Vec<(f64, pb::Point3)>,
    replans: u32,
}

/// One finished trial: its record and, when asked for, its plot and its
/// frame-by-frame track (CSV).
pub struct TrialResult {
    pub record: TrialRecord,
    pub plot: Option<PlotScene>,
    pub track_csv: Option<String>,
    pub wall_s: f64,
}

/// The shared, read-only context of a run.
pub struct RunContext {
    pub suite: Suite,
    pub worlds: Vec<LoadedWorld>,
    pub settings: TrialSettings,
}

impl RunContext {
    pub fn new(suite: Suite, settings: TrialSettings) -> anyhow::Result<Arc<Self>> {
        let worlds = suite
            .scenarios
            .iter()
            .map(|s| load_world(&s.world_path(&suite)).with_context(|| format!("scenario `{}`", s.name)))
            .collect::<anyhow::Result<Vec<_>>>()?;
        std::fs::create_dir_all(&settings.work_dir)
            .with_context(|| format!("cannot create {}", settings.work_dir.display()))?;
        Ok(Arc::new(Self { suite, worlds, settings }))
    }
}

/// Runs one trial end to end. Never fails: a trial that cannot be run is a
/// record with outcome `error` and the reason.
pub async fn run_trial(ctx: Arc<RunContext>, spec: TrialSpec, with_plot: bool) -> TrialResult {
    let started = Instant::now();
    let scenario = &ctx.suite.scenarios[spec.scenario];
    let loaded = &ctx.worlds[spec.scenario];
    let instruction = &scenario.instructions[spec.instruction];
    let nominal = loaded.world.start;
    let start = nominal.compose(&spec.start_offset);
    let text = instruction.text(nominal);
    let mut record = TrialRecord {
        scenario: scenario.name.clone(),
        mode: spec.mode,
        instruction: instruction.id.clone(),
        trial: spec.trial,
        seed: spec.seed,
        outcome: Outcome::Error,
        reason: String::new(),
        steps_completed: 0,
        steps_total: 0,
        destination: instruction.destination(),
        success_radius_m: instruction.radius,
        stop_distance_m: instruction.stop_distance(&loaded.world),
        final_position: start.position().into(),
        path_length_m: 0.0,
        odom_path_length_m: 0.0,
        duration_s: 0.0,
        frames: 0,
        replans: 0,
        contact: ContactAccount::default(),
    };
    let budget = scenario.max_mission_s.unwrap_or(ctx.suite.run.max_mission_s);
    let robot_id = format!("eval-{}-{}-{}-{:08x}", scenario.name, spec.mode, spec.trial, spec.seed as u32);
    let world_file = ctx.settings.work_dir.join(format!("{robot_id}.toml"));

    let outcome = async {
        std::fs::write(&world_file, with_start(&loaded.text, start)?)
            .with_context(|| format!("cannot write {}", world_file.display()))?;
        run_mission(&ctx.settings, &robot_id, &world_file, spec.seed, &text, budget).await
    }
    .await;
    let _ = std::fs::remove_file(&world_file);

    let (watched, steps) = match outcome {
        Ok(v) => v,
        Err(e) => {
            record.reason = format!("{e:#}");
            return TrialResult { record, plot: None, track_csv: None, wall_s: started.elapsed().as_secs_f64() };
        }
    };
    record.outcome = watched.outcome.unwrap_or(Outcome::Error);
    record.reason = watched.reason.clone();
    record.replans = watched.replans;
    record.steps_total = watched.steps_total;
    if let Some(m) = &watched.metrics {
        record.steps_completed = m.steps_completed;
        if m.steps_total > 0 {
            record.steps_total = m.steps_total;
        }
        record.odom_path_length_m = m.odom_path_length_m;
    }
    // The gateway's figure for a timed-out trial runs on to whichever frame
    // the cancellation landed on; count it over the trial's frames instead,
    // which end at the budget.
    if record.outcome == Outcome::TimedOut {
        record.odom_path_length_m = odom_path_length(&steps);
    }

    let track = truth_track(&steps);
    if let (Some(first), Some(last)) = (steps.first(), steps.last()) {
        let (t0, t1) = (first.truth.as_ref(), last.truth.as_ref());
        if let (Some(t0), Some(t1)) = (t0, t1) {
            record.path_length_m = t1.path_length_m - t0.path_length_m;
            record.final_position = Point2::new(t1.pose.x, t1.pose.y);
            if let Some(name) = &instruction.follow {
                // G_d of a FOLLOW: where the followed person is at the end.
                if let Some(at) = loaded.world.pedestrian_index(name).and_then(|k| t1.pedestrians.get(k)) {
                    record.destination = Point2::new(at.x, at.y);
                }
            }
            record.contact = ContactAccount::from_track(&track);
            // Events counted by the simulator at its physics substep, finer than frames.
            record.contact.hard_events = t1.hard_collisions - t0.hard_collisions;
            record.contact.soft_events = t1.soft_collisions - t0.soft_collisions;
            record.contact.hard_by_robot = t1.hard_collisions_by_robot - t0.hard_collisions_by_robot;
            record.contact.pedestrian_events = t1.pedestrian_contacts - t0.pedestrian_contacts;
            record.contact.pedestrian_by_robot = t1.pedestrian_contacts_by_robot - t0.pedestrian_contacts_by_robot;
        }
        record.duration_s = last.stamp - first.stamp;
        record.frames = steps.len() as u32;
    }

    let plot = with_plot.then(|| {
        plot_scene(
            &loaded.world,
            format!("{} — {} — trial {} (seed {}) — {}", scenario.title, spec.mode, spec.trial, spec.seed, text),
            start,
            &record,
            &track,
            &watched,
        )
    });
    let track_csv = with_plot.then(|| track_csv(&loaded.world, &steps));
    TrialResult { record, plot, track_csv, wall_s: started.elapsed().as_secs_f64() }
}

/// The trial frame by frame: sensor time, true pose, odometry, the command
/// received and the one applied, contact, and where each pedestrian was.
fn track_csv(world: &World, steps: &[StepRecord]) -> String {
    use std::fmt::Write as _;
    let mut out = String::from(
        "stamp_s,x_m,y_m,theta_rad,odom_x_m,odom_y_m,odom_theta_rad,cmd_v,cmd_w,applied_v,applied_w,hard_contact,no_go",
    );
    for p in &world.pedestrians {
        let name = world.entity(p.entity).map_or("pedestrian", |e| e.name.as_str()).replace([',', ' '], "_");
        let _ = write!(out, ",{name}_x_m,{name}_y_m");
    }
    out.push('\n');
    for s in steps {
        let Some(t) = &s.truth else { continue };
        let (cv, cw) = s.command.map_or((0.0, 0.0), |(_, c)| (c.linear, c.angular));
        let _ = write!(
            out,
            "{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.3},{:.3},{:.3},{:.3},{},{}",
            s.stamp,
            t.pose.x,
            t.pose.y,
            t.pose.theta,
            s.odom.x,
            s.odom.y,
            s.odom.theta,
            cv,
            cw,
            s.applied.linear,
            s.applied.angular,
            u8::from(t.in_hard_contact),
            u8::from(t.in_no_go)
        );
        for p in &t.pedestrians {
            let _ = write!(out, ",{:.3},{:.3}", p.x, p.y);
        }
        out.push('\n');
    }
    out
}

/// The trial's ground truth frame by frame, contact as the simulator saw it
/// (pedestrians move as they react to the robot, so only the simulator
/// knows where they were).
fn truth_track(steps: &[StepRecord]) -> Vec<TruthSample> {
    steps
        .iter()
        .filter_map(|s| {
            let t = s.truth.as_ref()?;
            Some(TruthSample {
                stamp: s.stamp,
                pose: t.pose,
                odom: s.odom,
                odom_origin: t.odom_origin,
                hard_contact: t.in_hard_contact,
                soft_contact: t.in_no_go,
            })
        })
        .collect()
}

/// Odometry path length over `frames` as the gateway's metrics count it: the
/// distance between consecutive odometry positions.
fn odom_path_length(frames: &[StepRecord]) -> f64 {
    frames.windows(2).map(|w| (w[1].odom.x - w[0].odom.x).hypot(w[1].odom.y - w[0].odom.y)).sum()
}

/// The odom frame's world origin in force at `stamp` (the last sample at or before it).
fn origin_at(track: &[TruthSample], stamp: f64) -> Option<Pose> {
    let k = track.partition_point(|s| s.stamp <= stamp + 1e-9);
    track.get(k.saturating_sub(1)).map(|s| s.odom_origin)
}

/// The world's layout as a plot: structure, markings, labelled objects, the start.
pub fn world_scene(world: &World, title: String, start: Pose) -> PlotScene {
    let poly = |shape: &Shape| -> Vec<Point2> {
        match shape {
            Shape::Polygon(pts) => pts.iter().map(|p| Point2::new(p.x, p.y)).collect(),
            Shape::Circle { centre, radius } => (0..16)
                .map(|k| {
                    let a = f64::from(k) * std::f64::consts::TAU / 16.0;
                    Point2::new(centre.x + radius * a.cos(), centre.y + radius * a.sin())
                })
                .collect(),
        }
    };
    let mut scene = PlotScene { title, start, ..Default::default() };
    for s in &world.solids {
        let Some(e) = world.entity(s.entity) else { continue };
        if e.class_id >= 0 {
            let (lo, hi) = s.shape.bounds();
            let label = if e.name.is_empty() {
                vlnav_proto::coco::name(e.class_id).unwrap_or("object").to_string()
            } else {
                e.name.clone()
            };
            scene.objects.push(PlotObject {
                at: Point2::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0),
                radius: ((hi.x - lo.x).max(hi.y - lo.y)) / 2.0,
                label,
                outline: poly(&s.shape),
            });
        } else {
            scene.obstacles.push(poly(&s.shape));
        }
    }
    for p in &world.pedestrians {
        let at = p.position_at(0.0);
        scene.objects.push(PlotObject {
            at: Point2::new(at.x, at.y),
            radius: p.radius,
            label: "pedestrian (t = 0)".into(),
            outline: Vec::new(),
        });
    }
    for m in &world.markings {
        let [r, g, b] = m.color;
        for s in &m.shapes {
            scene.zones.push(PlotZone { polygon: poly(s), colour: format!("#{r:02x}{g:02x}{b:02x}") });
        }
    }
    scene
}

/// A scenario's layout with one instruction's destination, success circle
/// and (when it has a route) the route's waypoints as subgoals.
pub fn layout_scene(suite: &Suite, scenario: usize, instruction: usize, world: &World) -> PlotScene {
    let sc = &suite.scenarios[scenario];
    let ins = &sc.instructions[instruction];
    let start = world.start;
    let mut scene = world_scene(world, format!("{} — {} — \"{}\"", sc.title, ins.mode, ins.text(start)), start);
    scene.destination = ins.destination();
    scene.success_radius = ins.radius;
    let mut from: Point2 = start.position().into();
    for leg in &ins.route {
        from = leg.end_point(from);
        scene.subgoals.push(from);
    }
    scene
}

fn plot_scene(
    world: &World,
    title: String,
    start: Pose,
    record: &TrialRecord,
    track: &[TruthSample],
    watched: &Watched,
) -> PlotScene {
    let mut scene = world_scene(world, title, start);
    scene.destination = record.destination;
    scene.success_radius = record.success_radius_m;
    scene.true_path = track.iter().map(|s| s.pose.position().into()).collect();
    scene.odom_path = track.iter().map(|s| s.odom_in_world().position().into()).collect();
    scene.hard_contacts = track.iter().filter(|s| s.hard_contact).map(|s| s.pose.position().into()).collect();
    for (stamp, goal) in &watched.subgoals {
        if let Some(o) = origin_at(track, *stamp) {
            scene.subgoals.push(o.transform(&Point2::new(goal.x, goal.y).into()).into());
        }
    }
    for (stamp, target) in &watched.targets {
        if let Some(o) = origin_at(track, *stamp) {
            scene.target_estimates.push(o.transform(&Point2::new(target.x, target.y).into()).into());
        }
    }
    scene
}

/// Starts the agent, submits, watches, stops the agent. Returns what the
/// stream said and the agent's per-frame records of this mission.
async fn run_mission(
    settings: &TrialSettings,
    robot_id: &str,
    world_file: &Path,
    seed: u64,
    text: &str,
    budget_s: f64,
) -> anyhow::Result<(Watched, Vec<StepRecord>)> {
    let stall = Duration::from_secs_f64(settings.stall_timeout_s);
    let opts = EdgeOptions {
        gateway: settings.gateway_uri.clone(),
        robot_id: robot_id.to_string(),
        driver: DriverKind::Sim,
        scenario: world_file.to_string_lossy().into_owned(),
        seed,
        lockstep: true,
        frame_rate: settings.frame_rate_hz,
        width: Some(settings.camera_width),
        height: Some(settings.camera_height),
        liveness_timeout_s: settings.stall_timeout_s,
        tls: match &settings.pki {
            Some(pki) => {
                pki.ensure_robot(robot_id)?;
                pki.client_args(Some((pki.robot_cert(robot_id), pki.robot_key(robot_id))))
            }
            None => Default::default(),
        },
        ..EdgeOptions::default()
    }
    .with_codecs(settings.codecs);
    let (tx, mut rx) = mpsc::unbounded_channel();
    let shutdown = CancellationToken::new();
    // The robot waits after its first (idle) frame until the mission is in
    // place, so every run of a seed starts its mission on the same frame.
    let gate = IdleGate::closed();
    let hooks = Hooks { observer: Some(tx), idle_gate: Some(gate.clone()), ..Hooks::default() };
    let mut agent = tokio::spawn(vlnav_edge_agent::run_with(opts, shutdown.clone(), hooks));
    // Stops the agent however this function returns.
    let _stop = shutdown.clone().drop_guard();

    // Attached once the gateway has answered a first frame.
    let mut steps: Vec<StepRecord> = Vec::new();
    tokio::select! {
        r = rx.recv() => match r {
            Some(s) => steps.push(s),
            None => {
                let why = match (&mut agent).await {
                    Ok(Err(e)) => format!("{e:#}"),
                    Ok(Ok(())) => "the agent stopped before its first frame".into(),
                    Err(e) => format!("the agent task failed: {e}"),
                };
                anyhow::bail!("edge agent for {robot_id}: {why}");
            }
        },
        _ = tokio::time::sleep(stall) => anyhow::bail!("edge agent {robot_id} did not attach to {} within {} s", settings.gateway_uri, settings.stall_timeout_s),
    }

    let channel = vlnav_runtime::client::channel_with(&settings.gateway_uri, &settings.caller)
        .with_context(|| format!("bad gateway uri {}", settings.gateway_uri))?;
    let mut missions = MissionServiceClient::new(channel);
    let submitted = missions
        .submit_mission(pb::SubmitMissionRequest {
            robot_id: robot_id.to_string(),
            instruction: Some(pb::submit_mission_request::Instruction::Text(text.to_string())),
            dry_run: false,
        })
        .await
        .map_err(|s| anyhow::anyhow!("SubmitMission({text:?}): {:?}: {}", s.code(), s.message()))?
        .into_inner();
    gate.open();
    let mut watched = Watched::default();
    if let Some(pb::submit_mission_response::Outcome::Clarification(c)) = &submitted.outcome {
        watched.outcome = Some(Outcome::Clarification);
        watched.reason = format!("the planner asked: {}", c.question);
        return Ok((watched, Vec::new()));
    }
    if let Some(pb::submit_mission_response::Outcome::Plan(p)) = &submitted.outcome {
        watched.steps_total = p.steps.len() as u32;
    }
    let mission_id = submitted.mission_id.clone();
    let mut stream = missions
        .watch_mission(pb::WatchMissionRequest { mission_id: mission_id.clone() })
        .await
        .map_err(|s| anyhow::anyhow!("WatchMission({mission_id}): {:?}: {}", s.code(), s.message()))?
        .into_inner();

    // Every frame after submission; the mission's own are those whose answer
    // carried its id (the gateway tags each VelocityCommand with it).
    let mut after_submit: Vec<StepRecord> = Vec::new();
    let mut finished_stamp = f64::INFINITY;
    let mut cancelled_for_time = false;
    // The frame that ran past the budget: a timed-out trial ends there, not
    // at whichever later frame the cancellation happened to land on.
    let mut time_cut = None;
    // The frame that asked the user: a trial ends there. The frames the held
    // robot sends until the cancellation lands depend on wall time, not on
    // the trial, so counting them would make a run depend on machine load.
    let mut asked_at = None;
    let mut agent_done = false;
    loop {
        tokio::select! {
            ev = stream.message() => {
                let ev = match ev {
                    Ok(Some(ev)) => ev,
                    Ok(None) => break,
                    Err(s) => anyhow::bail!("WatchMission({mission_id}) broke: {:?}: {}", s.code(), s.message()),
                };
                use pb::mission_event::Kind;
                match ev.kind {
                    Some(Kind::Plan(p)) => {
                        if let Some(plan) = p.plan { watched.steps_total = plan.steps.len() as u32; }
                    }
                    Some(Kind::TargetSeen(t)) => {
                        if let Some(target) = t.target { watched.targets.push((ev.stamp, target)); }
                    }
                    Some(Kind::SubgoalReached(r)) => {
                        if let Some(goal) = r.goal { watched.subgoals.push((ev.stamp, goal)); }
                    }
                    Some(Kind::Replanned(r)) => {
                        watched.replans += 1;
                        if let Some(plan) = r.plan { watched.steps_total = plan.steps.len() as u32; }
                    }
                    Some(Kind::ClarificationNeeded(c)) => {
                        // The harness plays no user: a question ends the trial.
                        watched.outcome = Some(Outcome::Clarification);
                        watched.reason = format!(
                            "the robot asked: {}",
                            c.clarification.map(|c| c.question).unwrap_or_default()
                        );
                        if ev.stamp > 0.0 {
                            asked_at = Some(ev.stamp);
                        }
                        let _ = missions.cancel_mission(pb::CancelMissionRequest { mission_id: mission_id.clone() }).await;
                    }
                    Some(Kind::Finished(f)) => {
                        let state = pb::MissionState::try_from(f.state).unwrap_or(pb::MissionState::Unspecified);
                        if watched.outcome.is_none() {
                            watched.outcome = Some(match state {
                                pb::MissionState::Succeeded => Outcome::Succeeded,
                                pb::MissionState::Cancelled if cancelled_for_time => Outcome::TimedOut,
                                pb::MissionState::AwaitingClarification => Outcome::Clarification,
                                _ => Outcome::Failed,
                            });
                            if watched.reason.is_empty() {
                                watched.reason = f.reason.clone();
                            }
                        }
                        watched.metrics = f.metrics;
                        if ev.stamp > 0.0 {
                            finished_stamp = ev.stamp;
                        }
                        break;
                    }
                    _ => {}
                }
            }
            s = rx.recv(), if !agent_done => {
                let Some(s) = s else { agent_done = true; continue };
                let (stamp, elapsed) =
                    (s.stamp, after_submit.first().map(|f: &StepRecord| s.stamp - f.stamp).unwrap_or(0.0));
                after_submit.push(s);
                if elapsed > budget_s && !cancelled_for_time {
                        cancelled_for_time = true;
                        time_cut = Some(stamp);
                        watched.reason = format!("no result within {budget_s} s of sensor time");
                        match missions.cancel_mission(pb::CancelMissionRequest { mission_id: mission_id.clone() }).await {
                            Ok(_) => {}
                            // It finished on the same frame: its Finished event is on the way.
                            Err(s) if s.code() == tonic::Code::FailedPrecondition => {
                                cancelled_for_time = false;
                                time_cut = None;
                                watched.reason.clear();
                            }
                            Err(s) => anyhow::bail!("CancelMission({mission_id}): {:?}: {}", s.code(), s.message()),
                        }
                }
            }
            _ = tokio::time::sleep(stall) => {
                anyhow::bail!("mission {mission_id} made no progress for {} s of wall time", settings.stall_timeout_s);
            }
        }
    }
    if watched.outcome.is_none() {
        watched.reason = format!("the event stream of mission {mission_id} ended before it finished");
    }
    // The frame that finished the mission is the agent's once its answer
    // arrives: wait for it, so no run loses its last frame to the shutdown.
    if finished_stamp.is_finite() && !agent_done && after_submit.last().is_none_or(|s| s.stamp < finished_stamp - 1e-9)
    {
        let deadline = tokio::time::Instant::now() + stall;
        while let Ok(Some(s)) = tokio::time::timeout_at(deadline, rx.recv()).await {
            let last = s.stamp >= finished_stamp - 1e-9;
            after_submit.push(s);
            if last {
                break;
            }
        }
    }
    shutdown.cancel();
    // Frames already queued by the agent that still belong to the mission.
    let _ = agent.await;
    while let Ok(s) = rx.try_recv() {
        after_submit.push(s);
    }
    let mut frames = mission_frames(after_submit, &mission_id, finished_stamp);
    if let Some(cut) = time_cut.filter(|_| watched.outcome == Some(Outcome::TimedOut)) {
        frames.retain(|s| s.stamp <= cut + 1e-9);
    }
    if let Some(cut) = asked_at {
        frames.retain(|s| s.stamp <= cut + 1e-9);
    }
    Ok((watched, frames))
}

/// The frames of one mission: those answered under its id or, should the
/// gateway leave commands untagged, every frame from submission up to the
/// stamp of its `Finished` event.
fn mission_frames(after_submit: Vec<StepRecord>, mission_id: &str, finished_stamp: f64) -> Vec<StepRecord> {
    if after_submit.iter().any(|s| s.mission_id == mission_id) {
        after_submit.into_iter().filter(|s| s.mission_id == mission_id).collect()
    } else {
        after_submit.into_iter().filter(|s| s.stamp <= finished_stamp + 1e-9).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(stamp: f64, mission: &str) -> StepRecord {
        StepRecord {
            seq: 0,
            stamp,
            odom: vlnav_sim::Pose2::new(0.0, 0.0, 0.0),
            truth: None,
            command: None,
            applied: vlnav_edge_agent::Twist::ZERO,
            verdict: vlnav_edge_agent::Verdict::NoCommand,
            idle: mission.is_empty(),
            mission_id: mission.into(),
        }
    }

    #[test]
    fn a_missions_frames_are_the_tagged_ones_or_those_up_to_its_end() {
        let tagged = vec![step(0.0, ""), step(0.2, "m1"), step(0.4, "m1"), step(0.6, "")];
        let got = mission_frames(tagged, "m1", 0.5);
        assert_eq!(got.iter().map(|s| s.stamp).collect::<Vec<_>>(), vec![0.2, 0.4]);
        let untagged = vec![step(0.0, ""), step(0.2, ""), step(0.4, ""), step(0.6, "")];
        let got = mission_frames(untagged, "m1", 0.4);
        assert_eq!(got.len(), 3);
    }

    const WORLD: &str = r#"
name = "t"
[robot]
start = [0.0, 0.0, 0.0]
[[walls]]
path = [[-2, -3], [9, -3], [9, 3], [-2, 3]]
closed = true
[[markings]]
kind = "restricted_zone"
polygon = [[3, -1], [4, -1], [4, 1], [3, 1]]
color = [220, 30, 30]
"#;

    #[test]
    fn the_start_pose_is_rewritten_and_the_world_still_parses() {
        let text = with_start(WORLD, Pose::new(0.5, -0.25, 0.1)).unwrap();
        let w = vlnav_sim::scenario::parse(&text).unwrap();
        assert_eq!((w.start.x, w.start.y, w.start.theta), (0.5, -0.25, 0.1));
        assert!(with_start("name = 'x'", Pose::default()).unwrap_err().to_string().contains("[robot]"));
    }

    #[test]
    fn contact_is_judged_on_the_footprint() {
        let w = vlnav_sim::scenario::parse(WORLD).unwrap();
        assert_eq!(contact_at(&w, Pose::new(0.0, 0.0, 0.0), 0.0), (false, false));
        // Footprint 0.988 m long: its front edge reaches the zone at x = 3 from x > 2.506.
        assert_eq!(contact_at(&w, Pose::new(2.6, 0.0, 0.0), 0.0), (false, true));
        assert_eq!(contact_at(&w, Pose::new(2.4, 0.0, 0.0), 0.0), (false, false));
        // Against the east wall (inner face at 9 − 0.075).
        assert!(contact_at(&w, Pose::new(8.45, 0.0, 0.0), 0.0).0);
    }

    #[test]
    fn target_estimates_map_through_the_origin_in_force() {
        let mk =
            |stamp: f64, ox: f64| TruthSample { stamp, odom_origin: Pose::new(ox, 0.0, 0.0), ..Default::default() };
        let track = [mk(0.0, 0.0), mk(1.0, 5.0), mk(2.0, 7.0)];
        assert_eq!(origin_at(&track, 1.5).unwrap().x, 5.0);
        assert_eq!(origin_at(&track, 1.0).unwrap().x, 5.0);
        assert_eq!(origin_at(&track, 9.0).unwrap().x, 7.0);
    }
}
