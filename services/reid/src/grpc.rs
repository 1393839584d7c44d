//! The thin tonic layer: validate, convert proto ↔ domain, ask the actor.

use std::collections::HashMap;

use image::RgbImage;
use tonic::{Request, Response, Status};
use vlnav_proto::v1::{
    self, EmbedRequest, EmbedResponse, Embedding, EnrollPersonRequest, EnrollPersonResponse, GalleryEntry,
    IdentifyRequest, IdentifyResponse, Identity, ImageEncoding, ListGalleryRequest, ListGalleryResponse,
    RemovePersonRequest, reid_service_server::ReidService,
};
use vlnav_runtime::actor::Mailbox;

use crate::actor::{IdentifyQuery, Msg, ReidError};
use crate::preprocess::CropBox;
use crate::sim::{LabelledInstance, Labels};

/// Longest accepted person name, bytes.
const MAX_NAME_LEN: usize = 64;
/// Most images or boxes in one request.
const MAX_ITEMS: usize = 256;
/// Largest decoded image side, pixels.
const MAX_SIDE: u32 = 8192;

impl From<ReidError> for Status {
    fn from(e: ReidError) -> Self {
        let msg = e.to_string();
        match e {
            ReidError::InvalidArgument(_) => Status::invalid_argument(msg),
            ReidError::EmptyGallery | ReidError::NoEmbeddings => Status::failed_precondition(msg),
            ReidError::UnknownPerson(_) => Status::not_found(msg),
            ReidError::Model(_) | ReidError::Gallery(_) => Status::internal(msg),
        }
    }
}

pub struct ReidGrpc {
    actor: Mailbox<Msg>,
    model: &'static str,
}

impl ReidGrpc {
    pub fn new(actor: Mailbox<Msg>, model: &'static str) -> Self {
        Self { actor, model }
    }
}

fn invalid(msg: impl Into<String>) -> Status {
    Status::invalid_argument(msg.into())
}

fn check_name(name: &str, field: &str) -> Result<String, Status> {
    let n = name.trim();
    if n.is_empty() {
        return Err(invalid(format!("{field}: a person's name is required")));
    }
    if n.len() > MAX_NAME_LEN || n.chars().any(char::is_control) {
        return Err(invalid(format!("{field}: at most {MAX_NAME_LEN} bytes of printable text")));
    }
    Ok(n.to_string())
}

/// Decodes an `Image` into RGB8, checking its declared size.
pub fn decode_image(img: &v1::Image, field: &str) -> Result<RgbImage, Status> {
    let encoding = ImageEncoding::try_from(img.encoding).unwrap_or(ImageEncoding::Unspecified);
    let (w, h) = (img.width, img.height);
    if w > MAX_SIDE || h > MAX_SIDE {
        return Err(invalid(format!("{field}: {w}×{h} exceeds {MAX_SIDE} pixels a side")));
    }
    let decoded = match encoding {
        ImageEncoding::Rgb8 => {
            if w == 0 || h == 0 {
                return Err(invalid(format!("{field}: width and height are required for RGB8")));
            }
            let want = w as usize * h as usize * 3;
            if img.data.len() != want {
                return Err(invalid(format!(
                    "{field}.data: RGB8 {w}×{h} needs {want} bytes (3 channels), got {}{}",
                    img.data.len(),
                    if img.data.len() == w as usize * h as usize * 4 { " — that is 4 channels (RGBA)" } else { "" }
                )));
            }
            return Ok(RgbImage::from_raw(w, h, img.data.clone()).expect("length checked"));
        }
        ImageEncoding::Png | ImageEncoding::Jpeg => {
            let format =
                if encoding == ImageEncoding::Png { image::ImageFormat::Png } else { image::ImageFormat::Jpeg };
            image::load_from_memory_with_format(&img.data, format)
                .map_err(|e| invalid(format!("{field}.data: not a readable {format:?} image: {e}")))?
                .to_rgb8()
        }
        ImageEncoding::Unspecified => {
            return Err(invalid(format!("{field}.encoding: set RGB8, PNG or JPEG")));
        }
    };
    if (w != 0 && w != decoded.width()) || (h != 0 && h != decoded.height()) {
        return Err(invalid(format!(
            "{field}: declared {w}×{h} but the image is {}×{}",
            decoded.width(),
            decoded.height()
        )));
    }
    Ok(decoded)
}

fn decode_images(images: &[v1::Image], field: &str) -> Result<Vec<RgbImage>, Status> {
    if images.is_empty() {
        return Err(invalid(format!("{field}: at least one image is required")));
    }
    if images.len() > MAX_ITEMS {
        return Err(invalid(format!("{field}: at most {MAX_ITEMS} images per request")));
    }
    images.iter().enumerate().map(|(i, im)| decode_image(im, &format!("{field}[{i}]"))).collect()
}

fn decode_labels(l: &v1::LabelImage, width: u32, height: u32) -> Result<Labels, Status> {
    if l.width != width || l.height != height {
        return Err(invalid(format!(
            "frame.labels: {}×{} does not match the frame's {width}×{height}",
            l.width, l.height
        )));
    }
    let want = width as usize * height as usize * 2;
    if l.instance_ids.len() != want {
        return Err(invalid(format!(
            "frame.labels.instance_ids: {width}×{height} u16 ids need {want} bytes, got {}",
            l.instance_ids.len()
        )));
    }
    let ids = l.instance_ids.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
    let instances: HashMap<u32, LabelledInstance> = l
        .instances
        .iter()
        .map(|i| (i.instance_id, LabelledInstance { class_id: i.class_id, identity: i.identity.clone() }))
        .collect();
    Ok(Labels { width, height, ids, instances })
}

