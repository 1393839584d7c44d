//! One actor per robot. It owns the robot's attach stream (the sender of
//! velocity commands), its connection state and the mission being executed,
//! and answers every sensor frame with exactly one command.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tokio::sync::{mpsc, oneshot};
use tonic::Status;
use tracing::Instrument;
use vlnav_proto::v1::{
    ActionStep, Clarification, EdgeHello, EdgeStatus, GatewayCommand, MissionAnnouncement, MissionEvent,
    OdometryUpdate, RobotInfo, Twist2D, VelocityCommand, gateway_command,
};
use vlnav_runtime::actor::Mailbox;

use crate::config::ExecutorParams;
use crate::executor::{Ctx, EventSink, MissionRun, Seen};
use crate::frames::CheckedFrame;
use crate::hub::Hub;
use crate::pipeline::Pipeline;
use crate::viz::{FrameView, MissionView, RobotHealth, Viz};

pub(crate) type Outbound = mpsc::Sender<Result<GatewayCommand, Status>>;

pub(crate) enum RobotMsg {
    Attach {
        hello: EdgeHello,
        outbound: Outbound,
        conn: u64,
        reply: oneshot::Sender<Result<(), Status>>,
    },
    Frame {
        conn: u64,
        frame: Box<CheckedFrame>,
    },
    Odometry {
        conn: u64,
        odometry: OdometryUpdate,
    },
    Status {
        conn: u64,
        status: EdgeStatus,
    },
    Detach {
        conn: u64,
        reason: String,
    },
    Reserve {
        mission_id: String,
        reply: oneshot::Sender<Result<(), Status>>,
    },
    Release {
        mission_id: String,
    },
    Start {
        run: Box<MissionRun>,
        reply: oneshot::Sender<Result<(), Status>>,
    },
    Cancel {
        mission_id: String,
        reply: oneshot::Sender<Result<(), Status>>,
    },
    Answer {
        mission_id: String,
        answer: String,
        reply: oneshot::Sender<Result<Result<Vec<ActionStep>, Clarification>, Status>>,
    },
}

/// A robot's actor and the status it publishes.
type RobotEntry = (Mailbox<RobotMsg>, Arc<Mutex<RobotInfo>>);

/// Every robot the gateway has seen, connected or not.
pub(crate) struct Fleet {
    robots: Mutex<HashMap<String, RobotEntry>>,
    hub: Arc<Hub>,
    pipeline: Pipeline,
    params: ExecutorParams,
    viz: Viz,
    next_conn: std::sync::atomic::AtomicU64,
}

impl Fleet {
    pub(crate) fn new(hub: Arc<Hub>, pipeline: Pipeline, params: ExecutorParams, viz: Viz) -> Arc<Self> {
        Arc::new(Self { robots: Mutex::new(HashMap::new()), hub, pipeline, params, viz, next_conn: 1.into() })
    }

    /// The live view and recordings.
    pub(crate) fn viz(&self) -> &Viz {
        &self.viz
    }

