//! Latency profile of one trace: per-stage duration percentiles, and the
//! critical path of every control cycle (frame in → command out) — which
//! stages the cycle actually waited on.
//!
//! Pure functions over [`Span`]s; clocks of different processes are trusted
//! only within a parent's interval (children are clamped to it).

use std::collections::{BTreeMap, HashMap};
use std::fmt::Write as _;

use crate::span::{Span, SpanKind};

/// Span name of one control cycle: the gateway's span from a sensor frame's
/// arrival to the velocity command it answers with.
pub const CONTROL_CYCLE: &str = "control-cycle";

/// A stage is a span name within one service and span kind: the gateway's
/// own "plan" span differs from the planner's server span "plan" — by
/// service in a cluster, by kind when `vlnav up` runs every server in one
/// process under one service name.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct StageKey {
    pub service: String,
    pub name: String,
    pub kind: SpanKind,
}

impl StageKey {
    pub fn of(span: &Span) -> Self {
        Self { service: span.service.clone(), name: span.name.clone(), kind: span.kind }
    }
}

impl std::fmt::Display for StageKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} [{}, {}]", self.name, self.service, self.kind.as_str())
    }
}

/// Duration figures of one stage, milliseconds.
#[derive(Clone, Debug, PartialEq)]
pub struct StageStats {
    pub stage: StageKey,
    pub count: usize,
    pub errors: usize,
    pub mean_ms: f64,
    pub p50_ms: f64,
    pub p95_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    pub total_ms: f64,
}

/// Nearest-rank percentile (`q` in 0..=1) of ascending `sorted`; NaN when empty.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (q.clamp(0.0, 1.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn ms(ns: u64) -> f64 {
    ns as f64 / 1e6
}

fn summarize(stage: StageKey, mut durations_ms: Vec<f64>, errors: usize) -> StageStats {
    durations_ms.sort_by(f64::total_cmp);
    let total_ms: f64 = durations_ms.iter().sum();
    let count = durations_ms.len();
    StageStats {
        stage,
        count,
        errors,
        mean_ms: if count > 0 { total_ms / count as f64 } else { f64::NAN },
        p50_ms: percentile(&durations_ms, 0.50),
        p95_ms: percentile(&durations_ms, 0.95),
        p99_ms: percentile(&durations_ms, 0.99),
        max_ms: durations_ms.last().copied().unwrap_or(f64::NAN),
        total_ms,
    }
}

/// Count, errors and p50/p95/p99 of every stage in `spans`, the stage with
/// the largest total time first.
pub fn stage_stats(spans: &[Span]) -> Vec<StageStats> {
    let mut by_stage: HashMap<StageKey, (Vec<f64>, usize)> = HashMap::new();
    for s in spans {
        let entry = by_stage.entry(StageKey::of(s)).or_default();
        entry.0.push(ms(s.duration_ns()));
        entry.1 += s.is_error() as usize;
    }
    let mut out: Vec<StageStats> = by_stage.into_iter().map(|(k, (d, e))| summarize(k, d, e)).collect();
    out.sort_by(|a, b| b.total_ms.total_cmp(&a.total_ms).then_with(|| a.stage.cmp(&b.stage)));
    out
}

/// A stretch of a critical path, attributed to the deepest span on the path
/// that covers it: a span's own work and the gaps between its calls count as
/// the span's own time.
#[derive(Clone, Debug, PartialEq)]
pub struct PathSegment {
    pub stage: StageKey,
    pub start_ns: u64,
    pub end_ns: u64,
}

impl PathSegment {
    pub fn duration_ns(&self) -> u64 {
        self.end_ns - self.start_ns
    }
}

/// Children of each span id, for walking a trace.
pub struct SpanTree<'a> {
    by_id: HashMap<&'a str, &'a Span>,
    children: HashMap<&'a str, Vec<&'a Span>>,
}

