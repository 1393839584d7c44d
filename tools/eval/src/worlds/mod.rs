//! Generated worlds: `vlnav worlds generate`.
//!
//! A family (corridor, hall, office, home, carpark, warehouse) lays out a
//! world from a seed — sizes, clutter, distractors of the target's class,
//! coloured objects that are not zones, floor markings on and off the route,
//! 0–4 people crossing, coming towards or walking ahead of the robot — and
//! the route an instruction describes: geometric legs from the start pose
//! (whole or half metres, whole degrees), then a landmark the robot is to
//! stop before. From the route come up to three instructions in the suite's
//! conventions (`scenarios/suite.toml`'s header): the hybrid text as a person
//! would say it, and the geometric (dead-reckoned) or visual (landmarks only)
//! text the suite derives from the route. Each is checked on the true map
//! with a grid A* for the Husky's footprint ([`feasible`]); an infeasible one
//! is dropped and counted, a world left without any is not written.
//!
//! Everything derives from (family, seed): the same seed writes the same
//! bytes. Seeds below [`TEST_SEED_BASE`] are the development set; the test
//! set is [`test_set`], a fixed list of seeds at or above it.

pub mod draft;
pub mod families;
pub mod feasible;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::seed::mix64;
use draft::{Draft, Form, Object, Rng};
use vlnav_sim::geometry::Vec2;

/// Seeds at or above this belong to the test set, below to development.
pub const TEST_SEED_BASE: u64 = 1_000_000;
/// Worlds per family in the test set.
pub const TEST_WORLDS_PER_FAMILY: u64 = 55;

/// A kind of generated world.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, clap::ValueEnum)]
pub enum Family {
    /// A corridor with doors to side rooms, hazards on the floor.
    Corridor,
    /// An open hall with pillars, benches and people crossing.
    Hall,
    /// An office floor: desk rows, aisles, cables.
    Office,
    /// A flat: rooms joined by doors 0.8–1.4 m wide, furniture.
    Home,
    /// An outdoor car park: cars, painted zones, hydrants.
    Carpark,
    /// A warehouse: racks and aisles.
    Warehouse,
}

impl Family {
    pub const ALL: [Family; 6] =
        [Family::Corridor, Family::Hall, Family::Office, Family::Home, Family::Carpark, Family::Warehouse];

    pub fn as_str(self) -> &'static str {
        match self {
            Family::Corridor => "corridor",
            Family::Hall => "hall",
            Family::Office => "office",
            Family::Home => "home",
            Family::Carpark => "carpark",
            Family::Warehouse => "warehouse",
        }
    }

    pub fn parse(s: &str) -> Option<Family> {
        Family::ALL.into_iter().find(|f| f.as_str() == s)
    }

    fn title(self) -> &'static str {
        match self {
            Family::Corridor => "Corridor",
            Family::Hall => "Hall",
            Family::Office => "Office",
            Family::Home => "Home",
            Family::Carpark => "Car park",
            Family::Warehouse => "Warehouse",
        }
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The test set: (family, seed) for seeds 1,000,000 + k, k < 55, every
/// family (330 worlds before infeasible ones are dropped).
pub fn test_set() -> Vec<(Family, u64)> {
    Family::ALL.into_iter().flat_map(|f| (0..TEST_WORLDS_PER_FAMILY).map(move |k| (f, TEST_SEED_BASE + k))).collect()
}

/// The development set: `count` worlds of `family` from `seed` on (all below
/// the test set's seeds).
pub fn dev_set(family: Family, count: u64, seed: u64) -> anyhow::Result<Vec<(Family, u64)>> {
    anyhow::ensure!(
        seed.checked_add(count).is_some_and(|end| end <= TEST_SEED_BASE),
        "development seeds must stay below {TEST_SEED_BASE} (the test set's); use --set test for those"
    );
    Ok((seed..seed + count).map(|s| (family, s)).collect())
}

/// One leg of a route: turn (degrees, left positive), then move (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leg {
    pub turn_deg: i64,
    pub move_m: f64,
}

/// What a family lays out: the world, the geometric legs from the start and
/// the landmark to stop before.
#[derive(Clone, Debug)]
pub struct Layout {
    pub draft: Draft,
    pub legs: Vec<Leg>,
    /// Index of the target in `draft.objects`.
    pub target: usize,
    /// The spoken stopping distance from the target, metres.
    pub d_s: f64,
    /// An object next to the target that singles it out ("the chair next to
    /// the potted plant"): index in `draft.objects`.
    pub reference: Option<usize>,
    /// The world has other instances of the target's class (so a visual
    /// instruction, which names only the class, would be ambiguous).
    pub distractors: bool,
}

