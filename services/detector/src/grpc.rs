//! The tonic layer: validate a request, convert proto → domain, ask the
//! actor, convert back. Errors are mapped to gRPC status codes in one place.

use tonic::{Request, Response, Status};
use vlnav_geometry::convert::{InvalidField, encoded_image_from_proto};
use vlnav_geometry::rgb::{ImageError, decode_off_thread};
use vlnav_proto::v1::{self, detector_service_server::DetectorService};
use vlnav_runtime::actor::Mailbox;

use crate::actor::{BackendInfo, DetectError, Input, InputKind, Job, Msg};
use crate::classes::Labeled;
use crate::detection::DetectFilter;
use crate::sim::{self, Instance, LabelError, LabeledFrame};

/// Everything that can go wrong in a Detect call, mapped once to a status.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Invalid(#[from] InvalidField),
    #[error(transparent)]
    Detect(#[from] DetectError),
    #[error(transparent)]
    Gone(#[from] vlnav_runtime::actor::ActorGone),
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        match &e {
            ServiceError::Invalid(_) | ServiceError::Detect(DetectError::InvalidArgument(_)) => {
                Status::invalid_argument(e.to_string())
            }
            ServiceError::Detect(DetectError::Internal(_)) => Status::internal(e.to_string()),
            ServiceError::Gone(g) => Status::unavailable(g.to_string()),
        }
    }
}

fn invalid(field: &str, msg: impl Into<String>) -> ServiceError {
    InvalidField::new(field, msg).into()
}

impl From<ImageError> for ServiceError {
    fn from(e: ImageError) -> Self {
        e.in_field("frame.rgb").into()
    }
}

impl From<LabelError> for ServiceError {
    fn from(e: LabelError) -> Self {
        let field = match e {
            LabelError::DepthSize { .. } => "frame.depth",
            LabelError::Length { field: "data_mm", .. } => "frame.depth",
            _ => "frame.labels",
        };
        invalid(field, e.to_string())
    }
}

pub struct DetectorGrpc {
    mailbox: Mailbox<Msg>,
    info: BackendInfo,
    default_min_score: f32,
}

impl DetectorGrpc {
    pub fn new(mailbox: Mailbox<Msg>, info: BackendInfo, default_min_score: f32) -> Self {
        Self { mailbox, info, default_min_score }
    }
}

/// The caller's class and score wishes.
pub fn filter_from_request(
    class_ids: &[i32],
    min_score: f32,
    default_min_score: f32,
) -> Result<DetectFilter, ServiceError> {
    for (i, &c) in class_ids.iter().enumerate() {
        if vlnav_proto::coco::name(c).is_none() {
            return Err(invalid("class_ids", format!("class_ids[{i}] = {c} is not a COCO-80 class id (0–79)")));
        }
    }
    if !(0.0..=1.0).contains(&min_score) {
        return Err(invalid("min_score", format!("{min_score} is outside [0, 1] (0 means the backend's default)")));
    }
    let min_score = if min_score == 0.0 { default_min_score } else { min_score };
    Ok(DetectFilter { class_ids: class_ids.to_vec(), min_score })
}

/// Decodes `frame.rgb` (off the async threads: JPEG decoding takes milliseconds).
async fn rgb_input(frame: &v1::RgbdFrame) -> Result<Input, ServiceError> {
    let rgb = frame.rgb.as_ref().ok_or_else(|| invalid("frame.rgb", "is required by this backend"))?;
    Ok(Input::Rgb(decode_off_thread(encoded_image_from_proto(rgb)?).await?))
}

/// Parses `frame.labels` and, `with_depth`, the aligned `frame.depth`.
pub fn labels_input(frame: &v1::RgbdFrame, with_depth: bool) -> Result<Input, ServiceError> {
    let labels = frame.labels.as_ref().filter(|l| l.width > 0 && l.height > 0).ok_or(LabelError::Missing)?;
    let (width, height) = (labels.width, labels.height);
    let instance_ids = sim::parse_u16_image("instance_ids", width, height, &labels.instance_ids)?;
    let depth_mm = match &frame.depth {
        Some(d) if with_depth && !d.data_mm.is_empty() => {
            if (d.width, d.height) != (width, height) {
                return Err(LabelError::DepthSize { dw: d.width, dh: d.height, width, height }.into());
            }
            sim::parse_u16_image("data_mm", width, height, &d.data_mm)?
        }
        _ => Vec::new(),
    };
    let instances = labels
        .instances
        .iter()
        .map(|i| Instance {
            instance_id: i.instance_id,
            class_id: i.class_id,
            visible_fraction: if i.visible_fraction > 0.0 { i.visible_fraction.min(1.0) } else { 1.0 },
        })
        .collect();
    let robot = crate::error_model::hash_str(&frame.robot_id);
    Ok(Input::Labels(LabeledFrame { robot, seq: frame.seq, width, height, instance_ids, instances, depth_mm }))
}

fn to_proto(l: &Labeled) -> v1::BoundingBox {
    let d = &l.detection;
    v1::BoundingBox {
        x_min: d.x_min,
        y_min: d.y_min,
        x_max: d.x_max,
        y_max: d.y_max,
        class_id: d.class_id,
        score: d.score,
        label: l.label.clone(),
    }
}

impl DetectorGrpc {
    async fn detect_inner(&self, req: v1::DetectRequest) -> Result<v1::DetectResponse, ServiceError> {
        let frame = req.frame.as_ref().ok_or_else(|| invalid("frame", "is required"))?;
        let filter = filter_from_request(&req.class_ids, req.min_score, self.default_min_score)?;
        let input = match self.info.input {
            InputKind::Rgb => rgb_input(frame).await?,
            InputKind::Labels { depth } => labels_input(frame, depth)?,
        };
        let dets = self.mailbox.call(|reply| Msg::Detect { job: Job { input, filter }, reply }).await??;
        Ok(v1::DetectResponse { boxes: dets.iter().map(to_proto).collect(), backend: self.info.backend.to_string() })
    }
}

#[tonic::async_trait]
impl DetectorService for DetectorGrpc {
    async fn detect(&self, request: Request<v1::DetectRequest>) -> Result<Response<v1::DetectResponse>, Status> {
        Ok(Response::new(self.detect_inner(request.into_inner()).await?))
    }

    async fn get_model_info(&self, _: Request<v1::GetModelInfoRequest>) -> Result<Response<v1::ModelInfo>, Status> {
        Ok(Response::new(v1::ModelInfo {
            backend: self.info.backend.to_string(),
            model: self.info.model.clone(),
            input_width: self.info.input_width,
            input_height: self.info.input_height,
            classes: self.info.classes.clone(),
            device: self.info.device.clone(),
            inputs: Some(match self.info.input {
                InputKind::Rgb => v1::FrameInputs { rgb: true, depth: false, labels: false },
                InputKind::Labels { depth } => v1::FrameInputs { rgb: false, depth, labels: true },
            }),
        }))
    }
}
