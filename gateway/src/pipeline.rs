//! Clients of the stage services. Every call carries the caller's trace
//! context (the runtime's traced channel), so stage spans join the mission's trace.

use vlnav_proto::v1::{
    detector_service_client::DetectorServiceClient, ingress_service_client::IngressServiceClient,
    local_planner_service_client::LocalPlannerServiceClient, planner_service_client::PlannerServiceClient,
    reid_service_client::ReidServiceClient, segmenter_service_client::SegmenterServiceClient,
    subgoal_service_client::SubgoalServiceClient,
};
use vlnav_runtime::client::{TracedChannel, channel};

use crate::config::GatewayOptions;

#[derive(Clone)]
pub struct Pipeline {
    pub ingress: IngressServiceClient<TracedChannel>,
    pub planner: PlannerServiceClient<TracedChannel>,
    pub detector: DetectorServiceClient<TracedChannel>,
    pub reid: ReidServiceClient<TracedChannel>,
    pub segmenter: SegmenterServiceClient<TracedChannel>,
    pub subgoal: SubgoalServiceClient<TracedChannel>,
    pub local_planner: LocalPlannerServiceClient<TracedChannel>,
}

/// Frames are large; allow what a 4096² RGB-D frame needs.
const MAX_MESSAGE: usize = 128 * 1024 * 1024;

impl Pipeline {
    /// Lazily connecting clients: services may start after the gateway.
    pub fn connect(opts: &GatewayOptions) -> anyhow::Result<Self> {
        let ch = |uri: &str| channel(uri).map_err(|e| anyhow::anyhow!("bad service address {uri}: {e}"));
        Ok(Self {
            ingress: IngressServiceClient::new(ch(&opts.ingress_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            planner: PlannerServiceClient::new(ch(&opts.planner_uri)?),
            detector: DetectorServiceClient::new(ch(&opts.detector_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            reid: ReidServiceClient::new(ch(&opts.reid_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            segmenter: SegmenterServiceClient::new(ch(&opts.segmenter_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            subgoal: SubgoalServiceClient::new(ch(&opts.subgoal_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
            local_planner: LocalPlannerServiceClient::new(ch(&opts.local_planner_uri)?)
                .max_decoding_message_size(MAX_MESSAGE)
                .max_encoding_message_size(MAX_MESSAGE),
        })
    }
}