/// The waypoints the legs reach from `start` (x, y, heading), and the final heading.
pub fn waypoints(start: [f64; 3], legs: &[Leg]) -> (Vec<[f64; 2]>, f64) {
    let (mut x, mut y, mut th) = (start[0], start[1], start[2]);
    let mut out = Vec::new();
    for l in legs {
        th += (l.turn_deg as f64).to_radians();
        x += l.move_m * th.cos();
        y += l.move_m * th.sin();
        out.push([x, y]);
    }
    (out, th)
}

/// "1 meter", "1.5 meters", "4 meters".
pub fn metres(d: f64) -> String {
    if (d - 1.0).abs() < 1e-9 {
        "1 meter".into()
    } else if (d - d.round()).abs() < 1e-9 {
        format!("{d:.0} meters")
    } else {
        format!("{d:.1} meters")
    }
}

/// The hybrid text of a layout: "Move 6 meters forward, then turn left 90
/// degrees and move 2 meters forward, then stop 1 meter before the chair
/// next to the potted plant".
pub fn hybrid_text(layout: &Layout) -> String {
    let mut parts = Vec::new();
    for l in &layout.legs {
        let turn = match l.turn_deg {
            0 => None,
            t if t > 0 => Some(format!("turn left {t} degrees")),
            t => Some(format!("turn right {} degrees", -t)),
        };
        let mv = (l.move_m > 0.0).then(|| format!("move {} forward", metres(l.move_m)));
        parts.push(match (turn, mv) {
            (Some(t), Some(m)) => format!("{t} and {m}"),
            (Some(t), None) => t,
            (None, Some(m)) => m,
            (None, None) => continue,
        });
    }
    let target = &layout.draft.objects[layout.target];
    let mut find = format!("stop {} before the {}", metres(layout.d_s), target.name);
    if let Some(r) = layout.reference {
        let _ = write!(find, " next to the {}", layout.draft.objects[r].name);
    }
    parts.push(find);
    let s = parts.join(", then ");
    let mut c = s.chars();
    match c.next() {
        Some(f) => f.to_uppercase().collect::<String>() + c.as_str(),
        None => s,
    }
}

/// One generated instruction, in the suite's terms.
#[derive(Clone, Debug, PartialEq)]
pub struct GenInstruction {
    pub id: String,
    pub mode: crate::metrics::Mode,
    /// Written out for the hybrid mode; derived from the route otherwise.
    pub text: Option<String>,
    /// Route: waypoints (no landmark), then the landmark leg.
    pub route: Vec<[f64; 2]>,
    pub find: String,
    pub target_at: [f64; 2],
    pub d_s: f64,
    /// The landmark's half depth along the approach, metres.
    pub size: f64,
    pub radius: f64,
}

/// A generated world with its instructions.
#[derive(Clone, Debug)]
pub struct GenWorld {
    pub family: Family,
    pub seed: u64,
    pub name: String,
    pub toml: String,
    pub instructions: Vec<GenInstruction>,
    /// (instruction id, why) for every instruction dropped as infeasible.
    pub dropped: Vec<(String, String)>,
    /// Length of the hybrid route on the true map (A*), metres.
    pub path_m: f64,
}

/// The world seed of (family, seed): the families draw independent streams.
fn world_seed(family: Family, seed: u64) -> u64 {
    mix64(seed ^ mix64(0x574f_524c_4400_0000 ^ family as u64))
}

