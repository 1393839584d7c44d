//! The thin tonic layer: validate the frame, convert proto → domain, ask the
//! actor, convert back.

use tonic::{Request, Response, Status};
use vlnav_proto::v1::{
    self, ImageEncoding, Point3, SegmentRequest, SegmentResponse, segmenter_service_server::SegmenterService,
};
use vlnav_runtime::actor::Mailbox;
use vlnav_subgoal::camera::{Camera, Intrinsics, Mount};

use crate::actor::{Msg, SegmentJob};
use crate::segment::{SegmentError, SemanticLabels};

/// Largest accepted image side, pixels.
const MAX_SIDE: u32 = 8192;
/// Largest accepted point stride.
const MAX_STRIDE: u32 = 1024;

impl From<SegmentError> for Status {
    fn from(e: SegmentError) -> Self {
        match e {
            SegmentError::InvalidInput(m) => Status::invalid_argument(m),
        }
    }
}

pub struct SegmenterGrpc {
    actor: Mailbox<Msg>,
    backend: &'static str,
}

impl SegmenterGrpc {
    pub fn new(actor: Mailbox<Msg>, backend: &'static str) -> Self {
        Self { actor, backend }
    }
}

fn invalid(msg: impl Into<String>) -> Status {
    Status::invalid_argument(msg.into())
}

fn camera(frame: &v1::RgbdFrame) -> Result<Camera, Status> {
    let c = frame.camera.as_ref().ok_or_else(|| invalid("frame.camera: required (intrinsics and mount)"))?;
    if c.width == 0 || c.height == 0 || c.width > MAX_SIDE || c.height > MAX_SIDE {
        return Err(invalid(format!(
            "frame.camera: width and height must be 1–{MAX_SIDE}, got {}×{}",
            c.width, c.height
        )));
    }
    let k = c.intrinsics.as_ref().ok_or_else(|| invalid("frame.camera.intrinsics: required"))?;
    if !(k.fx.is_finite() && k.fy.is_finite() && k.fx > 0.0 && k.fy > 0.0 && k.cx.is_finite() && k.cy.is_finite()) {
        return Err(invalid("frame.camera.intrinsics: fx and fy must be positive, cx and cy finite"));
    }
    let m = c.mount.unwrap_or_default();
    let t = m.translation.unwrap_or_default();
    if ![t.x, t.y, t.z, m.roll, m.pitch, m.yaw].iter().all(|v| v.is_finite()) {
        return Err(invalid("frame.camera.mount: translation and angles must be finite"));
    }
    if !(c.depth_min_m.is_finite() && c.depth_max_m.is_finite()) {
        return Err(invalid("frame.camera: depth_min_m and depth_max_m must be finite"));
    }
    Ok(Camera {
        width: c.width,
        height: c.height,
        intrinsics: Intrinsics { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy },
        mount: Mount { translation: nalgebra::Vector3::new(t.x, t.y, t.z), roll: m.roll, pitch: m.pitch, yaw: m.yaw },
        depth_min_m: c.depth_min_m,
        depth_max_m: c.depth_max_m,
    })
}

/// The colour image as RGB8 of exactly the camera's size.
fn rgb(frame: &v1::RgbdFrame, w: u32, h: u32) -> Result<Vec<u8>, Status> {
    let img = frame.rgb.as_ref().ok_or_else(|| invalid("frame.rgb: required"))?;
    let encoding = ImageEncoding::try_from(img.encoding).unwrap_or(ImageEncoding::Unspecified);
    let (data, iw, ih) = match encoding {
        ImageEncoding::Rgb8 => {
            if (img.width, img.height) != (w, h) {
                return Err(invalid(format!(
                    "frame.rgb: {}×{} does not match frame.camera's {w}×{h}",
                    img.width, img.height
                )));
            }
            let want = w as usize * h as usize * 3;
            if img.data.len() != want {
                let channels = img.data.len() as f64 / (w as usize * h as usize) as f64;
                return Err(invalid(format!(
                    "frame.rgb.data: RGB8 {w}×{h} needs {want} bytes (3 channels), got {} ({channels:.2} bytes per pixel)",
                    img.data.len()
                )));
            }
            (img.data.clone(), w, h)
        }
        ImageEncoding::Png | ImageEncoding::Jpeg => {
            let format =
                if encoding == ImageEncoding::Png { image::ImageFormat::Png } else { image::ImageFormat::Jpeg };
            let d = image::load_from_memory_with_format(&img.data, format)
                .map_err(|e| invalid(format!("frame.rgb.data: not a readable {format:?} image: {e}")))?
                .to_rgb8();
            let (iw, ih) = d.dimensions();
            (d.into_raw(), iw, ih)
        }
        ImageEncoding::Unspecified => return Err(invalid("frame.rgb.encoding: set RGB8, PNG or JPEG")),
    };
    if (iw, ih) != (w, h) {
        return Err(invalid(format!("frame.rgb: the image is {iw}×{ih} but frame.camera says {w}×{h}")));
    }
    Ok(data)
}

