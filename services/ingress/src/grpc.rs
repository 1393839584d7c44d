//! The tonic layer of `vlnav.v1.IngressService`: validates requests,
//! assembles the audio stream, hands speech to the actor and maps every
//! failure once to a gRPC status.

use std::sync::Arc;
use std::time::Duration;

use tonic::{Request, Response, Status, Streaming};
use vlnav_proto::v1::ingress_service_server::IngressService;
use vlnav_proto::v1::{AudioChunk, AudioFormat, NormalizeTextRequest, NormalizeTextResponse, Transcript};
use vlnav_runtime::actor::{ActorGone, Mailbox};

use crate::actor::Request as ActorRequest;
use crate::input::{AudioAssembler, Encoding, InputError};
use crate::text::{MAX_INSTRUCTION_CHARS, normalize_instruction};
use crate::trim::TrimConfig;
use crate::whisper::ModelError;

/// Limits and settings the handlers apply.
#[derive(Clone, Debug)]
pub struct Settings {
    pub max_audio_s: f64,
    pub chunk_timeout: Duration,
    pub trim: TrimConfig,
    pub model_name: String,
}

#[derive(Debug, thiserror::Error)]
pub enum IngressError {
    #[error("{field}: {message}")]
    InvalidField { field: &'static str, message: String },
    #[error("the audio stream carried no AudioChunk; send at least one chunk with format and data")]
    NoChunks,
    #[error("data: {0}")]
    Input(#[from] InputError),
    #[error("no audio chunk arrived for {waited_s:.1} s after {received_bytes} bytes; the upload stopped mid-way")]
    Stalled { waited_s: f64, received_bytes: usize },
    #[error("the client's audio stream failed after {received_bytes} bytes: {status}")]
    ClientStream { received_bytes: usize, status: String, code: tonic::Code },
    #[error("data: no words recognised in {seconds:.1} s of sound")]
    NothingRecognised { seconds: f64 },
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(transparent)]
    Actor(#[from] ActorGone),
}

impl From<IngressError> for Status {
    fn from(e: IngressError) -> Self {
        let msg = e.to_string();
        match e {
            IngressError::InvalidField { .. }
            | IngressError::NoChunks
            | IngressError::Input(_)
            | IngressError::NothingRecognised { .. } => Status::invalid_argument(msg),
            IngressError::Stalled { .. } => Status::deadline_exceeded(msg),
            // A message that does not decode (tonic reports it as INTERNAL) is the caller's
            // mistake; a size limit keeps its code; a stream cut off was cancelled.
            IngressError::ClientStream { code: tonic::Code::Internal, .. } => Status::invalid_argument(msg),
            IngressError::ClientStream {
                code: code @ (tonic::Code::OutOfRange | tonic::Code::ResourceExhausted),
                ..
            } => Status::new(code, msg),
            IngressError::ClientStream { .. } => Status::cancelled(msg),
            IngressError::Model(ModelError::Missing(_)) => Status::failed_precondition(msg),
            IngressError::Model(_) => Status::internal(msg),
            IngressError::Actor(_) => Status::unavailable(msg),
        }
    }
}

pub struct IngressApi {
    mailbox: Mailbox<ActorRequest>,
    settings: Arc<Settings>,
}

impl IngressApi {
    pub fn new(mailbox: Mailbox<ActorRequest>, settings: Settings) -> Self {
        Self { mailbox, settings: Arc::new(settings) }
    }

    async fn next_chunk(
        &self,
        stream: &mut Streaming<AudioChunk>,
        received_bytes: usize,
    ) -> Result<Option<AudioChunk>, IngressError> {
        match tokio::time::timeout(self.settings.chunk_timeout, stream.message()).await {
            Err(_) => {
                Err(IngressError::Stalled { waited_s: self.settings.chunk_timeout.as_secs_f64(), received_bytes })
            }
            Ok(Err(status)) => Err(IngressError::ClientStream {
                received_bytes,
                status: status.message().to_string(),
                code: status.code(),
            }),
            Ok(Ok(chunk)) => Ok(chunk),
        }
    }

    async fn transcribe_stream(&self, mut stream: Streaming<AudioChunk>) -> Result<Transcript, IngressError> {
        let first = self.next_chunk(&mut stream, 0).await?.ok_or(IngressError::NoChunks)?;
        let format = AudioFormat::try_from(first.format).map_err(|_| IngressError::InvalidField {
            field: "format",
            message: format!("unknown audio format {}; use AUDIO_FORMAT_PCM16_MONO or AUDIO_FORMAT_WAV", first.format),
        })?;
        let encoding = match format {
            AudioFormat::Unspecified => {
                return Err(IngressError::InvalidField {
                    field: "format",
                    message: "the first chunk must name the format: AUDIO_FORMAT_PCM16_MONO (with sample_rate) or AUDIO_FORMAT_WAV".into(),
                });
            }
            AudioFormat::Pcm16Mono => Encoding::Pcm16Mono { sample_rate: first.sample_rate },
            AudioFormat::Wav => Encoding::Wav,
        };
        let mut assembler = AudioAssembler::new(encoding, self.settings.max_audio_s).map_err(|e| match e {
            InputError::Audio(a) => IngressError::InvalidField {
                field: "sample_rate",
                message: format!("{a} (required for AUDIO_FORMAT_PCM16_MONO; 16000 is what Whisper hears)"),
            },
            other => other.into(),
        })?;
        assembler.push(&first.data)?;
        let mut index = 1usize;
        while let Some(chunk) = self.next_chunk(&mut stream, assembler.received_bytes()).await? {
            if chunk.format != 0 && chunk.format != first.format {
                return Err(IngressError::InvalidField {
                    field: "format",
                    message: format!(
                        "chunk {index} says format {} but the stream began as {}; later chunks may leave format unset",
                        chunk.format, first.format
                    ),
                });
            }
            assembler.push(&chunk.data)?;
            index += 1;
        }

        let trim = self.settings.trim;
        let speech = tokio::task::spawn_blocking(move || assembler.finish(&trim))
            .await
            .map_err(|e| ModelError::Inference(candle_core::Error::Msg(format!("audio preparation failed: {e}"))))??;
        let seconds = speech.seconds();
        let recognition = self.mailbox.call(|reply| ActorRequest::Recognize { speech, reply }).await??;
        let text = normalize_instruction(&recognition.text);
        if text.is_empty() {
            return Err(IngressError::NothingRecognised { seconds });
        }
        tracing::info!(seconds, tokens = recognition.tokens, windows = recognition.windows, %text, "transcribed");
        Ok(Transcript { text, audio_seconds: seconds, model: self.settings.model_name.clone() })
    }
}

/// Validates and normalises one typed instruction.
pub fn normalize_request(text: &str) -> Result<String, IngressError> {
    if text.chars().count() > 4 * MAX_INSTRUCTION_CHARS {
        return Err(IngressError::InvalidField {
            field: "text",
            message: format!("{} characters; an instruction has at most {MAX_INSTRUCTION_CHARS}", text.chars().count()),
        });
    }
    let normalized = normalize_instruction(text);
    if normalized.is_empty() {
        return Err(IngressError::InvalidField {
            field: "text",
            message:
                "empty after normalisation (only whitespace, control or invisible characters); type the instruction"
                    .into(),
        });
    }
    let n = normalized.chars().count();
    if n > MAX_INSTRUCTION_CHARS {
        return Err(IngressError::InvalidField {
            field: "text",
            message: format!("{n} characters; an instruction has at most {MAX_INSTRUCTION_CHARS}"),
        });
    }
    Ok(normalized)
}

#[tonic::async_trait]
impl IngressService for IngressApi {
    async fn transcribe(&self, request: Request<Streaming<AudioChunk>>) -> Result<Response<Transcript>, Status> {
        let transcript = self.transcribe_stream(request.into_inner()).await.map_err(|e| {
            tracing::warn!(error = %e, "transcription refused");
            Status::from(e)
        })?;
        Ok(Response::new(transcript))
    }

    async fn normalize_text(
        &self,
        request: Request<NormalizeTextRequest>,
    ) -> Result<Response<NormalizeTextResponse>, Status> {
        let text = normalize_request(&request.into_inner().text)?;
        Ok(Response::new(NormalizeTextResponse { text }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_map_to_the_documented_codes() {
        let code = |e: IngressError| Status::from(e).code();
        assert_eq!(code(IngressError::NoChunks), tonic::Code::InvalidArgument);
        assert_eq!(code(InputError::TooLong { seconds: 61.0, limit_s: 60.0 }.into()), tonic::Code::InvalidArgument);
        assert_eq!(code(IngressError::Stalled { waited_s: 1.0, received_bytes: 0 }), tonic::Code::DeadlineExceeded);
        assert_eq!(code(ModelError::Missing("m".into()).into()), tonic::Code::FailedPrecondition);
        assert_eq!(code(ActorGone("ingress").into()), tonic::Code::Unavailable);
        // A chunk that does not decode is the caller's mistake (found by fuzzing: it was CANCELLED).
        let stream = |code| IngressError::ClientStream { received_bytes: 0, status: "failed to decode".into(), code };
        assert_eq!(code(stream(tonic::Code::Internal)), tonic::Code::InvalidArgument);
        assert_eq!(code(stream(tonic::Code::OutOfRange)), tonic::Code::OutOfRange);
        assert_eq!(code(stream(tonic::Code::Cancelled)), tonic::Code::Cancelled);
        let too_long = Status::from(IngressError::from(InputError::TooLong { seconds: 75.0, limit_s: 60.0 }));
        assert_eq!(too_long.message(), "data: the audio is 75.0 s long; at most 60 s is accepted");
    }

    #[test]
    fn typed_text_is_checked_after_normalisation() {
        assert_eq!(normalize_request("  Move  4 m ahead ,then stop ").unwrap(), "Move 4 m ahead, then stop");
        let err = normalize_request(" \u{200B}\n ").unwrap_err().to_string();
        assert!(err.starts_with("text: empty"), "{err}");
        assert!(normalize_request(&"go ".repeat(2_000)).unwrap_err().to_string().starts_with("text: "));
    }
}
