//! Runs the paraphrase corpus (`tests/corpus/*.tsv`) through one backend and
//! prints its accuracy per category, the latency per instruction (p50, p95,
//! mean) and which backend produced each answer (an LLM's output that the
//! validator refuses twice falls back to the rules, and counts as the rules').
//!
//!     cargo run --release -p vlnav-planner --example corpus -- --backend rules
//!     cargo run --release -p vlnav-planner --example corpus -- --backend gguf --per-category 2
//!     cargo run --release -p vlnav-planner --example corpus -- --backend openai --llama-server --per-category 2
//!     cargo run --release -p vlnav-planner --example corpus -- --backend openai --openai-url http://host:8080/v1
//!
//! `--llama-server` starts `deploy/llama-server.sh`'s binary (or
//! `$VLNAV_LLAMA_SERVER`) on the shipped Gemma GGUF. `--per-category N` takes
//! the first N lines of each category and `--limit N` the first N of those
//! (the LLM backends take seconds per instruction on a CPU). `--misses`
//! lists every wrong answer.
//! `--set heldback` runs the held-back instructions (`tests/heldback/`)
//! instead, `--set both` both sets. `--fallback gguf|openai` keeps the rules
//! as the backend and asks that model only where the rules would ask the
//! user (its plan kept only if it passes the validator and the provenance
//! check):
//!
//!     cargo run --release -p vlnav-planner --example corpus -- --set both --fallback gguf --misses
//!
//! `VLNAV_MODELS_DIR` locates the models (default `models`).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use vlnav_planner::corpus::{self, Tally};
use vlnav_planner::gguf::GemmaChat;
use vlnav_planner::llama_server::{self, LlamaServer};
use vlnav_planner::{Options, planner::Planner};

fn main() -> anyhow::Result<()> {
    let mut backend = "rules".to_string();
    let mut per_category = usize::MAX;
    let mut limit = usize::MAX;
    let mut openai_url: Option<String> = None;
    let mut start_llama = false;
    let mut show_misses = false;
    let mut threads = 2usize;
    let mut fallback: Option<String> = None;
    let mut set = "corpus".to_string();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--backend" => backend = args.next().ok_or_else(|| anyhow::anyhow!("--backend needs a name"))?,
            "--per-category" => {
                per_category = args.next().ok_or_else(|| anyhow::anyhow!("--per-category needs N"))?.parse()?
            }
            "--limit" => limit = args.next().ok_or_else(|| anyhow::anyhow!("--limit needs N"))?.parse()?,
            "--openai-url" => {
                openai_url = Some(args.next().ok_or_else(|| anyhow::anyhow!("--openai-url needs a URL"))?)
            }
            "--llama-server" => start_llama = true,
            "--threads" => threads = args.next().ok_or_else(|| anyhow::anyhow!("--threads needs N"))?.parse()?,
            "--misses" => show_misses = true,
            "--fallback" => fallback = Some(args.next().ok_or_else(|| anyhow::anyhow!("--fallback needs a name"))?),
            "--set" => set = args.next().ok_or_else(|| anyhow::anyhow!("--set needs corpus, heldback or both"))?,
            other => anyhow::bail!(
                "unknown argument {other:?}; use --backend rules|gguf|openai, --per-category N, --limit N, --openai-url URL, --llama-server, --threads N, --misses, --fallback gguf|openai, --set corpus|heldback|both"
            ),
        }
    }
    let models_dir = PathBuf::from(std::env::var("VLNAV_MODELS_DIR").unwrap_or_else(|_| "models".into()));
    let _server = if start_llama {
        let bin = llama_server::locate(&models_dir).map_err(anyhow::Error::msg)?;
        let server = LlamaServer::start(&bin, &GemmaChat::path(&models_dir), threads, Duration::from_secs(300))
            .map_err(anyhow::Error::msg)?;
        openai_url = Some(server.base_url());
        Some(server)
    } else {
        None
    };
    let mut planner = Planner::load(&Options {
        backend: backend.clone(),
        models_dir: models_dir.clone(),
        openai_url,
        openai_model: "gemma3-270m".into(),
        openai_timeout_s: 300.0,
        fallback: fallback.clone(),
        ..Options::default()
    })?;

    let dirs: &[&str] = match set.as_str() {
        "corpus" => &["tests/corpus"],
        "heldback" => &["tests/heldback"],
        "both" => &["tests/corpus", "tests/heldback"],
        other => anyhow::bail!("--set {other:?}: use corpus, heldback or both"),
    };
    let mut all = Vec::new();
    for d in dirs {
        all.extend(corpus::load_dir(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(d)).map_err(anyhow::Error::msg)?);
    }
    let mut taken: BTreeMap<String, usize> = BTreeMap::new();
    let cases: Vec<_> = all
        .into_iter()
        .filter(|c| {
            let n = taken.entry(c.category.clone()).or_default();
            *n += 1;
            *n <= per_category
        })
        .take(limit)
        .collect();

    let mut tally = Tally::default();
    let mut latencies = Vec::with_capacity(cases.len());
    let mut produced_by: BTreeMap<String, usize> = BTreeMap::new();
    let mut misses = Vec::new();
    // Answers the backend produced itself (not the rules' fallback), and how
    // many of those were right.
    let (mut own, mut own_right) = (0usize, 0usize);
    for (i, case) in cases.iter().enumerate() {
        let t = Instant::now();
        let planned = planner.plan(&case.instruction, &backend)?;
        latencies.push(t.elapsed());
        *produced_by.entry(planned.backend.clone()).or_default() += 1;
        let verdict = corpus::judge(&case.expected, &planned);
        tally.add(&case.category, verdict.is_ok());
        if planned.backend != "rules" {
            own += 1;
            own_right += usize::from(verdict.is_ok());
        }
        if let Err(why) = verdict {
            misses.push(format!(
                "{} {:?} [{}]\n    got  {}\n    why  {why}",
                case.at,
                case.instruction,
                planned.backend,
                corpus::describe(&planned)
            ));
        }
        if backend != "rules" || (fallback.is_some() && latencies[i] > Duration::from_millis(100)) {
            eprintln!(
                "[{}/{}] {:.2} s {} [{}]",
                i + 1,
                cases.len(),
                latencies[i].as_secs_f64(),
                case.at,
                planned.backend
            );
        }
    }
    latencies.sort();
    let pct = |p: f64| -> Duration {
        let k = ((latencies.len() as f64 - 1.0) * p).round() as usize;
        latencies.get(k).copied().unwrap_or_default()
    };
    let mean = latencies.iter().sum::<Duration>() / latencies.len().max(1) as u32;
    match &fallback {
        Some(f) => println!("backend {backend}, fallback {f}: {} instructions ({set})", cases.len()),
        None => println!("backend {backend}: {} instructions ({set})", cases.len()),
    }
    println!("{}", tally.markdown());
    println!(
        "latency per instruction: p50 {:.2} ms, p95 {:.2} ms, mean {:.2} ms",
        pct(0.5).as_secs_f64() * 1e3,
        pct(0.95).as_secs_f64() * 1e3,
        mean.as_secs_f64() * 1e3
    );
    let produced: Vec<String> = produced_by.iter().map(|(b, n)| format!("{b} {n}")).collect();
    println!("answers produced by: {}", produced.join(", "));
    if backend != "rules" || fallback.is_some() {
        println!("the backend's own answers: {own}, of which right: {own_right}");
    }
    if show_misses {
        println!("{} misses:\n{}", misses.len(), misses.join("\n"));
    }
    Ok(())
}