    fn ctx(&self) -> Ctx<'_> {
        Ctx { pipeline: &self.pipeline, params: &self.params, hub: &self.hub, events: &self.viz }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, RobotEntry>> {
        self.robots.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The robot's mailbox, creating its actor on first contact.
    fn robot(self: &Arc<Self>, robot_id: &str) -> Mailbox<RobotMsg> {
        let mut robots = self.lock();
        if let Some((mb, _)) = robots.get(robot_id)
            && !mb.is_closed()
        {
            return mb.clone();
        }
        let (mailbox, rx) = Mailbox::channel("robot", 64);
        let info = Arc::new(Mutex::new(RobotInfo { robot_id: robot_id.to_string(), ..Default::default() }));
        let actor = RobotActor {
            robot_id: robot_id.to_string(),
            fleet: self.clone(),
            info: info.clone(),
            conn: None,
            reserved: None,
            run: None,
            last_stamp: None,
            command_seq: 0,
            announced: String::new(),
        };
        tokio::spawn(actor.run(rx));
        robots.insert(robot_id.to_string(), (mailbox.clone(), info));
        mailbox
    }

    /// A connected robot's mailbox, or NOT_FOUND naming the connected ones.
    fn connected(&self, robot_id: &str) -> Result<Mailbox<RobotMsg>, Status> {
        let robots = self.lock();
        match robots.get(robot_id) {
            Some((mb, info)) if info.lock().map(|i| i.connected).unwrap_or(false) => Ok(mb.clone()),
            _ => {
                let mut names: Vec<String> = robots
                    .iter()
                    .filter(|(_, (_, i))| i.lock().map(|i| i.connected).unwrap_or(false))
                    .map(|(k, _)| k.clone())
                    .collect();
                names.sort();
                Err(Status::not_found(format!(
                    "no robot named '{robot_id}' is connected (connected: {}); start its edge agent or pick one from ListRobots",
                    if names.is_empty() { "none".to_string() } else { names.join(", ") }
                )))
            }
        }
    }

    pub(crate) fn next_conn(&self) -> u64 {
        self.next_conn.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    }

    pub(crate) async fn attach(
        self: &Arc<Self>,
        hello: EdgeHello,
        outbound: Outbound,
        conn: u64,
    ) -> Result<Mailbox<RobotMsg>, Status> {
        let mb = self.robot(&hello.robot_id);
        mb.call(|reply| RobotMsg::Attach { hello, outbound, conn, reply }).await??;
        Ok(mb)
    }

    pub(crate) async fn reserve(&self, robot_id: &str, mission_id: &str) -> Result<(), Status> {
        let mb = self.connected(robot_id)?;
        mb.call(|reply| RobotMsg::Reserve { mission_id: mission_id.to_string(), reply }).await?
    }

    pub(crate) async fn release(&self, robot_id: &str, mission_id: &str) {
        let mb = self.lock().get(robot_id).map(|(mb, _)| mb.clone());
        if let Some(mb) = mb {
            let _ = mb.tell(RobotMsg::Release { mission_id: mission_id.to_string() }).await;
        }
    }

    fn any(&self, robot_id: &str) -> Result<Mailbox<RobotMsg>, Status> {
        self.lock()
            .get(robot_id)
            .map(|(mb, _)| mb.clone())
            .ok_or_else(|| Status::not_found(format!("robot '{robot_id}' is not known to this gateway")))
    }

    pub(crate) async fn start(&self, robot_id: &str, run: MissionRun) -> Result<(), Status> {
        let mb = self.any(robot_id)?;
        mb.call(|reply| RobotMsg::Start { run: Box::new(run), reply }).await?
    }

    pub(crate) async fn cancel(&self, robot_id: &str, mission_id: &str) -> Result<(), Status> {
        let mb = self.any(robot_id)?;
        mb.call(|reply| RobotMsg::Cancel { mission_id: mission_id.to_string(), reply }).await?
    }

    pub(crate) async fn answer(
        &self,
        robot_id: &str,
        mission_id: &str,
        answer: String,
    ) -> Result<Result<Vec<ActionStep>, Clarification>, Status> {
        let mb = self.any(robot_id)?;
        mb.call(|reply| RobotMsg::Answer { mission_id: mission_id.to_string(), answer, reply }).await?
    }

    pub(crate) fn list(&self) -> Vec<RobotInfo> {
        let mut out: Vec<RobotInfo> =
            self.lock().values().map(|(_, i)| i.lock().map(|i| i.clone()).unwrap_or_default()).collect();
        out.sort_by(|a, b| a.robot_id.cmp(&b.robot_id));
        out
    }

    /// Forgets every robot: their actors end once their streams are gone.
    pub(crate) fn close(&self) {
        self.lock().clear();
    }

    pub(crate) fn hub(&self) -> &Arc<Hub> {
        &self.hub
    }

    pub(crate) fn pipeline(&self) -> &Pipeline {
        &self.pipeline
    }
}

/// The executor's events go to the live view and the recordings.
impl EventSink for Viz {
    fn wants_events(&self) -> bool {
        self.is_on()
    }