impl<'a> SpanTree<'a> {
    pub fn new(spans: &'a [Span]) -> Self {
        let by_id: HashMap<&str, &Span> = spans.iter().map(|s| (s.span_id.as_str(), s)).collect();
        let mut children: HashMap<&str, Vec<&Span>> = HashMap::new();
        for s in spans {
            if let Some(p) = s.parent_id.as_deref()
                && p != s.span_id
            {
                children.entry(p).or_default().push(s);
            }
        }
        Self { by_id, children }
    }

    pub fn get(&self, span_id: &str) -> Option<&'a Span> {
        self.by_id.get(span_id).copied()
    }

    pub fn children(&self, span_id: &str) -> &[&'a Span] {
        self.children.get(span_id).map(Vec::as_slice).unwrap_or(&[])
    }

    /// The critical path of `root`: walking back from its end, the child that
    /// finished last before the current point is what the parent waited on
    /// (recursively); time no child covers is the span's own. Segments are in
    /// time order, do not overlap and add up to the root's duration.
    pub fn critical_path(&self, root: &Span) -> Vec<PathSegment> {
        let mut out = Vec::new();
        self.walk(root, root.start_ns, root.end_ns.max(root.start_ns), 0, &mut out);
        out.reverse();
        out
    }

    /// Appends `span`'s path within [lo, hi] to `out`, latest segment first.
    fn walk(&self, span: &Span, lo: u64, hi: u64, depth: usize, out: &mut Vec<PathSegment>) {
        let start = span.start_ns.clamp(lo, hi);
        let end = span.end_ns.clamp(lo, hi);
        let own = |a: u64, b: u64, out: &mut Vec<PathSegment>| {
            if b > a {
                out.push(PathSegment { stage: StageKey::of(span), start_ns: a, end_ns: b });
            }
        };
        // A malformed trace with a parent cycle must not recurse forever.
        if depth > 64 {
            own(start, end, out);
            return;
        }
        let mut kids: Vec<&Span> = self.children(&span.span_id).to_vec();
        kids.sort_by(|a, b| b.end_ns.cmp(&a.end_ns).then_with(|| b.start_ns.cmp(&a.start_ns)));
        let mut cursor = end;
        for kid in kids {
            if cursor <= start {
                break;
            }
            let kid_end = kid.end_ns.min(cursor);
            let kid_start = kid.start_ns.max(start);
            // Ends after the cursor and starts after it too: the parent
            // already waited on something later; skip.
            if kid_start >= cursor || kid_end <= kid_start {
                continue;
            }
            own(kid_end, cursor, out);
            self.walk(kid, kid_start, kid_end, depth + 1, out);
            cursor = kid_start;
        }
        own(start, cursor, out);
    }
}

/// Time on the critical path of one control cycle per stage.
#[derive(Clone, Debug, PartialEq)]
pub struct CycleBreakdown {
    pub span_id: String,
    pub start_ns: u64,
    pub duration_ns: u64,
    /// Nanoseconds on the path by stage; a stage's own time is listed under
    /// the stage itself (the cycle's own time is the gateway's work).
    pub by_stage: BTreeMap<StageKey, u64>,
}

impl CycleBreakdown {
    /// The stage holding the largest share of this cycle.
    pub fn dominant(&self) -> Option<(&StageKey, u64)> {
        self.by_stage.iter().max_by(|a, b| a.1.cmp(b.1).then_with(|| b.0.cmp(a.0))).map(|(k, v)| (k, *v))
    }
}

/// How a stage weighs on the control loop, over all cycles.
#[derive(Clone, Debug, PartialEq)]
pub struct PathShare {
    pub stage: StageKey,
    /// Cycles in which the stage is on the critical path at all.
    pub cycles_on_path: usize,
    /// Mean time on the path per cycle (over all cycles), ms.
    pub mean_ms: f64,
    /// p95 over the cycles it is on the path, ms.
    pub p95_ms: f64,
    /// Share of all control-cycle time.
    pub share: f64,
    /// Cycles in which this stage held the largest share.
    pub dominant_in: usize,
}