/// Generates one world. The instructions are checked on the true map; those
/// that fail are listed in `dropped`.
pub fn generate(family: Family, seed: u64) -> anyhow::Result<GenWorld> {
    let name = format!("{}-{seed}", family.as_str());
    let mut rng = Rng::new(world_seed(family, seed));
    let layout = families::layout(family, &name, &mut rng);
    let toml = layout.draft.to_toml();
    let world = vlnav_sim::scenario::parse(&toml).map_err(|e| anyhow::anyhow!("generated world {name}: {e}"))?;
    let grid = feasible::Grid::new(&world);

    let start = layout.draft.start;
    let (wps, heading) = waypoints(start, &layout.legs);
    let target = &layout.draft.objects[layout.target];
    let last = wps.last().copied().unwrap_or([start[0], start[1]]);
    let approach = (target.at[1] - last[1]).atan2(target.at[0] - last[0]);
    let _ = heading;
    let size = (target.half_depth(approach + std::f64::consts::PI) * 100.0).round() / 100.0;
    let leg = crate::suite::Leg { at: target.at, find: Some(target.name.clone()), d_s: Some(layout.d_s), size };
    let stop = leg.end_point(crate::metrics::Point2::new(last[0], last[1]));
    let mut points: Vec<Vec2> = wps.iter().map(|p| Vec2::new(p[0], p[1])).collect();
    points.push(Vec2::new(stop.x, stop.y));

    let radius = ((layout.d_s + size + crate::suite::LANDMARK_SLACK_M) * 100.0).round() / 100.0;
    let base = GenInstruction {
        id: "hybrid".into(),
        mode: crate::metrics::Mode::Hybrid,
        text: Some(hybrid_text(&layout)),
        route: wps.clone(),
        find: target.name.clone(),
        target_at: target.at,
        d_s: layout.d_s,
        size,
        radius,
    };
    let mut base = base;
    base.route.dedup();
    let mut candidates = vec![base.clone()];
    // One more mode per world: visual where the class alone names the
    // target, otherwise geometric (dead reckoning needs no landmark).
    let visual_ok = !layout.distractors && layout.reference.is_none();
    let other =
        if visual_ok && rng.chance(0.5) { crate::metrics::Mode::Visual } else { crate::metrics::Mode::Geometric };
    candidates.push(GenInstruction { id: other.as_str().into(), mode: other, text: None, ..base });

    let mut instructions = Vec::new();
    let mut dropped = Vec::new();
    let mut path_m = 0.0;
    match feasible::check_route(&grid, Vec2::new(start[0], start[1]), &points) {
        Ok(len) => {
            path_m = len;
            instructions = candidates;
        }
        Err(why) => {
            for c in candidates {
                dropped.push((c.id, why.to_string()));
            }
        }
    }
    Ok(GenWorld { family, seed, name, toml, instructions, dropped, path_m })
}

fn fmt_pt(p: [f64; 2]) -> String {
    format!("[{:.2}, {:.2}]", p[0], p[1])
}

/// The suite manifest of generated worlds (world files under `worlds/`).
pub fn suite_toml(worlds: &[GenWorld], what: &str) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "# Generated by `vlnav worlds generate` ({what}): do not edit by hand.");
    let _ = writeln!(
        o,
        "# Conventions as tools/eval/scenarios/suite.toml: G_d is the landmark's centre, the radius\n\
         # = spoken stopping distance + the landmark's half depth along the approach + 0.5 m, and\n\
         # the stopping distance is the route's last leg's d_s + size. Geometric and visual texts\n\
         # are derived from the route. Every instruction was checked feasible for the Husky's\n\
         # footprint on the true map (grid A*)."
    );
    let _ = writeln!(
        o,
        "\n[run]\ntrials = 1\ncamera_width = 160\ncamera_height = 120\nstart_noise_xy_m = 0.10\nstart_noise_theta_deg = 3.0\nmax_mission_s = 150.0"
    );
    for w in worlds.iter().filter(|w| !w.instructions.is_empty()) {
        let _ = writeln!(
            o,
            "\n[[scenario]]\nname = \"{}\"\ntitle = \"{} {}\"\nfamily = \"{}\"\nworld = \"worlds/{}.toml\"",
            w.name,
            w.family.title(),
            w.seed,
            w.family.as_str(),
            w.name
        );
        for ins in &w.instructions {
            let _ = writeln!(o, "\n[[scenario.instruction]]\nid = \"{}\"\nmode = \"{}\"", ins.id, ins.mode.as_str());
            if let Some(t) = &ins.text {
                let _ = writeln!(o, "text = {t:?}");
            }
            let mut legs: Vec<String> = ins.route.iter().map(|p| format!("{{ at = {} }}", fmt_pt(*p))).collect();
            legs.push(format!(
                "{{ at = {}, find = {:?}, d_s = {:.1}, size = {:.2} }}",
                fmt_pt(ins.target_at),
                ins.find,
                ins.d_s,
                ins.size
            ));
            let _ = writeln!(o, "route = [{}]\nradius = {:.2}", legs.join(", "), ins.radius);
        }
    }
    o
}

/// What `generate_set` wrote.
#[derive(Debug, Default)]
pub struct SetReport {
    pub worlds_generated: usize,
    pub worlds_written: usize,
    pub instructions_kept: usize,
    pub instructions_dropped: usize,
    pub suite: PathBuf,
    /// (world, instruction, why) of every dropped instruction.
    pub dropped: Vec<(String, String, String)>,
}

