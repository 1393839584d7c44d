//! `vlnav profile <mission-id>`: mission → trace id (gateway) → spans (span
//! files of the built-in receiver, or Jaeger) → report.

use std::path::PathBuf;

use anyhow::Context as _;
use vlnav_proto::v1::GetMissionRequest;
use vlnav_proto::v1::mission_service_client::MissionServiceClient;

use crate::profile::{CONTROL_CYCLE, profile};
use crate::span::{Span, normalize_trace_id};
use crate::store::{SpanStore, dedup_sorted};

/// Default span directory of the receiver `vlnav up` runs (relative to the
/// working directory).
pub const DEFAULT_SPANS_DIR: &str = ".vlnav/traces";

/// Arguments of `vlnav profile`.
#[derive(clap::Args, Clone, Debug)]
pub struct ProfileArgs {
    /// The mission whose trace to profile.
    pub mission_id: String,
    /// Gateway to ask for the mission's trace id.
    #[arg(long, env = "VLNAV_GATEWAY", default_value = "https://127.0.0.1:50051")]
    pub gateway: String,
    /// The CA and token to call it with (a viewer's token is enough).
    #[command(flatten)]
    pub caller: vlnav_runtime::security::CallerArgs,
    /// Span directory written by the OTLP receiver of `vlnav up`.
    #[arg(long, env = "VLNAV_SPANS_DIR", default_value = DEFAULT_SPANS_DIR)]
    pub spans_dir: PathBuf,
    /// Read spans from Jaeger's query API instead (e.g. http://127.0.0.1:16686).
    #[arg(long, env = "VLNAV_JAEGER_URL")]
    pub jaeger: Option<String>,
    /// Use this trace id instead of asking the gateway.
    #[arg(long)]
    pub trace_id: Option<String>,
    /// Span name of one control cycle (frame in → command out).
    #[arg(long, default_value = CONTROL_CYCLE)]
    pub cycle_span: String,
}

/// Where a trace's spans are read from.
#[derive(Clone, Debug)]
pub enum SpanSource {
    Dir(PathBuf),
    Jaeger(String),
}

impl ProfileArgs {
    pub fn source(&self) -> SpanSource {
        match &self.jaeger {
            Some(url) => SpanSource::Jaeger(url.clone()),
            None => SpanSource::Dir(self.spans_dir.clone()),
        }
    }
}

/// Asks the gateway (`MissionService.GetMission`) for a mission's trace id.
pub async fn mission_trace_id(
    gateway: &str,
    caller: &vlnav_runtime::security::ClientSecurity,
    mission_id: &str,
) -> anyhow::Result<String> {
    let channel = vlnav_runtime::client::channel_with(gateway, caller)
        .with_context(|| format!("invalid gateway address {gateway:?}"))?;
    let mut client = MissionServiceClient::new(channel);
    let mission = client
        .get_mission(GetMissionRequest { mission_id: mission_id.to_string() })
        .await
        .map_err(|status| match status.code() {
            tonic::Code::NotFound => {
                anyhow::anyhow!("gateway {gateway} knows no mission {mission_id:?}: {}", status.message())
            }
            tonic::Code::Unavailable => anyhow::anyhow!(
                "cannot reach the gateway at {gateway} ({}); start it (`vlnav up`) or pass --gateway",
                status.message()
            ),
            _ => anyhow::anyhow!("gateway {gateway}: GetMission({mission_id:?}) failed: {status}"),
        })?
        .into_inner();
    if mission.trace_id.trim().is_empty() {
        anyhow::bail!("mission {mission_id} has no trace id (the gateway recorded none for it)");
    }
    normalize_trace_id(&mission.trace_id)
        .with_context(|| format!("gateway returned a bad trace id for mission {mission_id}"))
}

/// Reads every span of `trace_id` from `source`.
pub async fn read_spans(source: &SpanSource, trace_id: &str) -> anyhow::Result<Vec<Span>> {
    match source {
        SpanSource::Jaeger(url) => Ok(dedup_sorted(crate::jaeger::fetch_trace(url, trace_id).await?)),
        SpanSource::Dir(dir) => {
            if !dir.is_dir() {
                anyhow::bail!(
                    "span directory {} does not exist: run `vlnav up` (its OTLP receiver writes there) or pass --spans-dir / --jaeger",
                    dir.display()
                );
            }
            let spans = dedup_sorted(crate::store::read_trace(dir, trace_id)?);
            if spans.is_empty() {
                anyhow::bail!(
                    "no spans of trace {trace_id} in {} (spans are exported in batches: wait a few seconds after the mission, and check that OTEL_EXPORTER_OTLP_ENDPOINT points at the receiver)",
                    SpanStore::trace_file(dir, trace_id)?.display()
                );
            }
            Ok(spans)
        }
    }
}

/// Profiles one trace from `source` and returns the report.
pub async fn profile_trace(source: &SpanSource, trace_id: &str, cycle_span: &str) -> anyhow::Result<String> {
    let trace_id = normalize_trace_id(trace_id)?;
    let spans = read_spans(source, &trace_id).await?;
    Ok(profile(&trace_id, &spans, cycle_span).report())
}

/// The whole of `vlnav profile`: the mission's trace id from the gateway
/// (or `--trace-id`), its spans, the report.
pub async fn run_profile(args: ProfileArgs) -> anyhow::Result<String> {
    let trace_id = match &args.trace_id {
        Some(t) => normalize_trace_id(t)?,
        None => mission_trace_id(&args.gateway, &args.caller.load()?, &args.mission_id).await?,
    };
    let report = profile_trace(&args.source(), &trace_id, &args.cycle_span).await?;
    Ok(format!("mission {}\n{report}", args.mission_id))
}
