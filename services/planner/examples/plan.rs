//! Plans each instruction given on the command line with the rule-based
//! planner (MiniLM grounding included) and prints the plan or the question:
//!
//!     cargo run --release -p vlnav-planner --example plan -- "Turn left and find the chair."
//!
//! With `--ground` first, grounds each argument as a target phrase instead
//! and prints the closest class name or synonym with its similarity.
//! `VLNAV_MODELS_DIR` locates the models (default `models`).

use vlnav_planner::{Options, planner::Planner};

fn main() -> anyhow::Result<()> {
    let models_dir = std::env::var("VLNAV_MODELS_DIR").unwrap_or_else(|_| "models".into());
    let mut planner = Planner::load(&Options { models_dir: models_dir.into(), ..Options::default() })?;
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().is_some_and(|a| a == "--ground") {
        for phrase in &args[1..] {
            let best = planner.grounder().best_score(phrase);
            let head = phrase.split_whitespace().last().unwrap_or("");
            let grounded = planner.grounder().ground(phrase).map(|g| g.class_id);
            let head_score = best.as_ref().and_then(|(m, _)| {
                let class = vlnav_planner::grounding::lexical(m).map(|g| g.class_id)?;
                planner.grounder().class_score(head, class)
            });
            println!("{phrase:<32} {grounded:?}  closest {best:?}, head \"{head}\" to that class {head_score:?}");
        }
        return Ok(());
    }
    for instruction in args {
        let planned = planner.plan(&instruction, "rules")?;
        println!("{instruction}\n  {:?}", planned.outcome);
        for note in planned.notes {
            println!("  note: {note}");
        }
    }
    Ok(())
}