/// Generates `which` into `out`: worlds/*.toml, suite.toml, dropped.csv (every
/// instruction dropped, with why) and dropped/*.toml (worlds left without any).
pub fn generate_set(which: &[(Family, u64)], out: &Path, what: &str) -> anyhow::Result<SetReport> {
    std::fs::create_dir_all(out.join("worlds")).with_context(|| format!("cannot create {}", out.display()))?;
    let mut worlds = Vec::new();
    let mut rep = SetReport::default();
    for (f, s) in which {
        let w = generate(*f, *s)?;
        rep.worlds_generated += 1;
        rep.instructions_kept += w.instructions.len();
        rep.instructions_dropped += w.dropped.len();
        for (id, why) in &w.dropped {
            rep.dropped.push((w.name.clone(), id.clone(), why.clone()));
        }
        // A world left without instructions goes to dropped/, to be looked at.
        let dir = if w.instructions.is_empty() { "dropped" } else { "worlds" };
        if w.instructions.is_empty() {
            std::fs::create_dir_all(out.join(dir)).with_context(|| format!("cannot create {}", out.display()))?;
        } else {
            rep.worlds_written += 1;
        }
        let path = out.join(dir).join(format!("{}.toml", w.name));
        std::fs::write(&path, &w.toml).with_context(|| format!("cannot write {}", path.display()))?;
        worlds.push(w);
    }
    let suite = out.join("suite.toml");
    std::fs::write(&suite, suite_toml(&worlds, what)).with_context(|| format!("cannot write {}", suite.display()))?;
    let mut csv = String::from("world,instruction,reason\n");
    for (w, i, why) in &rep.dropped {
        let _ = writeln!(csv, "{w},{i},\"{why}\"");
    }
    std::fs::write(out.join("dropped.csv"), csv).context("cannot write dropped.csv")?;
    rep.suite = suite;
    Ok(rep)
}

/// `vlnav worlds generate` settings.
#[derive(clap::Args, Clone, Debug)]
pub struct GenerateArgs {
    /// The family to generate (development set); omit with --set test.
    #[arg(long, value_enum)]
    pub family: Option<Family>,
    /// Worlds to generate (development set).
    #[arg(long, default_value_t = 10)]
    pub count: u64,
    /// First seed (development set: below 1,000,000).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// `test`: the fixed test set (55 worlds per family, seeds 1,000,000 on),
    /// instead of --family/--count/--seed; `dev`: --count worlds of every
    /// family from --seed (development seeds).
    #[arg(long)]
    pub set: Option<String>,
    /// Output directory (worlds/*.toml, suite.toml, dropped.csv).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `vlnav worlds generate`; returns the summary line(s) to print.
pub fn run_generate(args: &GenerateArgs) -> anyhow::Result<String> {
    let (which, what) = match (args.set.as_deref(), args.family) {
        (Some("test"), _) => (test_set(), "the test set, every family, seeds 1000000 to 1000054".to_string()),
        (Some("dev"), _) => {
            let mut all = Vec::new();
            for f in Family::ALL {
                all.extend(dev_set(f, args.count, args.seed)?);
            }
            (all, format!("the development set, every family, {} worlds each from seed {}", args.count, args.seed))
        }
        (Some(other), _) => anyhow::bail!("--set {other}: the named sets are `test` and `dev`"),
        (None, Some(f)) => {
            (dev_set(f, args.count, args.seed)?, format!("family {f}, {} worlds from seed {}", args.count, args.seed))
        }
        (None, None) => anyhow::bail!("give --family (with --count and --seed) or --set test"),
    };
    let rep = generate_set(&which, &args.out, &what)?;
    let mut s = format!(
        "{} worlds generated, {} written; {} instructions kept, {} dropped as infeasible (dropped.csv)\nsuite: {}\n",
        rep.worlds_generated,
        rep.worlds_written,
        rep.instructions_kept,
        rep.instructions_dropped,
        rep.suite.display()
    );
    if !rep.dropped.is_empty() {
        let _ = writeln!(s, "first dropped: {} {}: {}", rep.dropped[0].0, rep.dropped[0].1, rep.dropped[0].2);
    }
    Ok(s)
}

/// Whether an object of `reach` at `at` keeps `gap` metres from every object in `objects`.
pub(crate) fn clear_of(objects: &[Object], at: [f64; 2], reach: f64, gap: f64) -> bool {
    objects.iter().all(|o| (o.at[0] - at[0]).hypot(o.at[1] - at[1]) >= o.reach() + reach + gap)
}

/// A box-shaped object's form.
pub(crate) fn boxed(l: f64, w: f64, yaw: f64) -> Form {
    Form::Box { size: [l, w], yaw }
}
