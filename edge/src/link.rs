//! The link to the gateway, shared by every driver: one attached stream
//! ([`Link`]), why a session on it ended ([`SessionEnd`]), the e-stop and
//! deadman reports sent up ([`StatusReporter`]), and the bookkeeping of the
//! newest admitted velocity command ([`LastCommand`]).

use std::time::Duration;

use anyhow::Context;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tonic::Streaming;
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::fleet_service_client::FleetServiceClient;
use vlnav_sim::Twist;

use crate::EdgeOptions;
use crate::convert;
use crate::safety::{CommandGate, Governor, Verdict};

/// Why a session ended.
#[derive(Debug)]
pub enum SessionEnd {
    /// Shutdown requested or the episode's time is up.
    Finished,
    /// The link failed; reconnect.
    Lost(String),
}

/// One attached stream to the gateway.
pub struct Link {
    tx: mpsc::Sender<pb::EdgeMessage>,
    rx: Streaming<pb::GatewayCommand>,
    last_heard: Instant,
}

impl Link {
    /// Attaches to the gateway and sends `hello` first.
    pub async fn connect(opts: &EdgeOptions, hello: pb::EdgeHello) -> anyhow::Result<Link> {
        let tls = opts.tls.load()?;
        if tls.is_some() && !opts.gateway.starts_with("https://") {
            anyhow::bail!(
                "--tls-ca is given but --gateway {} is not https://: this robot drives only for a gateway it has verified",
                opts.gateway
            );
        }
        let security = vlnav_runtime::security::ClientSecurity::new(tls, None);
        let channel = vlnav_runtime::client::channel_with(&opts.gateway, &security)
            .with_context(|| format!("bad --gateway uri {}", opts.gateway))?;
        let mut client = FleetServiceClient::new(channel)
            .max_decoding_message_size(opts.max_message_bytes)
            .max_encoding_message_size(opts.max_message_bytes);
        let (tx, rx) = mpsc::channel(4);
        tx.send(convert::edge(pb::edge_message::Kind::Hello(hello))).await.expect("receiver is alive");
        let attach = client.attach(tokio_stream::wrappers::ReceiverStream::new(rx));
        let response = tokio::time::timeout(Duration::from_secs_f64(opts.liveness_timeout_s), attach)
            .await
            .map_err(|_| {
                anyhow::anyhow!("gateway {} did not answer Attach within {} s", opts.gateway, opts.liveness_timeout_s)
            })?
            .with_context(|| format!("attaching to the gateway at {}", opts.gateway))?;
        Ok(Link { tx, rx: response.into_inner(), last_heard: Instant::now() })
    }

    /// Sends and waits for room (lockstep).
    pub async fn send(&self, msg: pb::EdgeMessage) -> Result<(), String> {
        self.tx.send(msg).await.map_err(|_| "the gateway closed the stream".to_string())
    }

    /// Sends if there is room; a full queue drops the message (real time
    /// prefers a fresh frame to a late one). Errors only on a closed stream.
    pub fn offer(&self, msg: pb::EdgeMessage) -> Result<bool, String> {
        match self.tx.try_send(msg) {
            Ok(()) => Ok(true),
            Err(mpsc::error::TrySendError::Full(_)) => Ok(false),
            Err(mpsc::error::TrySendError::Closed(_)) => Err("the gateway closed the stream".into()),
        }
    }

    /// The next command from the gateway.
    pub async fn recv(&mut self) -> Result<pb::GatewayCommand, String> {
        match self.rx.message().await {
            Ok(Some(m)) => {
                self.last_heard = Instant::now();
                Ok(m)
            }
            Ok(None) => Err("the gateway ended the stream".into()),
            Err(status) => Err(format!("stream failed: {} ({:?})", status.message(), status.code())),
        }
    }

    pub fn last_heard(&self) -> Instant {
        self.last_heard
    }
}

/// What the robot itself reports besides its sensors: its own e-stop and
/// its battery (ROS 2 robots; the other drivers report neither).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RobotState {
    pub platform_estop: bool,
    pub battery: Option<pb::BatteryStatus>,
}

