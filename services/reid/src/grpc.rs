//! The thin tonic layer: validate, convert proto ↔ domain, ask the actor.
//! Errors are mapped to gRPC status codes in one place.

use std::collections::HashMap;

use image::RgbImage;
use tonic::{Request, Response, Status};
use vlnav_geometry::convert::{InvalidField, encoded_image_from_proto, label_ids_from_proto};
use vlnav_geometry::rgb::{decode_all_off_thread, decode_off_thread};
use vlnav_proto::v1::{
    self, EmbedRequest, EmbedResponse, Embedding, EnrollPersonRequest, EnrollPersonResponse, GalleryEntry,
    IdentifyRequest, IdentifyResponse, Identity, ListGalleryRequest, ListGalleryResponse, RemovePersonRequest,
    reid_service_server::ReidService,
};
use vlnav_runtime::actor::{ActorGone, Mailbox};

use crate::actor::{IdentifyQuery, Msg, ReidError};
use crate::preprocess::CropBox;
use crate::sim::{LabelledInstance, Labels};

/// Longest accepted person name, bytes.
const MAX_NAME_LEN: usize = 64;
/// Most images or boxes in one request.
const MAX_ITEMS: usize = 256;

/// Everything that can go wrong in a ReID call, mapped once to a status.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    #[error(transparent)]
    Invalid(#[from] InvalidField),
    #[error(transparent)]
    Reid(#[from] ReidError),
    #[error(transparent)]
    Gone(#[from] ActorGone),
}

impl From<ServiceError> for Status {
    fn from(e: ServiceError) -> Self {
        let msg = e.to_string();
        match e {
            ServiceError::Invalid(_) | ServiceError::Reid(ReidError::InvalidArgument(_)) => {
                Status::invalid_argument(msg)
            }
            ServiceError::Reid(ReidError::EmptyGallery | ReidError::NoEmbeddings) => Status::failed_precondition(msg),
            ServiceError::Reid(ReidError::UnknownPerson(_)) => Status::not_found(msg),
            ServiceError::Reid(ReidError::Model(_) | ReidError::Gallery(_)) => Status::internal(msg),
            ServiceError::Gone(g) => g.into(),
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

fn check_name(name: &str, field: &str) -> Result<String, InvalidField> {
    let n = name.trim();
    if n.is_empty() {
        return Err(InvalidField::new(field, "a person's name is required"));
    }
    if n.len() > MAX_NAME_LEN || n.chars().any(char::is_control) {
        return Err(InvalidField::new(field, format!("at most {MAX_NAME_LEN} bytes of printable text")));
    }
    Ok(n.to_string())
}

/// Decodes one image off the async threads.
async fn decode_image(img: &v1::Image, field: &str) -> Result<RgbImage, InvalidField> {
    let encoded = encoded_image_from_proto(img).map_err(|e| e.in_field(field))?;
    decode_off_thread(encoded).await.map_err(|e| e.in_field(field))
}

/// Decodes `images` (1 to [`MAX_ITEMS`]) off the async threads.
async fn decode_images(images: &[v1::Image], field: &str) -> Result<Vec<RgbImage>, InvalidField> {
    if images.is_empty() {
        return Err(InvalidField::new(field, "at least one image is required"));
    }
    if images.len() > MAX_ITEMS {
        return Err(InvalidField::new(field, format!("at most {MAX_ITEMS} images per request")));
    }
    let encoded = images
        .iter()
        .enumerate()
        .map(|(i, im)| encoded_image_from_proto(im).map_err(|e| e.in_field(&format!("{field}[{i}]"))))
        .collect::<Result<Vec<_>, _>>()?;
    decode_all_off_thread(encoded).await.map_err(|(i, e)| e.in_field(&format!("{field}[{i}]")))
}

fn decode_labels(l: &v1::LabelImage, width: u32, height: u32) -> Result<Labels, InvalidField> {
    let ids = label_ids_from_proto(l, width, height, "frame.labels")?;
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

fn check_box(b: &v1::BoundingBox, i: usize, width: u32, height: u32) -> Result<CropBox, InvalidField> {
    let field = format!("boxes[{i}]");
    let c = CropBox { x_min: b.x_min, y_min: b.y_min, x_max: b.x_max, y_max: b.y_max };
    if ![c.x_min, c.y_min, c.x_max, c.y_max].iter().all(|v| v.is_finite()) {
        return Err(InvalidField::new(field, "coordinates must be finite"));
    }
    if c.x_max <= c.x_min || c.y_max <= c.y_min {
        return Err(InvalidField::new(field, "x_max > x_min and y_max > y_min are required"));
    }
    c.clip(width, height).ok_or_else(|| {
        InvalidField::new(
            field,
            format!(
                "({}, {})–({}, {}) covers less than a pixel of the {width}×{height} frame",
                c.x_min, c.y_min, c.x_max, c.y_max
            ),
        )
    })
}

impl ReidGrpc {
    async fn enroll_inner(&self, req: EnrollPersonRequest) -> Result<EnrollPersonResponse, ServiceError> {
        let name = check_name(&req.name, "name")?;
        let images = decode_images(&req.images, "images").await?;
        let n = name.clone();
        let out = self.actor.call(|reply| Msg::Enroll { name: n, images, reply }).await??;
        tracing::info!(%name, embeddings = out.embeddings, gallery_size = out.gallery_size, "enrolled");
        Ok(EnrollPersonResponse { name, embeddings: out.embeddings, gallery_size: out.gallery_size })
    }

    async fn identify_inner(&self, req: IdentifyRequest) -> Result<IdentifyResponse, ServiceError> {
        let frame = req.frame.as_ref().ok_or_else(|| InvalidField::new("frame", "is required"))?;
        let threshold = if req.threshold == 0.0 {
            None
        } else if req.threshold.is_finite() && (-1.0..=1.0).contains(&req.threshold) {
            Some(req.threshold)
        } else {
            return Err(InvalidField::new(
                "threshold",
                format!("a cosine similarity in [-1, 1] (0 = default), got {}", req.threshold),
            )
            .into());
        };
        let only = if req.name.trim().is_empty() { None } else { Some(check_name(&req.name, "name")?) };
        if req.boxes.len() > MAX_ITEMS {
            return Err(InvalidField::new("boxes", format!("at most {MAX_ITEMS} per request")).into());
        }
        let image = match &frame.rgb {
            Some(rgb) if !rgb.data.is_empty() => Some(decode_image(rgb, "frame.rgb").await?),
            _ => None,
        };
        let (width, height) = frame_size(frame, image.as_ref()).ok_or_else(|| {
            InvalidField::new("frame", "carries neither an rgb image nor labels to read the boxes from")
        })?;
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
        Ok(IdentifyResponse {
            identities: verdicts
                .into_iter()
                .map(|v| Identity {
                    box_index: v.box_index as u32,
                    name: v.name,
                    similarity: v.similarity,
                    matched: v.matched,
                })
                .collect(),
        })
    }

    async fn embed_inner(&self, req: EmbedRequest) -> Result<EmbedResponse, ServiceError> {
        let images = decode_images(&req.images, "images").await?;
        let embeddings = self.actor.call(|reply| Msg::Embed { images, reply }).await??;
        Ok(EmbedResponse {
            embeddings: embeddings.into_iter().map(|values| Embedding { values }).collect(),
            model: self.model.to_string(),
        })
    }

    async fn remove_inner(&self, req: RemovePersonRequest) -> Result<ListGalleryResponse, ServiceError> {
        let name = check_name(&req.name, "name")?;
        let people = self.actor.call(|reply| Msg::Remove { name, reply }).await??;
        Ok(listing(people))
    }
}

#[tonic::async_trait]
impl ReidService for ReidGrpc {
    async fn enroll_person(&self, req: Request<EnrollPersonRequest>) -> Result<Response<EnrollPersonResponse>, Status> {
        Ok(Response::new(self.enroll_inner(req.into_inner()).await?))
    }

    async fn identify(&self, req: Request<IdentifyRequest>) -> Result<Response<IdentifyResponse>, Status> {
        Ok(Response::new(self.identify_inner(req.into_inner()).await?))
    }

    async fn embed(&self, req: Request<EmbedRequest>) -> Result<Response<EmbedResponse>, Status> {
        Ok(Response::new(self.embed_inner(req.into_inner()).await?))
    }

    async fn list_gallery(&self, _req: Request<ListGalleryRequest>) -> Result<Response<ListGalleryResponse>, Status> {
        let people = self.actor.call(|reply| Msg::List { reply }).await.map_err(ServiceError::from)?;
        Ok(Response::new(listing(people)))
    }

    async fn remove_person(&self, req: Request<RemovePersonRequest>) -> Result<Response<ListGalleryResponse>, Status> {
        Ok(Response::new(self.remove_inner(req.into_inner()).await?))
    }
}

fn listing(people: Vec<(String, u32)>) -> ListGalleryResponse {
    ListGalleryResponse {
        people: people.into_iter().map(|(name, embeddings)| GalleryEntry { name, embeddings }).collect(),
    }
}
