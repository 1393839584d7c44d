//! The thin tonic layer: validate the frame, convert proto → domain, ask the
//! actor, convert back. Errors are mapped to gRPC status codes in one place.

use tonic::{Request, Response, Status};
use vlnav_geometry::camera::Camera;
use vlnav_geometry::convert::{
    DepthDefaults, InvalidField, camera_from_proto, depth_from_proto, encoded_image_from_proto, label_ids_from_proto,
};
use vlnav_geometry::rgb::decode_off_thread;
use vlnav_proto::v1::{
    self, GetSegmenterInfoRequest, Point3, SegmentRequest, SegmentResponse, SegmenterInfo,
    segmenter_service_server::SegmenterService,
};
use vlnav_runtime::actor::{ActorGone, Mailbox};

use crate::actor::{Msg, SegmentJob};
use crate::segment::{Reads, SegmentError, SemanticLabels};

/// Largest accepted point stride.
const MAX_STRIDE: u32 = 1024;

/// Everything that can go wrong in a Segment call, mapped once to a status.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Invalid(#[from] InvalidField),
    #[error(transparent)]
    Segment(#[from] SegmentError),
    #[error(transparent)]
    Gone(#[from] ActorGone),
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        match e {
            ServiceError::Invalid(_) | ServiceError::Segment(SegmentError::InvalidInput(_)) => {
                Status::invalid_argument(e.to_string())
            }
            ServiceError::Gone(g) => g.into(),
        }
    }
}

/// What the service says about its backend.
#[derive(Clone, Debug)]
pub struct BackendInfo {
    pub name: &'static str,
    pub classes: Vec<String>,
    pub reads: Reads,
}

pub struct SegmenterGrpc {
    actor: Mailbox<Msg>,
    info: BackendInfo,
}

impl SegmenterGrpc {
    pub fn new(actor: Mailbox<Msg>, info: BackendInfo) -> Self {
        Self { actor, info }
    }
}

/// The colour image as RGB8 of exactly the camera's size (decoded off the async threads).
async fn rgb(frame: &v1::RgbdFrame, camera: &Camera) -> Result<Vec<u8>, ServiceError> {
    let field = "frame.rgb";
    let img = frame.rgb.as_ref().ok_or_else(|| InvalidField::new(field, "is required (RGB8, PNG or JPEG)"))?;
    let encoded = encoded_image_from_proto(img).map_err(|e| e.in_field(field))?;
    let decoded = decode_off_thread(encoded).await.map_err(|e| e.in_field(field))?;
    let (w, h) = (camera.width, camera.height);
    if decoded.dimensions() != (w, h) {
        let (iw, ih) = decoded.dimensions();
        return Err(InvalidField::new(field, format!("the image is {iw}×{ih} but frame.camera says {w}×{h}")).into());
    }
    Ok(decoded.into_raw())
}

fn semantics(frame: &v1::RgbdFrame, camera: &Camera) -> Result<Option<SemanticLabels>, InvalidField> {
    let Some(l) = frame.labels.as_ref().filter(|l| !l.instance_ids.is_empty()) else { return Ok(None) };
    Ok(Some(SemanticLabels {
        ids: label_ids_from_proto(l, camera.width, camera.height, "frame.labels")?,
        semantic: l.instances.iter().map(|i| (i.instance_id, i.semantic.clone())).collect(),
    }))
}

impl SegmenterGrpc {
    async fn segment_inner(&self, req: SegmentRequest) -> Result<SegmentResponse, ServiceError> {
        let frame = req.frame.as_ref().ok_or_else(|| InvalidField::new("frame", "is required"))?;
        // Depth bounds left at 0 stay unset: the floor check then takes every return.
        let camera = camera_from_proto(frame.camera.as_ref(), "frame.camera", DepthDefaults::UNSET)?;
        if req.point_stride > MAX_STRIDE {
            return Err(
                InvalidField::new("point_stride", format!("at most {MAX_STRIDE}, got {}", req.point_stride)).into()
            );
        }
        // Only what the backend reads is decoded (and required).
        let reads = self.info.reads;
        let job = SegmentJob {
            camera,
            rgb: if reads.rgb { rgb(frame, &camera).await? } else { Vec::new() },
            depth_mm: depth_from_proto(frame.depth.as_ref(), &camera, "frame.depth")?.to_mm(),
            semantics: if reads.labels { semantics(frame, &camera)? } else { None },
            classes: if req.classes.is_empty() { None } else { Some(req.classes.clone()) },
            point_stride: req.point_stride as usize,
        };
        let seg = self.actor.call(|reply| Msg::Segment { job, reply }).await??;
        Ok(SegmentResponse {
            mask: if req.return_mask { seg.mask.into() } else { Default::default() },
            width: camera.width,
            height: camera.height,
            classes: seg.classes,
            virtual_points: seg.points.into_iter().map(|[x, y, z]| Point3 { x, y, z }).collect(),
            class_pixels: seg.class_pixels,
            backend: self.info.name.to_string(),
        })
    }
}

#[tonic::async_trait]
impl SegmenterService for SegmenterGrpc {
    async fn segment(&self, req: Request<SegmentRequest>) -> Result<Response<SegmentResponse>, Status> {
        Ok(Response::new(self.segment_inner(req.into_inner()).await?))
    }

    async fn get_segmenter_info(&self, _: Request<GetSegmenterInfoRequest>) -> Result<Response<SegmenterInfo>, Status> {
        let reads = self.info.reads;
        Ok(Response::new(SegmenterInfo {
            backend: self.info.name.to_string(),
            classes: self.info.classes.clone(),
            inputs: Some(v1::FrameInputs { rgb: reads.rgb, depth: true, labels: reads.labels }),
        }))
    }
}
