//! The thin tonic layer of the gateway: validates requests, talks to the
//! mission hub and the robot actors, and maps every failure to a status a
//! person can act on.

use std::pin::Pin;
use std::sync::Arc;

use futures::Stream;
use tokio::sync::{broadcast, mpsc};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use tracing::Instrument;
use vlnav_proto::v1::{
    AnswerClarificationRequest, AnswerClarificationResponse, Audio, AudioChunk, AudioFormat, AuditRecord,
    CancelMissionRequest, ClarificationNeeded, EdgeMessage, Finished, GatewayCommand, GetMissionRequest,
    ListMissionsRequest, ListMissionsResponse, ListRobotsRequest, ListRobotsResponse, Mission, MissionEvent,
    MissionState, PlanReady, PlanRequest, SubmitMissionRequest, SubmitMissionResponse, Transcribed,
    WatchMissionRequest, answer_clarification_response, edge_message,
    fleet_service_server::{FleetService, FleetServiceServer},
    mission_event::Kind,
    mission_service_server::{MissionService, MissionServiceServer},
    plan_response, submit_mission_request, submit_mission_response,
};
use vlnav_runtime::security::{robot_identity, robot_ids_of_peer, valid_robot_id};
use vlnav_runtime::{ServerConfig, ServiceSet};

use crate::auth::{AuthLayer, Caller, TokenStore};

use crate::config::GatewayOptions;
use crate::executor::MissionRun;
use crate::hub::{Hub, is_terminal};
use crate::pipeline::Pipeline;
use crate::robot::Fleet;
use crate::store::Store;

/// Longest accepted typed instruction, bytes.
pub(crate) const MAX_INSTRUCTION_BYTES: usize = 4096;
/// Audio is streamed to ingress in chunks of this size.
const AUDIO_CHUNK: usize = 64 * 1024;

/// The gateway's MissionService and FleetService, over its robots' actors,
/// the mission store and the stage clients.
#[derive(Clone)]
pub struct Gateway {
    fleet: Arc<Fleet>,
    auth: AuthLayer,
    /// Attach needs a client certificate naming the robot (set when the
    /// server verifies client certificates, docs/security.md).
    robot_certs: bool,
    /// Per-caller rate of SubmitMission.
    submissions: Arc<crate::limit::RateLimiter>,
}

impl Gateway {
    /// Opens the mission store in `opts.data_dir`, connects (lazily) to the
    /// stages, reads the token file and starts the live view and recordings.
    pub fn new(opts: &GatewayOptions) -> anyhow::Result<Self> {
        let store = Store::open(&opts.data_dir)?;
        let hub = Hub::open(store)?;
        let pipeline = Pipeline::connect(opts)?;
        let tokens = opts.tokens_file.as_deref().map(TokenStore::open).transpose()?;
        let viz = crate::viz::Viz::start(&opts.view, &opts.data_dir, hub.clone())?;
        Ok(Self {
            fleet: Fleet::new(hub, pipeline, opts.executor.clone(), viz),
            auth: AuthLayer::new(tokens),
            robot_certs: false,
            submissions: Arc::new(crate::limit::RateLimiter::new(opts.submit_per_minute, opts.submit_burst)),
        })
    }

