//! A scripted FleetService peer for protocol tests: it records what the edge
//! agent sends and answers each frame as the test's script says.

#![allow(dead_code)]

use std::pin::Pin;
use std::sync::{Arc, Mutex};

use futures::Stream;
use tokio::sync::mpsc;
use tonic::{Request, Response, Status, Streaming};
use vlnav_proto::v1 as pb;
use vlnav_proto::v1::fleet_service_server::{FleetService, FleetServiceServer};
use vlnav_runtime::{CancellationToken, ServerConfig, ServiceSet};

/// How to answer one frame.
#[derive(Clone, Debug)]
pub enum Reply {
    /// A velocity command with this stamp.
    Command { stamp: f64, linear: f64, angular: f64, idle: bool },
    /// A velocity command with this sequence number (a replay, a reordering).
    Numbered { seq: u64, stamp: f64, linear: f64 },
    /// A velocity command for `mission` that was never announced (empty:
    /// none), numbered in order, answering this frame.
    Unannounced { mission: &'static str, linear: f64 },
    /// No answer.
    Silence,
}

/// The script: (attach number from 0, frame index within that attach, frame stamp) → reply.
pub type Script = Arc<dyn Fn(usize, usize, f64) -> Reply + Send + Sync>;

#[derive(Default, Debug)]
pub struct Log {
    pub hellos: Vec<pb::EdgeHello>,
    /// (attach, frame) in arrival order.
    pub frames: Vec<(usize, pb::SensorFrame)>,
    pub odometry: Vec<pb::OdometryUpdate>,
    pub statuses: Vec<pb::EdgeStatus>,
    /// Stamps of the frames answered with a command, and the command's stamp.
    pub answered: Vec<(f64, f64)>,
    pub protocol_errors: Vec<String>,
}

#[derive(Clone)]
pub struct ScriptedGateway {
    pub log: Arc<Mutex<Log>>,
    script: Script,
    attaches: Arc<Mutex<usize>>,
}

type CommandStream = Pin<Box<dyn Stream<Item = Result<pb::GatewayCommand, Status>> + Send>>;

#[tonic::async_trait]
impl FleetService for ScriptedGateway {
    type AttachStream = CommandStream;

    async fn attach(
        &self,
        request: Request<Streaming<pb::EdgeMessage>>,
    ) -> Result<Response<Self::AttachStream>, Status> {
        let mut inbound = request.into_inner();
        let attach_no = {
            let mut n = self.attaches.lock().unwrap();
            *n += 1;
            *n - 1
        };
        let (tx, rx) = mpsc::channel::<Result<pb::GatewayCommand, Status>>(16);
        let log = self.log.clone();
        let script = self.script.clone();
        tokio::spawn(async move {
            let mut first = true;
            let mut index = 0usize;
            let mut seq = 0u64;
            let mut announced = "";
            while let Ok(Some(msg)) = inbound.message().await {
                let kind = msg.kind;
                if first {
                    first = false;
                    match kind {
                        Some(pb::edge_message::Kind::Hello(h)) => {
                            log.lock().unwrap().hellos.push(h);
                            continue;
                        }
                        other => log
                            .lock()
                            .unwrap()
                            .protocol_errors
                            .push(format!("first message was not a hello: {other:?}")),
                    }
                    continue;
                }
                match kind {
                    Some(pb::edge_message::Kind::Frame(f)) => {
                        let stamp = f.frame.as_ref().map(|f| f.stamp).unwrap_or(f64::NAN);
                        log.lock().unwrap().frames.push((attach_no, f));
                        let reply = script(attach_no, index, stamp);
                        index += 1;
                        // (seq, stamp, linear, angular, idle, mission, announce it as the gateway does)
                        let numbered = match reply {
                            Reply::Command { stamp: s, linear, angular, idle } => {
                                seq += 1;
                                Some((seq, s, linear, angular, idle, if idle { "" } else { "m-test" }, true))
                            }
                            Reply::Numbered { seq: n, stamp: s, linear } => {
                                Some((n, s, linear, 0.0, false, "m-test", true))
                            }
                            Reply::Unannounced { mission, linear } => {
                                seq += 1;
                                Some((seq, stamp, linear, 0.0, false, mission, false))
                            }
                            Reply::Silence => None,
                        };
                        if let Some((seq, s, linear, angular, idle, mission, announce)) = numbered {
                            log.lock().unwrap().answered.push((stamp, s));
                            if announce && mission != announced {
                                announced = mission;
                                let a = pb::GatewayCommand {
                                    kind: Some(pb::gateway_command::Kind::Mission(pb::MissionAnnouncement {
                                        mission_id: mission.into(),
                                        stamp: s,
                                    })),
                                };
                                if tx.send(Ok(a)).await.is_err() {
                                    break;
                                }
                            }
                            let cmd = pb::GatewayCommand {
                                kind: Some(pb::gateway_command::Kind::Velocity(pb::VelocityCommand {
                                    seq,
                                    stamp: s,
                                    twist: Some(pb::Twist2D { linear, angular }),
                                    idle,
                                    mission_id: mission.into(),
                                })),
                            };
                            if tx.send(Ok(cmd)).await.is_err() {
                                break;
                            }
                        }
                    }
                    Some(pb::edge_message::Kind::Odometry(o)) => log.lock().unwrap().odometry.push(o),
                    Some(pb::edge_message::Kind::Status(s)) => log.lock().unwrap().statuses.push(s),
                    Some(pb::edge_message::Kind::Hello(_)) => {
                        log.lock().unwrap().protocol_errors.push("second hello".into())
                    }
                    None => {}
                }
            }
        });
        Ok(Response::new(Box::pin(tokio_stream::wrappers::ReceiverStream::new(rx))))
    }

    async fn list_robots(&self, _: Request<pb::ListRobotsRequest>) -> Result<Response<pb::ListRobotsResponse>, Status> {
        Ok(Response::new(pb::ListRobotsResponse { robots: vec![] }))
    }
}

/// Starts the scripted gateway on 127.0.0.1:0; returns its URI and log.
pub async fn start(script: Script, shutdown: CancellationToken) -> (String, Arc<Mutex<Log>>) {
    let gw = ScriptedGateway { log: Arc::default(), script, attaches: Arc::default() };
    let log = gw.log.clone();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let svc = FleetServiceServer::new(gw).max_decoding_message_size(64 << 20).max_encoding_message_size(64 << 20);
    let set = ServiceSet::new().add("fleet", svc);
    tokio::spawn(async move {
        let _ = vlnav_runtime::serve(&ServerConfig::default(), listener, set, shutdown).await;
    });
    (format!("http://{addr}"), log)
}

/// Answers every frame with the given twist and the frame's own stamp.
pub fn answer_all(linear: f64, angular: f64) -> Script {
    Arc::new(move |_, _, stamp| Reply::Command { stamp, linear, angular, idle: false })
}