/// The control loop's latency: cycle duration percentiles and the critical
/// path shares of the stages it waited on.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlLoopProfile {
    pub cycle_name: String,
    pub cycles: usize,
    pub cycle: StageStats,
    /// Largest share first.
    pub shares: Vec<PathShare>,
    pub breakdowns: Vec<CycleBreakdown>,
}

/// Breaks down every span named `cycle_name` along its critical path.
/// `None` when the trace has no such span.
pub fn control_loop(spans: &[Span], cycle_name: &str) -> Option<ControlLoopProfile> {
    control_loop_of(spans, cycle_name, |_| true)
}

/// [`control_loop`] over the cycles `keep` accepts (those of a measured
/// interval, say), from spans of any number of traces.
pub fn control_loop_of(spans: &[Span], cycle_name: &str, keep: impl Fn(&Span) -> bool) -> Option<ControlLoopProfile> {
    let tree = SpanTree::new(spans);
    let mut cycles: Vec<&Span> = spans.iter().filter(|s| s.name == cycle_name && keep(s)).collect();
    if cycles.is_empty() {
        return None;
    }
    cycles.sort_by_key(|s| (s.start_ns, s.span_id.clone()));
    let breakdowns: Vec<CycleBreakdown> = cycles
        .iter()
        .map(|c| {
            let mut by_stage = BTreeMap::new();
            for seg in tree.critical_path(c) {
                *by_stage.entry(seg.stage.clone()).or_insert(0) += seg.duration_ns();
            }
            CycleBreakdown { span_id: c.span_id.clone(), start_ns: c.start_ns, duration_ns: c.duration_ns(), by_stage }
        })
        .collect();
    let total_ns: u64 = breakdowns.iter().map(|b| b.duration_ns).sum();
    let mut per_stage: BTreeMap<&StageKey, (Vec<f64>, u64, usize)> = BTreeMap::new();
    for b in &breakdowns {
        for (stage, ns) in &b.by_stage {
            let e = per_stage.entry(stage).or_default();
            e.0.push(ms(*ns));
            e.1 += ns;
        }
        if let Some((stage, _)) = b.dominant() {
            per_stage.get_mut(stage).expect("dominant stage is on the path").2 += 1;
        }
    }
    let n = breakdowns.len();
    let mut shares: Vec<PathShare> = per_stage
        .into_iter()
        .map(|(stage, (mut on_path, sum_ns, dominant_in))| {
            on_path.sort_by(f64::total_cmp);
            PathShare {
                stage: stage.clone(),
                cycles_on_path: on_path.len(),
                mean_ms: ms(sum_ns) / n as f64,
                p95_ms: percentile(&on_path, 0.95),
                share: if total_ns > 0 { sum_ns as f64 / total_ns as f64 } else { 0.0 },
                dominant_in,
            }
        })
        .collect();
    shares.sort_by(|a, b| b.share.total_cmp(&a.share).then_with(|| a.stage.cmp(&b.stage)));
    let cycle_key = StageKey::of(cycles[0]);
    let cycle = summarize(
        cycle_key,
        cycles.iter().map(|c| ms(c.duration_ns())).collect(),
        cycles.iter().filter(|c| c.is_error()).count(),
    );
    Some(ControlLoopProfile { cycle_name: cycle_name.to_string(), cycles: n, cycle, shares, breakdowns })
}

/// Everything `vlnav profile` prints for one trace.
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    pub trace_id: String,
    pub spans: usize,
    pub services: Vec<String>,
    /// Wall time from the first span's start to the last span's end, ms.
    pub wall_ms: f64,
    pub stages: Vec<StageStats>,
    pub control_loop: Option<ControlLoopProfile>,
}