    /// Ends every robot actor and waits (up to 5 s) until nothing else holds
    /// the gateway's state, so its mission store is closed when this returns.
    pub async fn close(self) {
        self.fleet.close();
        // Every frame handed over is written and every recording's file finished.
        let viz = self.fleet.viz().clone();
        let _ = tokio::task::spawn_blocking(move || viz.finish()).await;
        for _ in 0..250 {
            if Arc::strong_count(&self.fleet) <= 1 {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
    }

    /// Where the live view listens (`None`: off).
    pub fn live_view_addr(&self) -> Option<std::net::SocketAddr> {
        self.fleet.viz().live_addr()
    }

    /// Waits until every frame handed to the live view and the recordings is written.
    pub fn flush_view(&self) {
        self.fleet.viz().flush();
    }

    fn hub(&self) -> &Arc<Hub> {
        self.fleet.hub()
    }

    fn pipeline(&self) -> &Pipeline {
        self.fleet.pipeline()
    }

    /// The gateway's server settings on top of `base`: people come with
    /// tokens and robots with certificates, so a client certificate is
    /// checked when presented (Attach needs one) but not required.
    pub fn server_config(base: &ServerConfig) -> ServerConfig {
        ServerConfig { client_cert_optional: true, ..base.clone() }
    }

    /// MissionService and FleetService behind the token layer, ready for
    /// `vlnav_runtime::serve`, with the certificates the gateway answers
    /// ([`crate::auth::caller_policy`]). When `server` verifies client
    /// certificates, a robot attaches only with a certificate naming it.
    pub fn services(&self, server: &ServerConfig) -> ServiceSet {
        let max = server.max_message_bytes;
        let me = Self { robot_certs: server.tls.tls_client_ca.is_some(), ..self.clone() };
        ServiceSet::new()
            .add(
                "mission-api",
                me.auth.wrap(
                    MissionServiceServer::new(me.clone()).max_decoding_message_size(max).max_encoding_message_size(max),
                ),
            )
            .add(
                "fleet",
                me.auth.wrap(
                    FleetServiceServer::new(me.clone()).max_decoding_message_size(max).max_encoding_message_size(max),
                ),
            )
            .callers(crate::auth::caller_policy())
    }

    /// The mission `id`, if `caller` may see it.
    fn mission_for(&self, caller: &Caller, id: &str, what: &str) -> Result<Mission, Status> {
        let mission = self.mission(id)?;
        caller.check_robot(&mission.robot_id, what)?;
        Ok(mission)
    }

    fn audit(&self, id: &str, caller: &Caller, action: &str, detail: String) {
        let record = AuditRecord { action: action.into(), caller: caller.name.clone(), unix_time: unix_now(), detail };
        if let Err(e) = self.hub().record(id, 0.0, None, move |m| m.audit.push(record)) {
            tracing::error!(mission = %id, "cannot record the audit trail: {e}");
        }
    }

    fn mission(&self, id: &str) -> Result<Mission, Status> {
        if id.trim().is_empty() {
            return Err(Status::invalid_argument("mission_id is empty"));
        }
        self.hub()
            .get(id)
            .ok_or_else(|| Status::not_found(format!("no mission with id '{id}'; ListMissions shows the known ones")))
    }

    fn fail(&self, id: &str, reason: String) {
        let finished = Finished { state: MissionState::Failed as i32, reason, metrics: None };
        if let Err(e) = self.hub().record(id, 0.0, Some(Kind::Finished(finished)), |_| {}) {
            tracing::error!(mission = %id, "cannot record failure: {e}");
        }
    }

    async fn transcribe(&self, audio: Audio) -> Result<vlnav_proto::v1::Transcript, Status> {
        let format = audio.format;
        let rate = audio.sample_rate;
        let chunks: Vec<AudioChunk> = audio
            .data
            .chunks(AUDIO_CHUNK)
            .enumerate()
            .map(|(i, c)| AudioChunk {
                format: if i == 0 { format } else { 0 },
                sample_rate: if i == 0 { rate } else { 0 },
                data: c.to_vec().into(),
            })
            .collect();
        let resp = self
            .pipeline()
            .ingress
            .clone()
            .transcribe(tokio_stream::iter(chunks))
            .await
            .map_err(stage_unreachable("ingress"))?;
        Ok(resp.into_inner())
    }

    async fn submit(&self, caller: &Caller, req: SubmitMissionRequest) -> Result<SubmitMissionResponse, Status> {
        let robot_id = req.robot_id.trim().to_string();
        if robot_id.is_empty() && !req.dry_run {
            return Err(Status::invalid_argument("robot_id is empty; ListRobots shows the connected robots"));
        }
        if !robot_id.is_empty() {
            caller.check_robot(&robot_id, "submitting a mission to")?;
        }
        match &req.instruction {
            None => return Err(Status::invalid_argument("the instruction is missing: set `text` or `audio`")),
            Some(submit_mission_request::Instruction::Text(t)) if t.trim().is_empty() => {
                return Err(Status::invalid_argument("the instruction text is empty; say what the robot should do"));
            }
            Some(submit_mission_request::Instruction::Text(t)) if t.len() > MAX_INSTRUCTION_BYTES => {
                return Err(Status::invalid_argument(format!(
                    "the instruction is {} bytes; at most {MAX_INSTRUCTION_BYTES} are accepted",
                    t.len()
                )));
            }
            Some(submit_mission_request::Instruction::Audio(a)) if a.data.is_empty() => {
                return Err(Status::invalid_argument("the audio is empty"));
            }
            Some(submit_mission_request::Instruction::Audio(a))
                if !matches!(AudioFormat::try_from(a.format), Ok(AudioFormat::Wav | AudioFormat::Pcm16Mono)) =>
            {
                return Err(Status::invalid_argument(
                    "audio.format must be AUDIO_FORMAT_WAV or AUDIO_FORMAT_PCM16_MONO",
                ));
            }
            _ => {}
        }
        let mission_id = format!("m-{}", uuid::Uuid::new_v4().simple());
        if !req.dry_run {
            self.fleet.reserve(&robot_id, &mission_id).await?;
        }
        let span =
            tracing::info_span!("mission", mission.id = %mission_id, robot.id = %robot_id, dry_run = req.dry_run);
        let trace_id = {
            use opentelemetry::trace::TraceContextExt;
            use tracing_opentelemetry::OpenTelemetrySpanExt;
            span.context().span().span_context().trace_id().to_string()
        };
        let text = match &req.instruction {
            Some(submit_mission_request::Instruction::Text(t)) => t.trim().to_string(),
            _ => String::new(),
        };
        let now = unix_now();
        let record = Mission {
            mission_id: mission_id.clone(),
            robot_id: robot_id.clone(),
            instruction: text.clone(),
            state: MissionState::Pending as i32,
            dry_run: req.dry_run,
            created_unix: now,
            trace_id,
            submitted_by: caller.name.clone(),
            audit: vec![AuditRecord {
                action: "submit".into(),
                caller: caller.name.clone(),
                unix_time: now,
                detail: String::new(),
            }],
            ..Default::default()
        };
        if let Err(e) = self.hub().create(record) {
            self.fleet.release(&robot_id, &mission_id).await;
            return Err(Status::internal(e.to_string()));
        }
        let result = self.plan_and_start(&mission_id, &robot_id, req, text, span.clone()).instrument(span).await;
        if let Err(status) = &result {
            self.fleet.release(&robot_id, &mission_id).await;
            self.fail(&mission_id, format!("could not be planned: {}", status.message()));
        }
        result
    }

    async fn plan_and_start(
        &self,
        mission_id: &str,
        robot_id: &str,
        req: SubmitMissionRequest,
        mut text: String,
        span: tracing::Span,
    ) -> Result<SubmitMissionResponse, Status> {
        let hub = self.hub();
        if let Some(submit_mission_request::Instruction::Audio(audio)) = req.instruction {
            let transcript = self.transcribe(audio).await?;
            text = transcript.text.trim().to_string();
            let t = text.clone();
            hub.record(
                mission_id,
                0.0,
                Some(Kind::Transcribed(Transcribed {
                    transcript: text.clone(),
                    audio_seconds: transcript.audio_seconds,
                })),
                move |m| m.instruction = t,
            )
            .map_err(|e| Status::internal(e.to_string()))?;
            if text.is_empty() {
                return Err(Status::invalid_argument("no speech was recognised in the audio"));
            }
        }
        let planned = self
            .pipeline()
            .planner
            .clone()
            .plan(PlanRequest { instruction: text.clone(), backend: String::new() })
            .await
            .map_err(stage_unreachable("planner"))?
            .into_inner();
        let mut response = SubmitMissionResponse {
            mission_id: mission_id.to_string(),
            transcript: text.clone(),
            planner_backend: planned.backend.clone(),
            plan_json: planned.plan_json.clone(),
            ..Default::default()
        };
        let (plan, clarification) = match planned.outcome {
            Some(plan_response::Outcome::Plan(p)) => (p, None),
            Some(plan_response::Outcome::Clarification(c)) => (Default::default(), Some(c)),
            None => return Err(Status::internal("the planner returned neither a plan nor a question")),
        };
        let backend = planned.backend.clone();
        let plan_json = planned.plan_json.clone();
        match &clarification {
            None => {
                let (p, pj, b) = (plan.clone(), plan_json.clone(), backend.clone());
                hub.record(
                    mission_id,
                    0.0,
                    Some(Kind::Plan(PlanReady {
                        plan: Some(plan.clone()),
                        plan_json: plan_json.clone(),
                        backend: backend.clone(),
                    })),
                    move |m| {
                        m.plan = Some(p);
                        m.plan_json = pj;
                        m.planner_backend = b;
                    },
                )
            }
            Some(c) => {
                let c2 = c.clone();
                hub.record(
                    mission_id,
                    0.0,
                    Some(Kind::ClarificationNeeded(ClarificationNeeded { index: 0, clarification: Some(c.clone()) })),
                    move |m| {
                        m.clarification = Some(c2);
                        if !m.dry_run {
                            m.state = MissionState::AwaitingClarification as i32;
                        }
                    },
                )
            }
        }
        .map_err(|e| Status::internal(e.to_string()))?;
        if req.dry_run {
            let finished = Finished {
                state: MissionState::Planned as i32,
                reason: if clarification.is_some() {
                    "dry run: the planner needs an answer first".into()
                } else {
                    "dry run: planned and validated, nothing moved".into()
                },
                metrics: None,
            };
            hub.record(mission_id, 0.0, Some(Kind::Finished(finished)), |_| {})
                .map_err(|e| Status::internal(e.to_string()))?;
            response.state = MissionState::Planned as i32;
        } else {
            let run = MissionRun::new(
                mission_id.to_string(),
                robot_id.to_string(),
                text,
                plan.steps.clone(),
                clarification.clone(),
                span,
            );
            self.fleet.start(robot_id, run).await?;
            response.state =
                if clarification.is_some() { MissionState::AwaitingClarification } else { MissionState::Pending }
                    as i32;
        }
        response.outcome = Some(match clarification {
            Some(c) => submit_mission_response::Outcome::Clarification(c),
            None => submit_mission_response::Outcome::Plan(plan),
        });
        Ok(response)
    }
}

type EventStream = Pin<Box<dyn Stream<Item = Result<MissionEvent, Status>> + Send>>;
type CommandStream = ReceiverStream<Result<GatewayCommand, Status>>;

#[tonic::async_trait]
impl MissionService for Gateway {
    async fn submit_mission(
        &self,
        request: Request<SubmitMissionRequest>,
    ) -> Result<Response<SubmitMissionResponse>, Status> {
        let caller = Caller::of(&request);
        // Authenticated callers are limited by name, anonymous ones by address.
        let key = match (self.auth.is_on(), request.remote_addr()) {
            (false, Some(addr)) => format!("the anonymous caller at {}", addr.ip()),
            _ => caller.name.clone(),
        };
        if let Err(wait) = self.submissions.check(&key, std::time::Instant::now()) {
            return Err(Status::resource_exhausted(format!(
                "{key} submitted more than {} missions at once or {:.0} a minute; try again in {wait:.1} s \
                 (the gateway's --submit-per-minute and --submit-burst)",
                self.submissions.burst(),
                self.submissions.per_minute()
            )));
        }
        self.submit(&caller, request.into_inner()).await.map(Response::new)
    }

    type WatchMissionStream = EventStream;

    async fn watch_mission(
        &self,
        request: Request<WatchMissionRequest>,
    ) -> Result<Response<Self::WatchMissionStream>, Status> {
        let caller = Caller::of(&request);
        let id = request.into_inner().mission_id;
        self.mission_for(&caller, &id, "watching missions of")?;
        let watch = self.hub().watch(&id).ok_or_else(|| Status::not_found(format!("no mission with id '{id}'")))?;
        let (tx, rx) = mpsc::channel(64);
        let hub = self.hub().clone();
        tokio::spawn(async move {
            let mut last = 0;
            let is_end = |e: &MissionEvent| matches!(e.kind, Some(Kind::Finished(_)));
            for e in watch.backlog {
                last = e.seq;
                let end = is_end(&e);
                if tx.send(Ok(e)).await.is_err() || end {
                    return;
                }
            }
            if watch.finished {
                return;
            }
            let mut live = watch.live;
            loop {
                let batch = match live.recv().await {
                    Ok(e) if e.seq <= last => continue,
                    Ok(e) if e.seq == last + 1 => vec![e],
                    // Out of order or lagged: read what was missed from the log.
                    Ok(_) | Err(broadcast::error::RecvError::Lagged(_)) => hub.events_after(&id, last),
                    Err(broadcast::error::RecvError::Closed) => return,
                };
                for e in batch {
                    last = e.seq;
                    let end = is_end(&e);
                    if tx.send(Ok(e)).await.is_err() || end {
                        return;
                    }
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn get_mission(&self, request: Request<GetMissionRequest>) -> Result<Response<Mission>, Status> {
        let caller = Caller::of(&request);
        self.mission_for(&caller, &request.into_inner().mission_id, "viewing missions of").map(Response::new)
    }

    async fn list_missions(
        &self,
        request: Request<ListMissionsRequest>,
    ) -> Result<Response<ListMissionsResponse>, Status> {
        let caller = Caller::of(&request);
        let req = request.into_inner();
        let limit = match req.limit {
            0 => 100,
            n => n.min(10_000) as usize,
        };
        let robot = req.robot_id.trim();
        if !robot.is_empty() {
            caller.check_robot(robot, "listing missions of")?;
        }
        let mut missions = self.hub().list(robot, if caller.robots.is_some() { 10_000 } else { limit });
        missions.retain(|m| caller.may_act_on(&m.robot_id));
        missions.truncate(limit);
        Ok(Response::new(ListMissionsResponse { missions }))
    }

    async fn cancel_mission(&self, request: Request<CancelMissionRequest>) -> Result<Response<Mission>, Status> {
        let caller = Caller::of(&request);
        let id = request.into_inner().mission_id;
        let mission = self.mission_for(&caller, &id, "cancelling missions of")?;
        let state = MissionState::try_from(mission.state).unwrap_or(MissionState::Unspecified);
        if is_terminal(state) {
            return Err(Status::failed_precondition(format!(
                "mission {id} has already finished ({}); nothing to cancel",
                state.as_str_name()
            )));
        }
        self.audit(&id, &caller, "cancel", String::new());
        self.fleet.cancel(&mission.robot_id, &id).await?;
        self.mission(&id).map(Response::new)
    }

    async fn answer_clarification(
        &self,
        request: Request<AnswerClarificationRequest>,
    ) -> Result<Response<AnswerClarificationResponse>, Status> {
        let caller = Caller::of(&request);
        let req = request.into_inner();
        let mission = self.mission_for(&caller, &req.mission_id, "answering for missions of")?;
        if mission.state != MissionState::AwaitingClarification as i32 {
            return Err(Status::failed_precondition(format!(
                "mission {} is {}, not waiting for an answer",
                req.mission_id,
                MissionState::try_from(mission.state).unwrap_or_default().as_str_name()
            )));
        }
        if req.answer.trim().is_empty() {
            return Err(Status::invalid_argument("the answer is empty"));
        }
        if req.answer.len() > MAX_INSTRUCTION_BYTES {
            return Err(Status::invalid_argument(format!("the answer is longer than {MAX_INSTRUCTION_BYTES} bytes")));
        }
        self.audit(&req.mission_id, &caller, "answer", req.answer.trim().to_string());
        let outcome = self.fleet.answer(&mission.robot_id, &req.mission_id, req.answer.trim().to_string()).await?;
        let mission = self.mission(&req.mission_id)?;
        let plan_json = mission.plan_json.clone();
        Ok(Response::new(AnswerClarificationResponse {
            mission: Some(mission),
            plan_json,
            outcome: Some(match outcome {
                Ok(steps) => answer_clarification_response::Outcome::Plan(vlnav_proto::v1::ActionPlan { steps }),
                Err(c) => answer_clarification_response::Outcome::Clarification(c),
            }),
        }))
    }
}

fn unix_now() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs_f64()).unwrap_or(0.0)
}

#[tonic::async_trait]
impl FleetService for Gateway {
    type AttachStream = CommandStream;

    async fn attach(&self, request: Request<Streaming<EdgeMessage>>) -> Result<Response<Self::AttachStream>, Status> {
        let certified: Option<Vec<String>> =
            self.robot_certs.then(|| request.peer_certs().map(|c| robot_ids_of_peer(&c)).unwrap_or_default());
        let mut inbound = request.into_inner();
        let hello = match inbound.message().await? {
            Some(EdgeMessage { kind: Some(edge_message::Kind::Hello(h)) }) => h,
            _ => {
                return Err(Status::invalid_argument(
                    "the first message on Attach must be an EdgeHello naming the robot",
                ));
            }
        };
        if !valid_robot_id(&hello.robot_id) {
            return Err(Status::invalid_argument(format!(
                "robot_id '{}' must be 1–64 characters of letters, digits, '-', '_' or '.'",
                hello.robot_id
            )));
        }
        if let Some(ids) = certified
            && !ids.contains(&hello.robot_id)
        {
            tracing::warn!(claimed = %hello.robot_id, certified = ?ids, "attach refused");
            return Err(Status::permission_denied(if ids.is_empty() {
                format!(
                    "robot '{}' must attach with a client certificate naming it ({}); none was presented",
                    hello.robot_id,
                    robot_identity(&hello.robot_id)
                )
            } else {
                format!(
                    "this certificate belongs to robot [{}], not '{}': a robot attaches only as itself",
                    ids.join(", "),
                    hello.robot_id
                )
            }));
        }
        let (tx, rx) = mpsc::channel(16);
        let conn = self.fleet.next_conn();
        let robot = hello.robot_id.clone();
        let mailbox = self.fleet.attach(hello, tx.clone(), conn).await?;
        crate::link::spawn(inbound, robot, conn, mailbox, tx);
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn list_robots(&self, request: Request<ListRobotsRequest>) -> Result<Response<ListRobotsResponse>, Status> {
        let caller = Caller::of(&request);
        let mut robots = self.fleet.list();
        robots.retain(|r| caller.may_act_on(&r.robot_id));
        Ok(Response::new(ListRobotsResponse { robots }))
    }
}

/// A stage call's error as the gateway's caller gets it. When the stage could
/// not be reached or did not answer, the transport's words ("tcp connect
/// error") do not say which service is down: the message names it, as the
/// executor's stage failures do. A server that does not implement the call
/// is a deployment fault (the stage's address points at another server), not
/// the gateway lacking the caller's method: it is INTERNAL and says so. The
/// stage's own answers pass unchanged.
fn stage_unreachable(stage: &'static str) -> impl FnOnce(Status) -> Status {
    move |s| match s.code() {
        tonic::Code::Unavailable | tonic::Code::DeadlineExceeded | tonic::Code::Cancelled | tonic::Code::Unknown => {
            Status::new(s.code(), format!("the {stage} service failed: {}", s.message()))
        }
        tonic::Code::Unimplemented => Status::internal(format!(
            "the server at the {stage} service's address does not implement the {stage} call \
             (check the gateway's --{stage}-uri){}",
            if s.message().is_empty() { String::new() } else { format!(": {}", s.message()) }
        )),
        _ => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unreachable_stage_is_named_and_its_own_answers_pass_unchanged() {
        let down = stage_unreachable("planner")(Status::unavailable("tcp connect error"));
        assert_eq!(down.code(), tonic::Code::Unavailable);
        assert_eq!(down.message(), "the planner service failed: tcp connect error");
        let refused = stage_unreachable("planner")(Status::invalid_argument("the instruction is empty"));
        assert_eq!(refused.message(), "the instruction is empty");
        let elsewhere = stage_unreachable("planner")(Status::unimplemented(""));
        assert_eq!(elsewhere.code(), tonic::Code::Internal);
        assert_eq!(
            elsewhere.message(),
            "the server at the planner service's address does not implement the planner call \
             (check the gateway's --planner-uri)"
        );
    }
}