    fn event(&self, robot_id: &str, event: MissionEvent) {
        Viz::event(self, robot_id, event);
    }
}

/// Takes what is already queued behind a frame: the newest frame of each
/// connection wins, every other message is kept in order. Returns the frame
/// to act on, the other messages (handled first) and how many frames were
/// passed over.
fn newest_frame(
    conn: u64,
    frame: Box<CheckedFrame>,
    rx: &mut mpsc::Receiver<RobotMsg>,
) -> (RobotMsg, Vec<RobotMsg>, u64) {
    let mut newest = RobotMsg::Frame { conn, frame };
    let mut others = Vec::new();
    let mut skipped = 0;
    // Only what is queued now: a steady stream of frames cannot keep this loop going.
    for _ in 0..rx.len() {
        match rx.try_recv() {
            Ok(RobotMsg::Frame { conn: c, frame: f }) if c == conn => {
                skipped += 1;
                newest = RobotMsg::Frame { conn: c, frame: f };
            }
            Ok(other) => others.push(other),
            Err(_) => break,
        }
    }
    (newest, others, skipped)
}

/// Why a mission may not start on this robot now: its emergency stop (its
/// own or its edge agent's) is engaged. The edge agent holds the robot at
/// zero while it is, whatever the gateway sends (edge/README.md).
fn estop_refusal(info: &RobotInfo) -> Option<String> {
    if !info.connected || !info.estop {
        return None;
    }
    let whose = if info.platform_estop { "the robot's own emergency stop" } else { "its edge agent's e-stop" };
    Some(format!(
        "robot '{}' has {whose} engaged (reported at sensor time {:.3} s); release it, then submit the mission again",
        info.robot_id, info.last_stamp
    ))
}

fn clear_active(info: &Mutex<RobotInfo>) {
    if let Ok(mut i) = info.lock() {
        i.active_mission_id.clear();
    }
}

struct RobotActor {
    robot_id: String,
    fleet: Arc<Fleet>,
    info: Arc<Mutex<RobotInfo>>,
    conn: Option<(u64, Outbound)>,
    /// A mission being planned for this robot (between SubmitMission's check and start).
    reserved: Option<String>,
    run: Option<Box<MissionRun>>,
    last_stamp: Option<f64>,
    command_seq: u64,
    /// The mission last announced on the current connection (empty: none);
    /// the edge agent drives only for the announced one (fleet.proto).
    announced: String,
}

impl RobotActor {
    fn update(&self, f: impl FnOnce(&mut RobotInfo)) {
        if let Ok(mut i) = self.info.lock() {
            f(&mut i);
        }
    }

    fn busy_with(&self) -> Option<String> {
        self.run.as_ref().map(|r| r.mission_id.clone()).or_else(|| self.reserved.clone())
    }

    async fn run(mut self, mut rx: mpsc::Receiver<RobotMsg>) {
        while let Some(msg) = rx.recv().await {
            match msg {
                RobotMsg::Frame { conn, frame } if !self.lockstep() => {
                    // A real-time robot's world did not wait for this frame:
                    // act on the newest one queued and pass over the others.
                    let (frame, others, skipped) = newest_frame(conn, frame, &mut rx);
                    if skipped > 0 {
                        self.update(|i| i.frames_skipped += skipped);
                        tracing::debug!(robot = %self.robot_id, skipped, "newer frames were waiting; older ones passed over");
                    }
                    for other in others {
                        self.handle(other).await;
                    }
                    self.handle(frame).await;
                }
                msg => self.handle(msg).await,
            }
        }
    }

    fn lockstep(&self) -> bool {
        self.info.lock().map(|i| i.lockstep).unwrap_or(false)
    }

