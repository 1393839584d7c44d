//! Draws every scenario of a suite (world, start, destination, route) as SVG,
//! without running anything: `cargo run -p vlnav-eval --example suite_layouts -- [suite.toml] [out-dir]`.

use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let suite_path = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios/suite.toml"));
    let out = args.next().map(PathBuf::from).unwrap_or_else(|| PathBuf::from(".vlnav/eval/layouts"));
    let suite = vlnav_eval::suite::Suite::load(&suite_path)?;
    let worlds = suite
        .scenarios
        .iter()
        .map(|s| vlnav_eval::runner::load_world(&s.world_path(&suite)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    for p in vlnav_eval::write_layouts(&suite, &worlds, &out)? {
        println!("{}", p.display());
    }
    Ok(())
}
