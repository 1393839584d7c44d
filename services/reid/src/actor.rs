//! The ReID actor: owns the network and the gallery (and its file). Runs on
//! its own thread because a forward pass is CPU-bound work that must not
//! stall the async runtime; requests queue in its mailbox.

use std::path::PathBuf;

use image::RgbImage;
use tokio::sync::{mpsc, oneshot};
use vlnav_runtime::actor::Mailbox;

use crate::embedder::Embedder;
use crate::gallery::{Gallery, GalleryError};
use crate::preprocess::CropBox;
use crate::sim::{Labels, drawn_similarity, identity_under_box};
use vlnav_runtime::perception::{Draws, ReidModel};

/// What the actor runs on.
pub enum Backend {
    /// A real appearance network.
    Appearance(Embedder),
    /// Identities read from the simulator's label image: the truth (oracle,
    /// `None`) or similarities drawn from a measured model (realistic).
    Simulation(Option<SimReid>),
}

/// The realistic simulation backend's model and seed.
#[derive(Clone, Debug)]
pub struct SimReid {
    pub model: ReidModel,
    pub seed: u64,
}

impl Backend {
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Appearance(e) => e.kind().name(),
            Backend::Simulation(_) => "sim",
        }
    }
}

/// Everything that can go wrong, mapped once to a gRPC status in `grpc.rs`.
#[derive(Debug, thiserror::Error)]
pub enum ReidError {
    #[error("{0}")]
    InvalidArgument(String),
    #[error("the gallery is empty: enroll people with EnrollPerson first")]
    EmptyGallery,
    #[error("{0:?} is not in the gallery (see ListGallery)")]
    UnknownPerson(String),
    #[error("the simulation backend computes no appearance embeddings; run --reid-backend mobilenetv2 or osnet_*")]
    NoEmbeddings,
    #[error("model inference failed: {0}")]
    Model(#[from] candle_core::Error),
    #[error(transparent)]
    Gallery(#[from] GalleryError),
}

/// One person box's verdict.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    pub box_index: usize,
    /// Best candidate (empty if nobody could be scored).
    pub name: String,
    pub similarity: f32,
    pub matched: bool,
}

/// An identification request in domain terms.
pub struct IdentifyQuery {
    pub image: Option<RgbImage>,
    pub labels: Option<Labels>,
    /// Boxes clipped to the frame, with their index in the request.
    pub boxes: Vec<(usize, CropBox)>,
    /// Minimum similarity; `None` for the service default.
    pub threshold: Option<f32>,
    pub only: Option<String>,
    /// Hash of the robot id and the frame's seq (the realistic simulation's draws).
    pub robot: u64,
    pub seq: u64,
}

pub struct EnrollOutcome {
    pub embeddings: u32,
    pub gallery_size: u32,
}

pub enum Msg {
    Enroll { name: String, images: Vec<RgbImage>, reply: oneshot::Sender<Result<EnrollOutcome, ReidError>> },
    Identify { query: IdentifyQuery, reply: oneshot::Sender<Result<Vec<Verdict>, ReidError>> },
    Embed { images: Vec<RgbImage>, reply: oneshot::Sender<Result<Vec<Vec<f32>>, ReidError>> },
    List { reply: oneshot::Sender<Vec<(String, u32)>> },
    Remove { name: String, reply: oneshot::Sender<Result<Vec<(String, u32)>, ReidError>> },
}

pub struct ReidActor {
    backend: Backend,
    gallery: Gallery,
    gallery_path: PathBuf,
    default_threshold: f32,
}

impl ReidActor {
    pub fn new(backend: Backend, gallery: Gallery, gallery_path: PathBuf, default_threshold: f32) -> Self {
        Self { backend, gallery, gallery_path, default_threshold }
    }

    /// Starts the actor on a dedicated thread; it stops when every mailbox is dropped.
    pub fn spawn(self) -> Mailbox<Msg> {
        let (mailbox, rx) = Mailbox::channel("reid", 64);
        std::thread::Builder::new()
            .name("reid-actor".into())
            .spawn(move || self.run(rx))
            .expect("spawn the reid actor");
        mailbox
    }

    fn run(mut self, mut rx: mpsc::Receiver<Msg>) {
        while let Some(msg) = rx.blocking_recv() {
            match msg {
                Msg::Enroll { name, images, reply } => {
                    let _ = reply.send(self.enroll(&name, &images));
                }
                Msg::Identify { query, reply } => {
                    let _ = reply.send(self.identify(query));
                }
                Msg::Embed { images, reply } => {
                    let _ = reply.send(self.embed(&images));
                }
                Msg::List { reply } => {
                    let _ = reply.send(self.gallery.list());
                }
                Msg::Remove { name, reply } => {
                    let _ = reply.send(self.remove(&name));
                }
            }
        }
    }

