//! The segmenter actor: owns the backend and the point settings; runs on its
//! own thread (a 640×480 frame is a few milliseconds of CPU work).

use tokio::sync::{mpsc, oneshot};
use vlnav_geometry::camera::Camera;
use vlnav_runtime::actor::Mailbox;

use crate::segment::{FrameView, PointSettings, SegmentBackend, SegmentError, Segmentation, SemanticLabels, segment};

/// A request with its buffers owned (they cross threads).
pub struct SegmentJob {
    pub camera: Camera,
    pub rgb: Vec<u8>,
    pub depth_mm: Vec<u16>,
    pub semantics: Option<SemanticLabels>,
    pub classes: Option<Vec<String>>,
    /// 0: the service default, scaled to the frame's width ([`scaled_stride`]).
    pub point_stride: usize,
}

pub enum Msg {
    Segment { job: SegmentJob, reply: oneshot::Sender<Result<Segmentation, SegmentError>> },
}

/// The service's default stride (`--segmenter-point-stride`, every n-th
/// pixel of a 640-wide frame) scaled to a frame's width: a 160×120 frame
/// taken every 4th pixel would keep one pixel in 16 of a cable one pixel
/// wide, and the cable's end would be known only to 4 pixels (14 cm at 3 m).
pub use vlnav_geometry::camera::{STRIDE_REFERENCE_WIDTH, scaled_stride};

pub struct SegmenterActor {
    backend: Box<dyn SegmentBackend>,
    settings: PointSettings,
    default_stride: usize,
}

impl SegmenterActor {
    pub fn new(backend: Box<dyn SegmentBackend>, settings: PointSettings, default_stride: usize) -> Self {
        Self { backend, settings, default_stride }
    }

    pub fn spawn(self) -> Mailbox<Msg> {
        let (mailbox, rx) = Mailbox::channel("segmenter", 32);
        std::thread::Builder::new()
            .name("segmenter-actor".into())
            .spawn(move || self.run(rx))
            .expect("spawn the segmenter actor");
        mailbox
    }

    fn run(self, mut rx: mpsc::Receiver<Msg>) {
        while let Some(Msg::Segment { job, reply }) = rx.blocking_recv() {
            let _ = reply.send(self.handle(&job));
        }
    }

    pub fn handle(&self, job: &SegmentJob) -> Result<Segmentation, SegmentError> {
        let frame =
            FrameView { camera: job.camera, rgb: &job.rgb, depth_mm: &job.depth_mm, semantics: job.semantics.as_ref() };
        let stride =
            if job.point_stride == 0 { scaled_stride(self.default_stride, job.camera.width) } else { job.point_stride };
        segment(self.backend.as_ref(), &frame, job.classes.as_deref(), stride, &self.settings)
    }
}

#[cfg(test)]
mod tests {
    use super::scaled_stride;

    #[test]
    fn the_default_stride_keeps_the_point_spacing_of_a_640_wide_frame() {
        assert_eq!(scaled_stride(4, 640), 4);
        assert_eq!(scaled_stride(4, 1280), 8);
        assert_eq!(scaled_stride(4, 320), 2);
        assert_eq!(scaled_stride(4, 160), 1);
        assert_eq!(scaled_stride(4, 16), 1, "never less than every pixel");
        assert_eq!(scaled_stride(1, 640), 1);
    }
}