/// Profiles a trace's spans.
pub fn profile(trace_id: &str, spans: &[Span], cycle_name: &str) -> Profile {
    let mut services: Vec<String> = spans.iter().map(|s| s.service.clone()).collect();
    services.sort();
    services.dedup();
    let first = spans.iter().map(|s| s.start_ns).min().unwrap_or(0);
    let last = spans.iter().map(|s| s.end_ns).max().unwrap_or(0);
    Profile {
        trace_id: trace_id.to_string(),
        spans: spans.len(),
        services,
        wall_ms: ms(last.saturating_sub(first)),
        stages: stage_stats(spans),
        control_loop: control_loop(spans, cycle_name),
    }
}

fn fmt_ms(v: f64) -> String {
    if v.is_nan() {
        "-".into()
    } else if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

impl Profile {
    /// The plain-text report.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "trace {} · {} spans · {} services · {} ms from first span to last",
            self.trace_id,
            self.spans,
            self.services.len(),
            fmt_ms(self.wall_ms)
        );
        let _ = writeln!(s, "\nPer-stage latency (ms), largest total first");
        let name_w = self.stages.iter().map(|st| st.stage.name.len()).max().unwrap_or(5).max(5);
        let svc_w = self.stages.iter().map(|st| st.stage.service.len()).max().unwrap_or(7).max(7);
        let _ = writeln!(
            s,
            "  {:<name_w$}  {:<svc_w$}  {:<8}  {:>6}  {:>4}  {:>8}  {:>8}  {:>8}  {:>8}  {:>9}",
            "stage", "service", "kind", "count", "err", "p50", "p95", "p99", "max", "total"
        );
        for st in &self.stages {
            let _ = writeln!(
                s,
                "  {:<name_w$}  {:<svc_w$}  {:<8}  {:>6}  {:>4}  {:>8}  {:>8}  {:>8}  {:>8}  {:>9}",
                st.stage.name,
                st.stage.service,
                st.stage.kind.as_str(),
                st.count,
                st.errors,
                fmt_ms(st.p50_ms),
                fmt_ms(st.p95_ms),
                fmt_ms(st.p99_ms),
                fmt_ms(st.max_ms),
                fmt_ms(st.total_ms)
            );
        }
        match &self.control_loop {
            None => {
                let _ = writeln!(s, "\nControl loop: no `{CONTROL_CYCLE}` span in this trace (did the robot run?)");
            }
            Some(cl) => {
                let _ = writeln!(
                    s,
                    "\nControl loop critical path (frame in → command out), {} `{}` cycles: p50 {} ms, p95 {} ms, p99 {} ms, max {} ms",
                    cl.cycles,
                    cl.cycle_name,
                    fmt_ms(cl.cycle.p50_ms),
                    fmt_ms(cl.cycle.p95_ms),
                    fmt_ms(cl.cycle.p99_ms),
                    fmt_ms(cl.cycle.max_ms)
                );
                let label = |p: &PathShare| {
                    if p.stage.name == cl.cycle_name {
                        format!("{} (own time) [{}, {}]", p.stage.name, p.stage.service, p.stage.kind.as_str())
                    } else {
                        p.stage.to_string()
                    }
                };
                let w = cl.shares.iter().map(|p| label(p).len()).max().unwrap_or(5).max(5);
                let _ = writeln!(
                    s,
                    "  {:<w$}  {:>7}  {:>13}  {:>11}  {:>9}  {:>11}",
                    "stage", "share", "mean/cycle ms", "p95 on path", "on path", "dominant in"
                );
                for p in &cl.shares {
                    let _ = writeln!(
                        s,
                        "  {:<w$}  {:>6.1}%  {:>13}  {:>11}  {:>9}  {:>11}",
                        label(p),
                        100.0 * p.share,
                        fmt_ms(p.mean_ms),
                        fmt_ms(p.p95_ms),
                        p.cycles_on_path,
                        p.dominant_in
                    );
                }
                if let Some(slowest) = cl.breakdowns.iter().max_by_key(|b| b.duration_ns) {
                    let mut parts: Vec<(&StageKey, &u64)> = slowest.by_stage.iter().collect();
                    parts.sort_by(|a, b| b.1.cmp(a.1));
                    let parts: Vec<String> =
                        parts.iter().map(|(k, ns)| format!("{} {} ms", k.name, fmt_ms(ms(**ns)))).collect();
                    let _ = writeln!(
                        s,
                        "  slowest cycle {}: {} ms = {}",
                        slowest.span_id,
                        fmt_ms(ms(slowest.duration_ns)),
                        parts.join(" + ")
                    );
                }
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::span::{SpanKind, SpanStatus};

    const MS: u64 = 1_000_000;

    fn sp(id: u64, parent: Option<u64>, name: &str, service: &str, start_ms: u64, end_ms: u64) -> Span {
        Span {
            trace_id: "4bf92f3577b34da6a3ce929d0e0e4736".into(),
            span_id: format!("{id:016x}"),
            parent_id: parent.map(|p| format!("{p:016x}")),
            name: name.into(),
            service: service.into(),
            kind: SpanKind::Internal,
            start_ns: start_ms * MS,
            end_ns: end_ms * MS,
            attributes: Default::default(),
            status: SpanStatus::Unset,
        }
    }

    fn key(name: &str, service: &str) -> StageKey {
        StageKey { service: service.into(), name: name.into(), kind: SpanKind::Internal }
    }

    #[test]
    fn nearest_rank_percentiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.50), 50.0);
        assert_eq!(percentile(&v, 0.95), 95.0);
        assert_eq!(percentile(&v, 0.99), 99.0);
        assert_eq!(percentile(&v, 1.0), 100.0);
        assert_eq!(percentile(&v, 0.0), 1.0);
        assert_eq!(percentile(&[7.0], 0.99), 7.0);
        assert!(percentile(&[], 0.5).is_nan());
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0], 0.5), 2.0);
    }

    #[test]
    fn a_call_s_client_span_less_its_server_span_is_the_hop_and_only_kept_cycles_count() {
        let kind = |mut s: Span, k: SpanKind| {
            s.kind = k;
            s
        };
        // Two cycles; in each, the gateway calls the detector: the client
        // span holds 1 ms before and 2 ms after the server's 6 ms.
        let mut spans = Vec::new();
        for (c, t0) in [(1_u64, 0_u64), (10, 100)] {
            spans.push(sp(c, None, CONTROL_CYCLE, "gw", t0, t0 + 12));
            spans.push(kind(sp(c + 1, Some(c), "call Detect", "gw", t0 + 1, t0 + 10), SpanKind::Client));
            spans.push(kind(sp(c + 2, Some(c + 1), "detect", "det", t0 + 2, t0 + 8), SpanKind::Server));
        }
        let all = control_loop_of(&spans, CONTROL_CYCLE, |_| true).unwrap();
        assert_eq!(all.cycles, 2);
        let mean = |cl: &ControlLoopProfile, name: &str| {
            cl.shares.iter().find(|p| p.stage.name == name).map(|p| p.mean_ms).unwrap()
        };
        assert_eq!(mean(&all, "detect"), 6.0);
        assert_eq!(mean(&all, "call Detect"), 3.0, "the hop");
        assert_eq!(mean(&all, CONTROL_CYCLE), 3.0, "the gateway's own");
        // Only the cycles of a measured interval.
        let later = control_loop_of(&spans, CONTROL_CYCLE, |s| s.start_ns >= 50 * MS).unwrap();
        assert_eq!(later.cycles, 1);
        assert!(control_loop_of(&spans, CONTROL_CYCLE, |_| false).is_none());
    }

    #[test]
    fn stage_stats_group_by_service_and_name() {
        let mut spans = Vec::new();
        for i in 0..20u64 {
            // detect takes 1..=20 ms
            spans.push(sp(100 + i, None, "detect", "vlnav-detector", 1000 * i, 1000 * i + i + 1));
        }
        spans.push(sp(1, None, "plan", "vlnav-gateway", 0, 300));
        spans.push(sp(2, Some(1), "plan", "vlnav-planner", 10, 290));
        let mut err = sp(3, None, "plan", "vlnav-planner", 400, 410);
        err.status = SpanStatus::Error { message: "no model".into() };
        spans.push(err);
        let stats = stage_stats(&spans);
        let find = |n: &str, s: &str| stats.iter().find(|st| st.stage == key(n, s)).unwrap();
        let detect = find("detect", "vlnav-detector");
        assert_eq!(detect.count, 20);
        assert_eq!(detect.p50_ms, 10.0);
        assert_eq!(detect.p95_ms, 19.0);
        assert_eq!(detect.p99_ms, 20.0);
        assert_eq!(detect.max_ms, 20.0);
        assert_eq!(detect.total_ms, 210.0);
        assert_eq!(detect.mean_ms, 10.5);
        let planner = find("plan", "vlnav-planner");
        assert_eq!((planner.count, planner.errors), (2, 1));
        assert_eq!(find("plan", "vlnav-gateway").count, 1);
        // One process, one service name (`vlnav up`): the kind keeps the
        // gateway's span apart from the server span of the same name.
        let mut server = sp(4, None, "plan", "vlnav-gateway", 500, 505);
        server.kind = SpanKind::Server;
        let both = stage_stats(&[sp(5, None, "plan", "vlnav-gateway", 0, 10), server]);
        assert_eq!(both.len(), 2);
        assert_eq!(both.iter().map(|s| s.stage.kind).collect::<Vec<_>>(), [SpanKind::Internal, SpanKind::Server]);
        // Largest total first: gateway plan 300, planner 290, detect 210.
        assert_eq!(stats[0].stage, key("plan", "vlnav-gateway"));
        assert_eq!(stats[2].stage, key("detect", "vlnav-detector"));
    }

    /// control-cycle 0..100 ms:
    ///   detect 5..35 and segment 5..45 run in parallel, then subgoal 45..55,
    ///   local-plan 60..90 (with a nested server span 62..88), own time elsewhere.
    fn one_cycle(base: u64, id0: u64) -> Vec<Span> {
        let g = "vlnav-gateway";
        vec![
            sp(id0, Some(1), "control-cycle", g, base, base + 100),
            sp(id0 + 1, Some(id0), "detect", "vlnav-detector", base + 5, base + 35),
            sp(id0 + 2, Some(id0), "segment", "vlnav-segmenter", base + 5, base + 45),
            sp(id0 + 3, Some(id0), "subgoal", "vlnav-subgoal", base + 45, base + 55),
            sp(id0 + 4, Some(id0), "local-plan-call", g, base + 60, base + 90),
            sp(id0 + 5, Some(id0 + 4), "local-plan", "vlnav-local-planner", base + 62, base + 88),
        ]
    }

    #[test]
    fn critical_path_follows_the_latest_finishing_child() {
        let spans = one_cycle(0, 10);
        let tree = SpanTree::new(&spans);
        let path = tree.critical_path(&spans[0]);
        let got: Vec<(&str, u64, u64)> =
            path.iter().map(|p| (p.stage.name.as_str(), p.start_ns / MS, p.end_ns / MS)).collect();
        let want = [
            ("control-cycle", 0, 5),
            ("segment", 5, 45),
            ("subgoal", 45, 55),
            ("control-cycle", 55, 60),
            ("local-plan-call", 60, 62),
            ("local-plan", 62, 88),
            ("local-plan-call", 88, 90),
            ("control-cycle", 90, 100),
        ];
        assert_eq!(got, want);
        // detect ran in parallel with the longer segment: not on the path.
        assert!(path.iter().all(|p| p.stage.name != "detect"));
        let total: u64 = path.iter().map(PathSegment::duration_ns).sum();
        assert_eq!(total, 100 * MS);
    }

    #[test]
    fn children_outside_the_parent_are_clamped() {
        // A service clock 3 ms ahead: its span seems to end after the cycle.
        let spans = vec![
            sp(1, None, "control-cycle", "gw", 0, 20),
            sp(2, Some(1), "detect", "det", 10, 23),
            sp(3, Some(1), "late", "x", 25, 30),
        ];
        let tree = SpanTree::new(&spans);
        let path = tree.critical_path(&spans[0]);
        let got: Vec<(&str, u64, u64)> =
            path.iter().map(|p| (p.stage.name.as_str(), p.start_ns / MS, p.end_ns / MS)).collect();
        assert_eq!(got, [("control-cycle", 0, 10), ("detect", 10, 20)]);
    }

    #[test]
    fn parent_cycles_do_not_hang() {
        let spans = vec![sp(1, Some(2), "a", "s", 0, 10), sp(2, Some(1), "b", "s", 1, 9)];
        let tree = SpanTree::new(&spans);
        let total: u64 = tree.critical_path(&spans[0]).iter().map(PathSegment::duration_ns).sum();
        assert_eq!(total, 10 * MS);
    }

    #[test]
    fn control_loop_shares_and_dominant_stages() {
        let mut spans = vec![sp(1, None, "mission", "vlnav-gateway", 0, 1000)];
        spans.extend(one_cycle(0, 10));
        spans.extend(one_cycle(200, 20));
        // A third cycle where detection is slow (5..95) and dominates.
        spans.push(sp(30, Some(1), "control-cycle", "vlnav-gateway", 400, 500));
        spans.push(sp(31, Some(30), "detect", "vlnav-detector", 405, 495));
        let cl = control_loop(&spans, CONTROL_CYCLE).unwrap();
        assert_eq!(cl.cycles, 3);
        assert_eq!(cl.cycle.p50_ms, 100.0);
        let share = |n: &str| cl.shares.iter().find(|p| p.stage.name == n).unwrap();
        // segment: 40 + 40 + 0 ms of 300 ms.
        assert!((share("segment").share - 80.0 / 300.0).abs() < 1e-12);
        assert!((share("segment").mean_ms - 80.0 / 3.0).abs() < 1e-9);
        assert_eq!(share("segment").cycles_on_path, 2);
        assert_eq!(share("segment").dominant_in, 2);
        assert_eq!(share("detect").dominant_in, 1);
        assert_eq!(share("detect").cycles_on_path, 1);
        assert_eq!(share("detect").p95_ms, 90.0);
        // own time: 20 + 20 + 10 ms
        assert!((share("control-cycle").share - 50.0 / 300.0).abs() < 1e-12);
        let sum: f64 = cl.shares.iter().map(|p| p.share).sum();
        assert!((sum - 1.0).abs() < 1e-12);
        assert_eq!(cl.shares[0].stage.name, "detect", "largest share first: detect 90 ms > segment 80 ms");
        assert!(control_loop(&spans, "no-such-span").is_none());
    }

    #[test]
    fn report_lists_every_stage_and_the_path() {
        let mut spans = vec![sp(1, None, "mission", "vlnav-gateway", 0, 1000)];
        spans.extend(one_cycle(0, 10));
        let p = profile("4bf92f3577b34da6a3ce929d0e0e4736", &spans, CONTROL_CYCLE);
        assert_eq!(p.spans, 7);
        assert_eq!(p.wall_ms, 1000.0);
        let text = p.report();
        for stage in ["mission", "control-cycle", "detect", "segment", "subgoal", "local-plan"] {
            assert!(text.lines().any(|l| l.trim_start().starts_with(stage)), "{stage} missing in\n{text}");
        }
        assert!(text.contains("Control loop critical path"), "{text}");
        assert!(text.contains("slowest cycle 000000000000000a: 100 ms = segment 40.0 ms"), "{text}");
        let empty = profile("4bf92f3577b34da6a3ce929d0e0e4736", &spans[..1], CONTROL_CYCLE).report();
        assert!(empty.contains("no `control-cycle` span"), "{empty}");
    }
}