/// Reports e-stop, deadman and robot-state changes to the gateway, once per
/// change (the battery: once per whole percent or change of `low`).
#[derive(Default)]
pub struct StatusReporter {
    last: Option<Reported>,
}

/// What was last reported: e-stop, deadman tripped, the robot's own e-stop,
/// and the battery (whole percent, low).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Reported {
    estop: bool,
    deadman_tripped: bool,
    platform_estop: bool,
    battery: Option<(i64, bool)>,
}

impl StatusReporter {
    pub fn update(&mut self, stamp: f64, verdict: Verdict) -> Option<pb::EdgeMessage> {
        self.update_with(stamp, verdict, RobotState::default())
    }

    pub fn update_with(&mut self, stamp: f64, verdict: Verdict, robot: RobotState) -> Option<pb::EdgeMessage> {
        let estop = verdict == Verdict::EStop;
        let tripped = verdict.deadman_tripped();
        let battery = robot.battery.map(|b| ((b.fraction * 100.0).round() as i64, b.low));
        let key = Reported { estop, deadman_tripped: tripped, platform_estop: robot.platform_estop, battery };
        if self.last == Some(key) {
            return None;
        }
        self.last = Some(key);
        let detail = match verdict {
            Verdict::EStop if robot.platform_estop => "the robot's emergency stop is engaged: holding zero velocity",
            Verdict::EStop => "e-stop engaged: holding zero velocity",
            Verdict::DeadmanTripped => "deadman: no fresh command, holding zero velocity",
            Verdict::NoCommand => "waiting for the first command, holding zero velocity",
            Verdict::Commanded { .. } => "following commands",
        };
        Some(convert::edge(pb::edge_message::Kind::Status(pb::EdgeStatus {
            stamp,
            estop,
            deadman_tripped: tripped,
            detail: detail.into(),
            platform_estop: robot.platform_estop,
            battery: robot.battery,
        })))
    }

    pub fn reset(&mut self) {
        self.last = None;
    }
}

/// What the latest admitted velocity command said besides its twist:
/// whether the gateway is idle (no mission running) and for which mission
/// it was; and the gate that drops replayed, reordered, stale and
/// unanswerable commands on this link (docs/security.md).
#[derive(Clone, Debug)]
pub(crate) struct LastCommand {
    pub idle: bool,
    pub mission: String,
    gate: CommandGate,
}

impl LastCommand {
    pub(crate) fn new(gov: &Governor) -> Self {
        Self { idle: true, mission: String::new(), gate: CommandGate::new(gov.deadman_timeout()) }
    }

    /// A frame stamped `stamp` went to the gateway.
    pub(crate) fn frame_sent(&mut self, stamp: f64) {
        self.gate.frame_sent(stamp);
    }

    /// The gateway announced which mission drives from now on (fleet.proto).
    pub(crate) fn announce(&mut self, a: &pb::MissionAnnouncement) {
        tracing::debug!(mission = %a.mission_id, stamp = a.stamp, "mission announced");
        self.gate.announce(&a.mission_id);
    }

    /// Hands `v`'s twist to the governor and keeps the rest, unless the gate
    /// drops it (logged with the counts so far).
    pub(crate) fn take(&mut self, gov: &mut Governor, v: pb::VelocityCommand) {
        let twist = twist_of(&v);
        if let Err(why) = self.gate.admit(v.seq, v.stamp, &v.mission_id, twist != Twist::ZERO) {
            tracing::warn!(
                seq = v.seq,
                stamp = v.stamp,
                ?why,
                dropped = ?self.gate.dropped(),
                mission = %v.mission_id,
                announced = %self.gate.announced(),
                "velocity command dropped"
            );
            return;
        }
        gov.on_command(v.stamp, twist);
        self.idle = v.idle;
        self.mission = v.mission_id;
    }
}

pub(crate) fn twist_of(v: &pb::VelocityCommand) -> Twist {
    v.twist.map(|t| Twist::new(t.linear, t.angular)).unwrap_or(Twist::ZERO)
}
