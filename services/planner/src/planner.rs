//! The planner's state and its three operations (plan, replan, validate),
//! in plain Rust types: the actor owns one [`Planner`].

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::Options;
use crate::gguf::GemmaChat;
use crate::grounding::Grounder;
use crate::htn::{self, InputError, Parsed};
use crate::llm::{self, ChatModel};
use crate::minilm::MiniLm;
use crate::openai::{OpenAiChat, OpenAiConfig};
use crate::plan::{Clarification, Outcome, Plan, Planned};
use crate::replan::{self, ReplanError};
use crate::validate::Validator;

/// Backend names as requests spell them.
pub const BACKENDS: [&str; 3] = ["rules", "openai", "gguf"];

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error("{0}")]
    Input(#[from] InputError),
    #[error("backend: unknown backend \"{0}\"; use one of rules, openai, gguf (or leave it empty)")]
    UnknownBackend(String),
    #[error("backend: {0}")]
    Unavailable(String),
    #[error("{0}")]
    Replan(#[from] ReplanError),
    #[error("plan: the plan to revise is invalid: {0}")]
    InvalidPlan(String),
}

enum Gguf {
    NotLoaded(PathBuf),
    Loaded(Box<GemmaChat>),
}

pub struct Planner {
    validator: Arc<Validator>,
    grounder: Grounder,
    default_backend: String,
    /// Asked where the rules would ask the user (`Options::fallback`).
    fallback: Option<String>,
    openai: Option<OpenAiChat>,
    gguf: Gguf,
}

impl Planner {
    /// Loads MiniLM (required) and, if configured, the OpenAI client and the GGUF model.
    pub fn load(opts: &Options) -> anyhow::Result<Planner> {
        if !BACKENDS.contains(&opts.backend.as_str()) {
            anyhow::bail!(
                "--backend / VLNAV_PLANNER_BACKEND: unknown backend \"{}\"; use rules, openai or gguf",
                opts.backend
            );
        }
        let minilm = MiniLm::load(&opts.models_dir)?;
        let grounder = Grounder::with_minilm(minilm, opts.grounding_threshold)?;
        let openai = match &opts.openai_url {
            Some(url) => Some(OpenAiChat::new(OpenAiConfig {
                base_url: url.clone(),
                model: opts.openai_model.clone(),
                api_key: opts
                    .openai_api_key
                    .clone()
                    .or_else(|| std::env::var("OPENAI_API_KEY").ok())
                    .filter(|k| !k.is_empty()),
                timeout: Duration::from_secs_f64(opts.openai_timeout_s.max(0.1)),
                max_tokens: 512,
            })?),
            None => None,
        };
        if let Some(f) = &opts.fallback
            && !matches!(f.as_str(), "openai" | "gguf")
        {
            anyhow::bail!("--fallback / VLNAV_PLANNER_FALLBACK: unknown backend \"{f}\"; use openai or gguf");
        }
        if (opts.backend == "openai" || opts.fallback.as_deref() == Some("openai")) && openai.is_none() {
            anyhow::bail!("--backend openai needs --openai-url / VLNAV_PLANNER_OPENAI_URL");
        }
        let gguf_path = opts.gguf.clone().unwrap_or_else(|| GemmaChat::path(&opts.models_dir));
        let gguf = if opts.preload_gguf || opts.backend == "gguf" {
            Gguf::Loaded(Box::new(GemmaChat::load(&gguf_path)?))
        } else {
            Gguf::NotLoaded(gguf_path)
        };
        Ok(Planner {
            validator: Arc::new(Validator::new()),
            grounder,
            default_backend: opts.backend.clone(),
            fallback: opts.fallback.clone(),
            openai,
            gguf,
        })
    }

    /// A planner from parts (benches and tests that bring their own grounder).
    pub fn from_parts(
        grounder: Grounder,
        openai: Option<OpenAiChat>,
        gguf: Option<GemmaChat>,
        gguf_path: &Path,
    ) -> Planner {
        Planner {
            validator: Arc::new(Validator::new()),
            grounder,
            default_backend: "rules".into(),
            fallback: None,
            openai,
            gguf: match gguf {
                Some(g) => Gguf::Loaded(Box::new(g)),
                None => Gguf::NotLoaded(gguf_path.to_path_buf()),
            },
        }
    }

    /// Asks `backend` (openai or gguf) where the rule parser would ask the user.
    pub fn with_fallback(mut self, backend: Option<&str>) -> Planner {
        self.fallback = backend.map(str::to_string);
        self
    }

    pub fn validator(&self) -> Arc<Validator> {
        self.validator.clone()
    }

    pub fn grounder(&self) -> &Grounder {
        &self.grounder
    }

    fn model<'a>(
        openai: &'a mut Option<OpenAiChat>,
        gguf: &'a mut Gguf,
        backend: &str,
    ) -> Result<Option<&'a mut dyn ChatModel>, PlanError> {
        match backend {
            "rules" => Ok(None),
            "openai" => match openai.as_mut() {
                Some(m) => Ok(Some(m as &mut dyn ChatModel)),
                None => Err(PlanError::Unavailable(
                    "the openai backend is not configured; start the planner with --openai-url / VLNAV_PLANNER_OPENAI_URL".into(),
                )),
            },
            "gguf" => {
                if let Gguf::NotLoaded(path) = gguf {
                    let loaded = GemmaChat::load(path).map_err(|e| PlanError::Unavailable(e.to_string()))?;
                    *gguf = Gguf::Loaded(Box::new(loaded));
                }
                match gguf {
                    Gguf::Loaded(m) => Ok(Some(m.as_mut() as &mut dyn ChatModel)),
                    Gguf::NotLoaded(_) => unreachable!("loaded above"),
                }
            }
            other => Err(PlanError::UnknownBackend(other.to_string())),
        }
    }

    /// Instruction → plan or clarification. `backend` empty: the default.
    pub fn plan(&mut self, instruction: &str, backend: &str) -> Result<Planned, PlanError> {
        htn::check_input(instruction)?;
        let backend = if backend.is_empty() { self.default_backend.clone() } else { backend.to_string() };
        let planned = match Self::model(&mut self.openai, &mut self.gguf, &backend)? {
            None => {
                let parsed = htn::parse(instruction, &self.grounder);
                let planned = Planned {
                    outcome: parsed.outcome,
                    backend: "rules".into(),
                    notes: parsed.notes,
                    ungrounded: parsed.ungrounded,
                };
                match &self.fallback {
                    Some(fallback) if matches!(planned.outcome, Outcome::Clarify(_)) => {
                        let fallback = fallback.clone();
                        self.ask_fallback(&fallback, instruction, planned)?
                    }
                    _ => planned,
                }
            }
            Some(model) => llm::plan_with(model, instruction, &self.validator, &self.grounder),
        };
        Ok(self.final_check(planned))
    }

    /// The rules would ask; the fallback backend proposes a plan, used only
    /// if it passes the validator and the provenance check.
    fn ask_fallback(&mut self, fallback: &str, instruction: &str, mut asked: Planned) -> Result<Planned, PlanError> {
        let Some(model) = Self::model(&mut self.openai, &mut self.gguf, fallback)? else {
            return Ok(asked);
        };
        let name = model.name();
        let question = match &asked.outcome {
            Outcome::Clarify(c) => c.reason.clone(),
            Outcome::Plan(_) => String::new(),
        };
        let proposal = llm::propose(model, instruction, &self.validator, &self.grounder);
        match proposal.plan {
            Ok(plan) => {
                let mut notes = vec![format!(
                    "the rule parser would ask ({question}); {name} proposed this plan, and every distance, angle \
                     and target in it is in the instruction's words"
                )];
                notes.extend(proposal.notes);
                Ok(Planned { outcome: Outcome::Plan(plan), backend: name.to_string(), notes, ungrounded: vec![] })
            }
            Err(errors) => {
                asked.notes.extend(proposal.notes);
                asked.notes.push(format!("{name} was asked as the fallback; no plan passed: {}", errors.join("; ")));
                Ok(asked)
            }
        }
    }

    /// Revises the remaining plan after `failed_step` failed and the user answered.
    pub fn replan(
        &mut self,
        plan: &Plan,
        failed_step: usize,
        failure: &str,
        answer: &str,
        backend: &str,
    ) -> Result<Planned, PlanError> {
        if !backend.is_empty() && !BACKENDS.contains(&backend) {
            return Err(PlanError::UnknownBackend(backend.to_string()));
        }
        if !plan.steps.is_empty() {
            self.validator.validate_plan(plan).map_err(|e| PlanError::InvalidPlan(e.join("; ")))?;
        }
        let parsed = replan::replan(plan, failed_step, failure, answer, &self.grounder)?;
        let mut planned = self.checked(parsed, "rules");
        if !backend.is_empty() && backend != "rules" {
            planned
                .notes
                .push(format!("replanning uses the rule-based parser; backend \"{backend}\" is used for Plan only"));
        }
        Ok(self.final_check(planned))
    }

    fn checked(&self, parsed: Parsed, backend: &str) -> Planned {
        Planned {
            outcome: parsed.outcome,
            backend: backend.to_string(),
            notes: parsed.notes,
            ungrounded: parsed.ungrounded,
        }
    }

    /// The last gate: a plan leaves only if the validator accepts it (with its splits).
    fn final_check(&self, mut planned: Planned) -> Planned {
        if let Outcome::Plan(plan) = &planned.outcome {
            match self.validator.validate_plan(plan) {
                Ok(v) => {
                    planned.notes.extend(v.notes);
                    planned.outcome = Outcome::Plan(v.plan);
                }
                Err(errors) => {
                    planned.notes.push(format!("plan rejected by the validator: {}", errors.join("; ")));
                    planned.outcome = Outcome::Clarify(Clarification {
                        question: "I could not make a safe plan from that. Could you say it more simply?".into(),
                        reason: errors.join("; "),
                        options: vec![],
                    });
                }
            }
        }
        planned
    }
}
