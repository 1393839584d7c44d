//! Clients of the stage services. Every call carries the caller's trace
//! context (the runtime's traced channel), so stage spans join the mission's trace.

use std::sync::{Arc, Mutex, PoisonError};

use vlnav_proto::v1::{
    FrameInputs, detector_service_client::DetectorServiceClient, ingress_service_client::IngressServiceClient,
    local_planner_service_client::LocalPlannerServiceClient, planner_service_client::PlannerServiceClient,
    reid_service_client::ReidServiceClient, segmenter_service_client::SegmenterServiceClient,
    subgoal_service_client::SubgoalServiceClient,
};
use vlnav_runtime::client::{TracedChannel, channel_with};
use vlnav_runtime::security::ClientSecurity;

use crate::config::GatewayOptions;

#[derive(Clone)]
pub(crate) struct Pipeline {
    pub(crate) ingress: IngressServiceClient<TracedChannel>,
    pub(crate) planner: PlannerServiceClient<TracedChannel>,
    pub(crate) detector: DetectorServiceClient<TracedChannel>,
    pub(crate) reid: ReidServiceClient<TracedChannel>,
    pub(crate) segmenter: SegmenterServiceClient<TracedChannel>,
    pub(crate) subgoal: SubgoalServiceClient<TracedChannel>,
    pub(crate) local_planner: LocalPlannerServiceClient<TracedChannel>,
    /// The deadline of each call the executor makes (`--stage-timeout-s`).
    pub(crate) stage_timeout: std::time::Duration,
    /// What the detector and the segmenter read of a frame, as they said.
    pub(crate) detector_inputs: KnownInputs,
    pub(crate) segmenter_inputs: KnownInputs,
}

/// The parts of a frame a stage reads (`FrameInputs`), as the stage said
/// when first asked, shared by every robot's executor; `None` until then.
/// The gateway sends the stage only those parts (docs/architecture.md,
/// "Frames").
#[derive(Clone, Debug, Default)]
pub(crate) struct KnownInputs(Arc<Mutex<Option<FrameInputs>>>);

impl KnownInputs {
    pub(crate) fn get(&self) -> Option<FrameInputs> {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    pub(crate) fn set(&self, inputs: Option<FrameInputs>) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = inputs;
    }
}

/// Frames are large; allow what a 4096² RGB-D frame needs.
const MAX_MESSAGE: usize = 128 * 1024 * 1024;

/// A stage client over a lazily connecting traced channel to `$uri`, with
/// the frame-sized message limits.
macro_rules! stage_client {
    ($client:ident, $uri:expr, $security:expr) => {{
        let uri: &str = $uri;
        $client::new(channel_with(uri, $security).map_err(|e| anyhow::anyhow!("bad service address {uri}: {e}"))?)
            .max_decoding_message_size(MAX_MESSAGE)
            .max_encoding_message_size(MAX_MESSAGE)
    }};
}

impl Pipeline {
    /// Lazily connecting clients: services may start after the gateway.
    pub(crate) fn connect(opts: &GatewayOptions) -> anyhow::Result<Self> {
        let security = ClientSecurity::new(opts.stage_tls.load()?, None);
        let s = &security;
        Ok(Self {
            ingress: stage_client!(IngressServiceClient, &opts.ingress_uri, s),
            planner: stage_client!(PlannerServiceClient, &opts.planner_uri, s),
            detector: stage_client!(DetectorServiceClient, &opts.detector_uri, s),
            reid: stage_client!(ReidServiceClient, &opts.reid_uri, s),
            segmenter: stage_client!(SegmenterServiceClient, &opts.segmenter_uri, s),
            subgoal: stage_client!(SubgoalServiceClient, &opts.subgoal_uri, s),
            local_planner: stage_client!(LocalPlannerServiceClient, &opts.local_planner_uri, s),
            stage_timeout: std::time::Duration::from_secs_f64(opts.stage_timeout_s),
            detector_inputs: KnownInputs::default(),
            segmenter_inputs: KnownInputs::default(),
        })
    }
}
