//! Planner latency: the rule-based HTN parser (target p50 < 1 ms), target
//! grounding with all-MiniLM-L6-v2, and the local Gemma 3 270M backend.
//! Needs the models from deploy/fetch-models.sh.

use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use vlnav_planner::gguf::GemmaChat;
use vlnav_planner::grounding::{DEFAULT_THRESHOLD, Grounder};
use vlnav_planner::htn;
use vlnav_planner::llm;
use vlnav_planner::minilm::MiniLm;
use vlnav_planner::validate::Validator;

fn models_dir() -> PathBuf {
    std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"))
}

fn grounder() -> Grounder {
    let m = MiniLm::load(&models_dir()).unwrap_or_else(|e| panic!("{e}"));
    Grounder::with_minilm(m, DEFAULT_THRESHOLD).expect("class embeddings")
}

const PAPER: &str = "Buddy take left turn, move 4 m ahead, then find the standing person to reach close to it, In your right you may see the visitor chair follow it. Finally go at spot where bicycle is standing.";

fn rules(c: &mut Criterion) {
    let g = grounder();
    let v = Validator::new();
    let mut group = c.benchmark_group("rules");
    group.bench_function("paper_example_2_parse", |b| b.iter(|| htn::parse(PAPER, &g)));
    group.bench_function("paper_example_2_parse_and_validate", |b| {
        b.iter(|| {
            let p = htn::parse(PAPER, &g);
            if let vlnav_planner::plan::Outcome::Plan(p) = p.outcome {
                v.validate_plan(&p).unwrap();
            }
        })
    });
    // A phrase outside the synonyms table goes to MiniLM: the parse includes one embedding.
    group.bench_function("semantic_target_parse", |b| b.iter(|| htn::parse("go to the plush toy", &g)));
    group.finish();
}

fn grounding(c: &mut Criterion) {
    let g = grounder();
    let mut group = c.benchmark_group("grounding");
    group.bench_function("lexical_visitor_chair", |b| b.iter(|| g.ground("visitor chair").unwrap()));
    group.bench_function("minilm_plush_toy", |b| b.iter(|| g.ground("plush toy").unwrap()));
    group.bench_function("minilm_unknown_pharmacy", |b| b.iter(|| g.ground("pharmacy").unwrap_err()));
    group.finish();
}

fn local_llm(c: &mut Criterion) {
    let path = GemmaChat::path(&models_dir());
    let mut model = GemmaChat::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let g = grounder();
    let v = Validator::new();
    let mut group = c.benchmark_group("gguf");
    group.sample_size(10).measurement_time(Duration::from_secs(60)).warm_up_time(Duration::from_secs(1));
    group.bench_function("gemma3_270m_plan_move_find", |b| {
        b.iter(|| llm::plan_with(&mut model, "Move 2 meters forward, then find the chair.", &v, &g))
    });
    group.finish();
}

criterion_group!(benches, rules, grounding, local_llm);
criterion_main!(benches);
