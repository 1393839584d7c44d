//! vlnav-planner: a spoken instruction to a validated action plan behind
//! `vlnav.v1.PlannerService`.
//!
//! Backends (`--backend`, env `VLNAV_PLANNER_BACKEND`; a request may pick
//! another by name):
//! - `rules` (default): the deterministic HTN parser ([`htn`]) with target
//!   grounding by synonyms and all-MiniLM-L6-v2 similarity ([`grounding`]);
//! - `openai`: any OpenAI-compatible chat completions endpoint with the plan
//!   schema as structured output ([`openai`]);
//! - `gguf`: Gemma 3 270M in-process through candle ([`gguf`]).
//!
//! Every plan from every backend passes [`validate::Validator`] (the JSON
//! Schema in `schema/action_plan.schema.json` plus semantic rules); an LLM's
//! plan also passes [`provenance`] (its distances, angles and targets are the
//! instruction's words); an LLM gets one repair round, then the rule parser
//! answers. With `--fallback`, the rules answer first and an LLM is asked
//! only where they would ask the user. Layout: [`plan`],
//! [`validate`], [`htn`], [`grounding`], [`minilm`], [`replan`], [`llm`],
//! [`openai`], [`gguf`], [`corpus`] (the paraphrase corpus and its scoring)
//! — pure logic; [`planner`] ties them together;
//! [`actor`] owns the models; [`grpc`] is the tonic layer.

use std::path::PathBuf;

pub mod actor;
pub mod corpus;
pub mod gguf;
pub mod grounding;
pub mod grpc;
pub mod htn;
pub mod llama_server;
pub mod llm;
pub mod minilm;
pub mod openai;
pub mod plan;
pub mod planner;
pub mod provenance;
pub mod replan;
pub mod typo;
pub mod validate;

pub use vlnav_runtime::ports::PLANNER as DEFAULT_PORT;

/// Planner settings (flags or environment).
#[derive(clap::Args, Clone, Debug)]
pub struct Options {
    /// Backend used when a request names none: rules, openai or gguf.
    #[arg(long = "backend", env = "VLNAV_PLANNER_BACKEND", default_value = "rules")]
    pub backend: String,
    /// Model directory (all-MiniLM-L6-v2 in `minilm/`, Gemma in `gemma/`).
    #[arg(long = "models-dir", env = "VLNAV_MODELS_DIR", default_value = "models")]
    pub models_dir: PathBuf,
    /// Cosine similarity a target phrase needs to ground semantically.
    #[arg(long, env = "VLNAV_PLANNER_GROUNDING_THRESHOLD", default_value_t = grounding::DEFAULT_THRESHOLD)]
    pub grounding_threshold: f32,
    /// OpenAI-compatible base URL up to /v1 (e.g. http://127.0.0.1:8080/v1); unset: no openai backend.
    #[arg(long, env = "VLNAV_PLANNER_OPENAI_URL")]
    pub openai_url: Option<String>,
    /// Model name sent to the OpenAI-compatible endpoint.
    #[arg(long, env = "VLNAV_PLANNER_OPENAI_MODEL", default_value = "gpt-4o-mini")]
    pub openai_model: String,
    /// API key for the endpoint (also read from OPENAI_API_KEY); unset for local servers.
    #[arg(long, env = "VLNAV_PLANNER_OPENAI_API_KEY", hide_env_values = true)]
    pub openai_api_key: Option<String>,
    /// Per-request timeout of the OpenAI-compatible endpoint, seconds.
    #[arg(long, env = "VLNAV_PLANNER_OPENAI_TIMEOUT_S", default_value_t = 30.0)]
    pub openai_timeout_s: f64,
    /// Gemma GGUF for the gguf backend (default `<models-dir>/gemma/gemma3-270m-q4_k_m.gguf`).
    #[arg(long, env = "VLNAV_PLANNER_GGUF")]
    pub gguf: Option<PathBuf>,
    /// A backend (openai or gguf) asked when the rule parser cannot plan an
    /// instruction and would ask instead: its plan is used only if it passes
    /// the validator and the provenance check (every distance, angle and
    /// target in the instruction's words); otherwise the question stands.
    /// Unset: the rules' question is the answer.
    #[arg(long, env = "VLNAV_PLANNER_FALLBACK")]
    pub fallback: Option<String>,
    /// Load the GGUF model at start instead of on the first gguf request.
    #[arg(long, env = "VLNAV_PLANNER_PRELOAD_GGUF", default_value_t = false)]
    pub preload_gguf: bool,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            backend: "rules".into(),
            models_dir: PathBuf::from(std::env::var("VLNAV_MODELS_DIR").unwrap_or_else(|_| "models".into())),
            grounding_threshold: grounding::DEFAULT_THRESHOLD,
            openai_url: None,
            openai_model: "gpt-4o-mini".into(),
            openai_api_key: None,
            openai_timeout_s: 30.0,
            gguf: None,
            fallback: None,
            preload_gguf: false,
        }
    }
}

/// Loads the models, spawns the planner actor and returns the PlannerService.
/// Fails when all-MiniLM-L6-v2 is missing, naming the file and
/// `deploy/fetch-models.sh`.
pub async fn services(
    opts: &Options,
    server: &vlnav_runtime::ServerConfig,
) -> anyhow::Result<vlnav_runtime::ServiceSet> {
    let opts = opts.clone();
    let planner = tokio::task::spawn_blocking(move || planner::Planner::load(&opts)).await??;
    let validator = planner.validator();
    let mailbox = actor::spawn(planner);
    let svc = grpc::PlannerGrpc::new(mailbox, validator);
    let server_svc = vlnav_proto::v1::planner_service_server::PlannerServiceServer::new(svc)
        .max_decoding_message_size(server.max_message_bytes)
        .max_encoding_message_size(server.max_message_bytes);
    Ok(vlnav_runtime::ServiceSet::new().add("plan", server_svc).callers(vlnav_runtime::CallerPolicy::stages()))
}