    /// Applies `change` to a copy, persists it, and only then makes it current,
    /// so a failed write leaves memory and disk in agreement.
    fn commit(&mut self, change: impl FnOnce(&mut Gallery)) -> Result<(), ReidError> {
        let mut next = self.gallery.clone();
        change(&mut next);
        next.save(&self.gallery_path)?;
        self.gallery = next;
        Ok(())
    }

    fn enroll(&mut self, name: &str, images: &[RgbImage]) -> Result<EnrollOutcome, ReidError> {
        let embeddings = match &self.backend {
            Backend::Appearance(e) => e.embed_images(images)?,
            Backend::Simulation(_) => Vec::new(),
        };
        let mut kept = 0;
        self.commit(|g| kept = g.enroll(name, images.len() as u32, embeddings))?;
        let person = &self.gallery.people[name];
        let count = if kept == 0 { person.images } else { kept as u32 };
        Ok(EnrollOutcome { embeddings: count, gallery_size: self.gallery.people.len() as u32 })
    }

    fn remove(&mut self, name: &str) -> Result<Vec<(String, u32)>, ReidError> {
        if !self.gallery.contains(name) {
            return Err(ReidError::UnknownPerson(name.to_string()));
        }
        self.commit(|g| {
            g.remove(name);
        })?;
        Ok(self.gallery.list())
    }

    fn embed(&self, images: &[RgbImage]) -> Result<Vec<Vec<f32>>, ReidError> {
        match &self.backend {
            Backend::Appearance(e) => Ok(e.embed_images(images)?),
            Backend::Simulation(_) => Err(ReidError::NoEmbeddings),
        }
    }

    fn identify(&self, q: IdentifyQuery) -> Result<Vec<Verdict>, ReidError> {
        if self.gallery.is_empty() {
            return Err(ReidError::EmptyGallery);
        }
        if let Some(name) = &q.only
            && !self.gallery.contains(name)
        {
            return Err(ReidError::UnknownPerson(name.clone()));
        }
        let threshold = q.threshold.unwrap_or(self.default_threshold);
        let verdict = |box_index: usize, name: String, similarity: f32| {
            let matched = !name.is_empty() && similarity >= threshold;
            Verdict { box_index, name: if matched { name } else { String::new() }, similarity, matched }
        };
        match &self.backend {
            Backend::Appearance(embedder) => {
                let image = q.image.as_ref().ok_or_else(|| {
                    ReidError::InvalidArgument("frame.rgb: the appearance backend needs the colour image".into())
                })?;
                let regions: Vec<CropBox> = q.boxes.iter().map(|(_, b)| *b).collect();
                let embeddings = embedder.embed_regions(image, &regions)?;
                Ok(q.boxes
                    .iter()
                    .zip(embeddings)
                    .map(|((i, _), e)| match self.gallery.best_match(&e, q.only.as_deref()) {
                        Some(m) => verdict(*i, m.name, m.similarity),
                        None => verdict(*i, String::new(), 0.0),
                    })
                    .collect())
            }
            Backend::Simulation(sim) => {
                let labels = q.labels.as_ref().ok_or_else(|| {
                    ReidError::InvalidArgument(
                        "frame.labels: the simulation backend reads identities from the label image, and this frame has none".into(),
                    )
                })?;
                if let Some(sim) = sim {
                    let draws = Draws::new(sim.seed, q.robot, q.seq);
                    return Ok(q
                        .boxes
                        .iter()
                        .map(|(i, b)| {
                            let truth = identity_under_box(labels, *b);
                            let best = self
                                .gallery
                                .people
                                .keys()
                                .filter(|name| q.only.as_deref().is_none_or(|o| o == name.as_str()))
                                .map(|name| (drawn_similarity(&sim.model, &draws, *i, truth.as_ref(), name), name))
                                .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(a.1)));
                            match best {
                                Some((s, name)) => verdict(*i, name.clone(), s),
                                None => verdict(*i, String::new(), 0.0),
                            }
                        })
                        .collect());
                }
                Ok(q.boxes
                    .iter()
                    .map(|(i, b)| match identity_under_box(labels, *b) {
                        Some(l)
                            if self.gallery.contains(&l.identity)
                                && q.only.as_deref().is_none_or(|o| o == l.identity) =>
                        {
                            verdict(*i, l.identity, l.purity)
                        }
                        _ => verdict(*i, String::new(), 0.0),
                    })
                    .collect())
            }
        }
    }
}
