//! OpenAI-compatible chat completions over HTTP (OpenAI, vLLM, llama.cpp's
//! `llama-server`, Ollama, Gemini's OpenAI endpoint), with the plan schema as
//! structured output (`response_format: {type: "json_schema"}`).

use std::time::Duration;

use serde_json::{Value, json};

use crate::llm::{ChatModel, LlmError};

/// Where and how to reach the endpoint.
#[derive(Clone, Debug)]
pub struct OpenAiConfig {
    /// Base URL up to `/v1`, e.g. `http://127.0.0.1:8080/v1` or `https://api.openai.com/v1`.
    pub base_url: String,
    pub model: String,
    /// Bearer token; `None` for local servers without one.
    pub api_key: Option<String>,
    pub timeout: Duration,
    pub max_tokens: u32,
}

pub struct OpenAiChat {
    cfg: OpenAiConfig,
    http: reqwest::blocking::Client,
}

impl OpenAiChat {
    /// Builds the HTTP client (TLS with the ring provider and the platform's roots).
    pub fn new(cfg: OpenAiConfig) -> Result<OpenAiChat, LlmError> {
        // Installing the process-wide provider twice is harmless; the first wins.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let http = reqwest::blocking::Client::builder()
            .timeout(cfg.timeout)
            .build()
            .map_err(|e| LlmError::Unreachable { url: cfg.base_url.clone(), msg: e.to_string() })?;
        Ok(OpenAiChat { cfg, http })
    }

    fn endpoint(&self) -> String {
        format!("{}/chat/completions", self.cfg.base_url.trim_end_matches('/'))
    }
}

impl ChatModel for OpenAiChat {
    fn name(&self) -> &'static str {
        "openai"
    }

    fn complete(&mut self, system: &str, user: &str, schema: &Value) -> Result<String, LlmError> {
        let url = self.endpoint();
        let body = json!({
            "model": self.cfg.model,
            "messages": [
                {"role": "system", "content": system},
                {"role": "user", "content": user},
            ],
            "temperature": 0,
            "max_tokens": self.cfg.max_tokens,
            "response_format": {
                "type": "json_schema",
                "json_schema": {"name": "action_plan", "strict": false, "schema": schema},
            },
        });
        let mut req = self.http.post(&url).json(&body);
        if let Some(key) = &self.cfg.api_key {
            req = req.bearer_auth(key);
        }
        let resp = req.send().map_err(|e| LlmError::Unreachable { url: url.clone(), msg: e.to_string() })?;
        let status = resp.status();
        let text = resp.text().map_err(|e| LlmError::Reply(e.to_string()))?;
        if !status.is_success() {
            return Err(LlmError::Http { status: status.as_u16(), body: text.chars().take(500).collect() });
        }
        let v: Value = serde_json::from_str(&text).map_err(|e| LlmError::Reply(format!("not JSON: {e}")))?;
        v["choices"][0]["message"]["content"]
            .as_str()
            .map(str::to_string)
            .ok_or_else(|| LlmError::Reply("no choices[0].message.content in the reply".into()))
    }
}
