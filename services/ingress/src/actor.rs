//! The actor that owns the Whisper model. Recognition is seconds of CPU
//! work, so the actor runs on its own OS thread rather than on the async
//! runtime; requests queue in its mailbox and are served one at a time.
//! A request whose caller has gone (client cancelled, deadline passed) is
//! skipped, and one in progress stops at the next token.

use std::panic::AssertUnwindSafe;

use tokio::sync::oneshot;
use vlnav_runtime::actor::Mailbox;

use crate::input::Speech;
use crate::whisper::{ModelError, Recognition, SpeechRecognizer};

/// Requests queued at most; further callers wait for space.
pub const MAILBOX_CAPACITY: usize = 16;

pub enum Request {
    Recognize { speech: Speech, reply: oneshot::Sender<Result<Recognition, ModelError>> },
}

/// Starts the actor thread; it ends when every mailbox handle is dropped.
pub fn spawn(mut recognizer: SpeechRecognizer) -> std::io::Result<Mailbox<Request>> {
    let (mailbox, mut inbox) = Mailbox::channel("ingress", MAILBOX_CAPACITY);
    std::thread::Builder::new().name("ingress-whisper".into()).spawn(move || {
        while let Some(request) = inbox.blocking_recv() {
            match request {
                Request::Recognize { speech, reply } => {
                    if reply.is_closed() {
                        continue;
                    }
                    let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
                        recognizer.recognize(&speech.samples, &mut || !reply.is_closed())
                    }));
                    let result = outcome.unwrap_or_else(|panic| {
                        let what = panic
                            .downcast_ref::<&str>()
                            .map(|s| s.to_string())
                            .or_else(|| panic.downcast_ref::<String>().cloned())
                            .unwrap_or_else(|| "unknown panic".into());
                        tracing::error!(%what, "Whisper recognition panicked");
                        Err(ModelError::Inference(candle_core::Error::Msg(format!("recognition panicked: {what}"))))
                    });
                    let _ = reply.send(result);
                }
            }
        }
    })?;
    Ok(mailbox)
}