/// The frame's size: from the colour image, else the labels, else the camera info.
fn frame_size(frame: &v1::RgbdFrame, image: Option<&RgbImage>) -> Option<(u32, u32)> {
    if let Some(i) = image {
        return Some((i.width(), i.height()));
    }
    if let Some(l) = frame.labels.as_ref().filter(|l| l.width > 0 && l.height > 0) {
        return Some((l.width, l.height));
    }
    frame.camera.as_ref().filter(|c| c.width > 0 && c.height > 0).map(|c| (c.width, c.height))
}

fn check_box(b: &v1::BoundingBox, i: usize, width: u32, height: u32) -> Result<CropBox, Status> {
    let field = format!("boxes[{i}]");
    let c = CropBox { x_min: b.x_min, y_min: b.y_min, x_max: b.x_max, y_max: b.y_max };
    if ![c.x_min, c.y_min, c.x_max, c.y_max].iter().all(|v| v.is_finite()) {
        return Err(invalid(format!("{field}: coordinates must be finite")));
    }
    if c.x_max <= c.x_min || c.y_max <= c.y_min {
        return Err(invalid(format!("{field}: x_max > x_min and y_max > y_min are required")));
    }
    c.clip(width, height).ok_or_else(|| {
        invalid(format!(
            "{field}: ({}, {})–({}, {}) covers less than a pixel of the {width}×{height} frame",
            c.x_min, c.y_min, c.x_max, c.y_max
        ))
    })
}

#[tonic::async_trait]
impl ReidService for ReidGrpc {
    async fn enroll_person(&self, req: Request<EnrollPersonRequest>) -> Result<Response<EnrollPersonResponse>, Status> {
        let req = req.into_inner();
        let name = check_name(&req.name, "name")?;
        let images = decode_images(&req.images, "images")?;
        let n = name.clone();
        let out = self.actor.call(|reply| Msg::Enroll { name: n, images, reply }).await??;
        tracing::info!(%name, embeddings = out.embeddings, gallery_size = out.gallery_size, "enrolled");
        Ok(Response::new(EnrollPersonResponse { name, embeddings: out.embeddings, gallery_size: out.gallery_size }))
    }

    async fn identify(&self, req: Request<IdentifyRequest>) -> Result<Response<IdentifyResponse>, Status> {
        let req = req.into_inner();
        let frame = req.frame.as_ref().ok_or_else(|| invalid("frame: required"))?;
        let threshold = if req.threshold == 0.0 {
            None
        } else if req.threshold.is_finite() && (-1.0..=1.0).contains(&req.threshold) {
            Some(req.threshold)
        } else {
            return Err(invalid(format!(
                "threshold: a cosine similarity in [-1, 1] (0 = default), got {}",
                req.threshold
            )));
        };
        let only = if req.name.trim().is_empty() { None } else { Some(check_name(&req.name, "name")?) };
        if req.boxes.len() > MAX_ITEMS {
            return Err(invalid(format!("boxes: at most {MAX_ITEMS} per request")));
        }
        let image = match &frame.rgb {
            Some(rgb) if !rgb.data.is_empty() => Some(decode_image(rgb, "frame.rgb")?),
            _ => None,
        };
        let (width, height) = frame_size(frame, image.as_ref())
            .ok_or_else(|| invalid("frame: carries neither an rgb image nor labels to read the boxes from"))?;
        let labels = match &frame.labels {
            Some(l) if !l.instance_ids.is_empty() => Some(decode_labels(l, width, height)?),
            _ => None,
        };
        let boxes = req
            .boxes
            .iter()
            .enumerate()
            .map(|(i, b)| check_box(b, i, width, height).map(|c| (i, c)))
            .collect::<Result<Vec<_>, _>>()?;
        let robot = vlnav_runtime::perception::hash_str(&frame.robot_id);
        let query = IdentifyQuery { image, labels, boxes, threshold, only, robot, seq: frame.seq };
        let verdicts = self.actor.call(|reply| Msg::Identify { query, reply }).await??;
        Ok(Response::new(IdentifyResponse {
            identities: verdicts
                .into_iter()
                .map(|v| Identity {
                    box_index: v.box_index as u32,
                    name: v.name,
                    similarity: v.similarity,
                    matched: v.matched,
                })
                .collect(),
        }))
    }

    async fn embed(&self, req: Request<EmbedRequest>) -> Result<Response<EmbedResponse>, Status> {
        let images = decode_images(&req.into_inner().images, "images")?;
        let embeddings = self.actor.call(|reply| Msg::Embed { images, reply }).await??;
        Ok(Response::new(EmbedResponse {
            embeddings: embeddings.into_iter().map(|values| Embedding { values }).collect(),
            model: self.model.to_string(),
        }))
    }

    async fn list_gallery(&self, _req: Request<ListGalleryRequest>) -> Result<Response<ListGalleryResponse>, Status> {
        let people = self.actor.call(|reply| Msg::List { reply }).await?;
        Ok(Response::new(listing(people)))
    }

    async fn remove_person(&self, req: Request<RemovePersonRequest>) -> Result<Response<ListGalleryResponse>, Status> {
        let name = check_name(&req.into_inner().name, "name")?;
        let people = self.actor.call(|reply| Msg::Remove { name, reply }).await??;
        Ok(Response::new(listing(people)))
    }
}

fn listing(people: Vec<(String, u32)>) -> ListGalleryResponse {
    ListGalleryResponse {
        people: people.into_iter().map(|(name, embeddings)| GalleryEntry { name, embeddings }).collect(),
    }
}