fn depth(frame: &v1::RgbdFrame, w: u32, h: u32) -> Result<Vec<u16>, Status> {
    let d = frame.depth.as_ref().ok_or_else(|| invalid("frame.depth: required (floor zones are checked in 3-D)"))?;
    if (d.width, d.height) != (w, h) {
        return Err(invalid(format!(
            "frame.depth: {}×{} does not match the {w}×{h} colour image (depth must be aligned to colour)",
            d.width, d.height
        )));
    }
    let want = w as usize * h as usize * 2;
    if d.data_mm.len() != want {
        return Err(invalid(format!(
            "frame.depth.data_mm: {w}×{h} little-endian u16 needs {want} bytes, got {}",
            d.data_mm.len()
        )));
    }
    Ok(d.data_mm.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect())
}

fn semantics(frame: &v1::RgbdFrame, w: u32, h: u32) -> Result<Option<SemanticLabels>, Status> {
    let Some(l) = frame.labels.as_ref().filter(|l| !l.instance_ids.is_empty()) else { return Ok(None) };
    if (l.width, l.height) != (w, h) {
        return Err(invalid(format!("frame.labels: {}×{} does not match the frame's {w}×{h}", l.width, l.height)));
    }
    if l.instance_ids.len() != w as usize * h as usize * 2 {
        return Err(invalid(format!(
            "frame.labels.instance_ids: {w}×{h} u16 ids need {} bytes, got {}",
            w as usize * h as usize * 2,
            l.instance_ids.len()
        )));
    }
    Ok(Some(SemanticLabels {
        ids: l.instance_ids.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect(),
        semantic: l.instances.iter().map(|i| (i.instance_id, i.semantic.clone())).collect(),
    }))
}

#[tonic::async_trait]
impl SegmenterService for SegmenterGrpc {
    async fn segment(&self, req: Request<SegmentRequest>) -> Result<Response<SegmentResponse>, Status> {
        let req = req.into_inner();
        let frame = req.frame.as_ref().ok_or_else(|| invalid("frame: required"))?;
        let camera = camera(frame)?;
        let (w, h) = (camera.width, camera.height);
        let job = SegmentJob {
            camera,
            rgb: rgb(frame, w, h)?,
            depth_mm: depth(frame, w, h)?,
            semantics: semantics(frame, w, h)?,
            classes: if req.classes.is_empty() { None } else { Some(req.classes.clone()) },
            point_stride: if req.point_stride > MAX_STRIDE {
                return Err(invalid(format!("point_stride: at most {MAX_STRIDE}, got {}", req.point_stride)));
            } else {
                req.point_stride as usize
            },
        };
        let seg = self.actor.call(|reply| Msg::Segment { job, reply }).await??;
        Ok(Response::new(SegmentResponse {
            mask: if req.return_mask { seg.mask } else { Vec::new() },
            width: w,
            height: h,
            classes: seg.classes,
            virtual_points: seg.points.into_iter().map(|[x, y, z]| Point3 { x, y, z }).collect(),
            class_pixels: seg.class_pixels,
            backend: self.backend.to_string(),
        }))
    }
}