    async fn handle(&mut self, msg: RobotMsg) {
        match msg {
            RobotMsg::Attach { hello, outbound, conn, reply } => {
                if let Some((old, tx)) = &self.conn
                    && !tx.is_closed()
                {
                    let _ = reply.send(Err(Status::already_exists(format!(
                        "robot '{}' is already attached (connection {old}); stop the other edge agent first",
                        self.robot_id
                    ))));
                    return;
                }
                self.conn = Some((conn, outbound));
                self.last_stamp = None;
                self.announced.clear();
                self.update(|i| {
                    i.connected = true;
                    i.driver = hello.driver.clone();
                    i.lockstep = hello.lockstep;
                    i.limits = hello.limits;
                });
                tracing::info!(robot = %self.robot_id, driver = %hello.driver, lockstep = hello.lockstep, "robot attached");
                let _ = reply.send(Ok(()));
            }
            RobotMsg::Detach { conn, reason } => {
                if self.conn.as_ref().is_some_and(|(c, _)| *c == conn) {
                    self.conn = None;
                    self.update(|i| i.connected = false);
                    tracing::info!(robot = %self.robot_id, %reason, "robot detached");
                }
            }
            RobotMsg::Odometry { conn, odometry } => {
                if self.is_current(conn) {
                    self.update(|i| {
                        i.last_odometry = odometry.pose;
                        i.last_stamp = odometry.stamp;
                    });
                }
            }
            RobotMsg::Status { conn, status } => {
                if self.is_current(conn) {
                    self.update(|i| {
                        i.estop = status.estop;
                        i.deadman_tripped = status.deadman_tripped;
                        i.platform_estop = status.platform_estop;
                        if status.battery.is_some() {
                            i.battery = status.battery;
                        }
                    });
                }
            }
            RobotMsg::Frame { conn, frame } => {
                if self.is_current(conn) {
                    self.on_frame(*frame).await;
                }
            }
            RobotMsg::Reserve { mission_id, reply } => {
                let estop = self.info.lock().ok().and_then(|i| estop_refusal(&i));
                let r = match self.busy_with() {
                    Some(other) => Err(Status::failed_precondition(format!(
                        "robot '{}' is busy with mission {other}; cancel it (CancelMission) or wait for it to finish",
                        self.robot_id
                    ))),
                    None if estop.is_some() => Err(Status::failed_precondition(estop.unwrap_or_default())),
                    None => {
                        self.reserved = Some(mission_id);
                        Ok(())
                    }
                };
                let _ = reply.send(r);
            }
            RobotMsg::Release { mission_id } => {
                if self.reserved.as_deref() == Some(mission_id.as_str()) {
                    self.reserved = None;
                }
            }
            RobotMsg::Start { run, reply } => {
                let r = match self.busy_with() {
                    Some(other) if other != run.mission_id => Err(Status::failed_precondition(format!(
                        "robot '{}' is busy with mission {other}",
                        self.robot_id
                    ))),
                    _ => {
                        self.reserved = None;
                        let id = run.mission_id.clone();
                        self.fleet.viz.start_mission(&self.robot_id, &id, run.plan_proto(), run.instruction());
                        self.update(|i| i.active_mission_id = id);
                        self.run = Some(run);
                        Ok(())
                    }
                };
                let _ = reply.send(r);
            }
            RobotMsg::Cancel { mission_id, reply } => {
                let r = match self.run.as_mut() {
                    Some(run) if run.mission_id == mission_id => {
                        let ctx = self.fleet.ctx();
                        clear_active(&self.info);
                        run.cancel(&ctx);
                        self.fleet.viz.end_mission(&self.robot_id, &mission_id);
                        self.run = None;
                        Ok(())
                    }
                    _ => Err(Status::failed_precondition(format!(
                        "mission {mission_id} is not running on robot '{}'",
                        self.robot_id
                    ))),
                };
                let _ = reply.send(r);
            }
            RobotMsg::Answer { mission_id, answer, reply } => {
                let r = match self.run.as_mut() {
                    Some(run) if run.mission_id == mission_id => {
                        let ctx = self.fleet.ctx();
                        run.answer(&ctx, &answer).await
                    }
                    _ => Err(Status::failed_precondition(format!(
                        "mission {mission_id} is not waiting on robot '{}'",
                        self.robot_id
                    ))),
                };
                let _ = reply.send(r);
            }
        }
    }

    fn is_current(&self, conn: u64) -> bool {
        self.conn.as_ref().is_some_and(|(c, _)| *c == conn)
    }

