//! The task that owns every target track. Box depths are measured before the
//! request reaches it; the actor only fuses, so it never waits on pixels.

use tokio::sync::{mpsc, oneshot};
use vlnav_runtime::actor::Mailbox;

use crate::tracks::{Observation, TargetEstimate, TrackParams, Tracks};

pub enum Msg {
    Observe {
        key: String,
        obs: Observation,
        reply: oneshot::Sender<TargetEstimate>,
    },
    /// Replies whether the track existed.
    Reset {
        key: String,
        reply: oneshot::Sender<bool>,
    },
}

/// Spawns the track actor and returns its mailbox.
pub fn spawn(params: TrackParams) -> Mailbox<Msg> {
    let (mailbox, rx) = Mailbox::channel("subgoal", 256);
    tokio::spawn(run(Tracks::new(params), rx));
    mailbox
}

async fn run(mut tracks: Tracks, mut rx: mpsc::Receiver<Msg>) {
    while let Some(msg) = rx.recv().await {
        match msg {
            Msg::Observe { key, obs, reply } => {
                let _ = reply.send(tracks.observe(&key, &obs));
            }
            Msg::Reset { key, reply } => {
                let _ = reply.send(tracks.reset(&key));
            }
        }
    }
}