    async fn on_frame(&mut self, frame: CheckedFrame) {
        let f = frame.frame();
        let stamp = f.stamp;
        self.last_stamp = Some(stamp);
        self.update(|i| {
            i.frames_received += 1;
            i.last_stamp = stamp;
            i.last_odometry = f.odom;
        });
        let health = self
            .info
            .lock()
            .map(|i| RobotHealth { estop: i.estop, platform_estop: i.platform_estop, battery: i.battery })
            .unwrap_or_default();
        let estop = health.estop;
        let fleet = self.fleet.clone();
        let ctx = fleet.ctx();
        let (twist, active, span, mission_id, seen, mission) = match self.run.as_mut() {
            Some(run) => {
                let tick = run.on_frame(&ctx, &frame, estop).await;
                let id = run.mission_id.clone();
                let mission = fleet.viz.is_on().then(|| MissionView {
                    mission_id: id.clone(),
                    step: run.step().cloned(),
                    steps: run.plan_len(),
                    state: match tick.finished {
                        Some(state) => format!("{:?}", state).to_lowercase(),
                        None if run.is_awaiting() => "awaiting answer".into(),
                        None => "running".into(),
                    },
                });
                if tick.finished.is_some() {
                    // The robot is free before anyone can read that the mission ended.
                    clear_active(&self.info);
                    run.flush(&ctx);
                    self.run = None;
                } else {
                    run.flush(&ctx);
                }
                (tick.twist, tick.active, tick.span, id, tick.seen, mission)
            }
            None => (Twist2D::default(), false, tracing::Span::none(), String::new(), Seen::default(), None),
        };
        let finished = mission.as_ref().is_some_and(|_| self.run.is_none());
        self.command_seq += 1;
        let announcement = (mission_id != self.announced).then(|| {
            self.announced = mission_id.clone();
            GatewayCommand {
                kind: Some(gateway_command::Kind::Mission(MissionAnnouncement {
                    mission_id: mission_id.clone(),
                    stamp,
                })),
            }
        });
        let cmd = GatewayCommand {
            kind: Some(gateway_command::Kind::Velocity(VelocityCommand {
                seq: self.command_seq,
                stamp,
                twist: Some(twist),
                idle: !active,
                mission_id,
            })),
        };
        if let Some((_, tx)) = &self.conn {
            // Same stream, so the edge agent reads it before the command it governs.
            if let Some(a) = announcement
                && tx.send(Ok(a)).await.is_err()
            {
                tracing::warn!(robot = %self.robot_id, "the edge agent went away before the mission was announced");
                return;
            }
            let forward = tracing::info_span!(parent: &span, "edge-forward", robot.id = %self.robot_id);
            if span.is_none() {
                let _ = tx.send(Ok(cmd.clone())).await;
            } else if tx.send(Ok(cmd.clone())).instrument(forward).await.is_err() {
                tracing::warn!(robot = %self.robot_id, "the edge agent went away before its command was sent");
            }
        }
        // The command has left: the view gets the frame (moved, not copied).
        if fleet.viz.is_on() {
            let command = match cmd.kind {
                Some(gateway_command::Kind::Velocity(v)) => v,
                _ => VelocityCommand::default(),
            };
            let mission_id = mission.as_ref().map(|m| m.mission_id.clone());
            let lockstep = self.lockstep();
            fleet
                .viz
                .frame(
                    FrameView {
                        robot_id: self.robot_id.clone(),
                        frame: frame.into_sensor(),
                        command,
                        mission,
                        seen,
                        health,
                    },
                    lockstep,
                )
                .await;
            if finished && let Some(id) = mission_id {
                fleet.viz.end_mission(&self.robot_id, &id);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(conn: u64, seq: u64) -> RobotMsg {
        let f = vlnav_proto::v1::RgbdFrame { seq, ..crate::frames::tests::frame(8, 6) };
        let f = CheckedFrame::check(vlnav_proto::v1::SensorFrame { frame: Some(f), truth: None }, None).unwrap();
        RobotMsg::Frame { conn, frame: Box::new(f) }
    }

    fn seq(msg: &RobotMsg) -> Option<(u64, u64)> {
        match msg {
            RobotMsg::Frame { conn, frame } => Some((*conn, frame.frame().seq)),
            _ => None,
        }
    }

    #[test]
    fn a_mission_is_refused_while_either_estop_is_engaged() {
        let mut info = RobotInfo { robot_id: "a300".into(), connected: true, ..Default::default() };
        assert_eq!(estop_refusal(&info), None);
        info.estop = true;
        info.platform_estop = true;
        let why = estop_refusal(&info).unwrap();
        assert!(why.contains("robot 'a300' has the robot's own emergency stop engaged"), "{why}");
        info.platform_estop = false;
        assert!(estop_refusal(&info).unwrap().contains("edge agent's e-stop"));
        info.connected = false;
        assert_eq!(estop_refusal(&info), None, "only an attached robot's report counts");
    }

    #[tokio::test]
    async fn the_newest_queued_frame_wins_and_other_messages_keep_their_order() {
        let (tx, mut rx) = mpsc::channel(16);
        tx.send(frame(1, 2)).await.unwrap();
        tx.send(RobotMsg::Release { mission_id: "a".into() }).await.unwrap();
        tx.send(frame(1, 3)).await.unwrap();
        // A frame of an older connection is not a newer frame of this one.
        tx.send(frame(0, 9)).await.unwrap();
        tx.send(RobotMsg::Detach { conn: 1, reason: "gone".into() }).await.unwrap();
        let RobotMsg::Frame { conn, frame: first } = frame(1, 1) else { unreachable!() };
        let (newest, others, skipped) = newest_frame(conn, first, &mut rx);
        assert_eq!(seq(&newest), Some((1, 3)));
        assert_eq!(skipped, 2, "frames 1 and 2 are passed over");
        assert_eq!(others.len(), 3);
        assert!(matches!(&others[0], RobotMsg::Release { mission_id } if mission_id == "a"));
        assert_eq!(seq(&others[1]), Some((0, 9)));
        assert!(matches!(&others[2], RobotMsg::Detach { conn: 1, .. }));
        assert!(rx.try_recv().is_err(), "everything queued was taken");
    }
}
