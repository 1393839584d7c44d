//! The families' layouts.
//!
//! Each family builds its structure (walls, doors, racks, desk rows, parked
//! cars) and a route (geometric legs from the start, then a landmark ahead
//! of the last waypoint, in view from there); [`Scene::furnish`] then adds
//! what every family randomises: distractors of the target's class (out of
//! view or well beyond the target, or singled out by a reference object
//! next to the target), clutter, coloured objects that are not zones, floor
//! markings on and off the route and 0–4 people crossing, coming towards or
//! walking ahead of the robot. All walls are axis-aligned.

use vlnav_sim::geometry::{Vec2, point_segment_distance, segments_intersect};

use super::draft::{Cable, Draft, Form, MarkKind, Marking, Object, Obstacle, Person, Rgb, Rng, Wall, rect};
use super::{Family, Layout, Leg, boxed, clear_of, waypoints};

/// Rounds to the 0.01 m the world file is written with.
fn r2(v: f64) -> f64 {
    (v * 100.0).round() / 100.0
}

fn p2(x: f64, y: f64) -> [f64; 2] {
    [r2(x), r2(y)]
}

const RED: Rgb = [215, 30, 30];
const YELLOW: Rgb = [230, 200, 30];

/// A landmark of a COCO class with its spoken name, shape and colour. A box's
/// length (along its x axis) is its broad side: placed with yaw = heading +
/// 90°, it faces a robot coming along the heading.
fn landmark(class: i32, rng: &mut Rng) -> Object {
    let (name, form, height, color): (&str, Form, f64, Rgb) = match class {
        0 => {
            ("person", Form::Cylinder { radius: 0.25 }, 1.75, *rng.pick(&[[60, 80, 150], [150, 60, 50], [70, 110, 70]]))
        }
        1 => ("bicycle", boxed(1.7, 0.5, 0.0), 1.0, *rng.pick(&[[200, 40, 40], [30, 90, 160], [40, 40, 40]])),
        3 => ("motorcycle", boxed(2.0, 0.7, 0.0), 1.1, [30, 30, 30]),
        10 => ("fire hydrant", Form::Cylinder { radius: 0.15 }, 0.8, [200, 30, 30]),
        11 => ("stop sign", boxed(0.6, 0.1, 0.0), 2.0, [210, 20, 20]),
        13 => ("bench", boxed(1.6, 0.5, 0.0), 0.5, *rng.pick(&[[120, 85, 50], [90, 90, 95]])),
        24 => ("backpack", boxed(0.35, 0.25, 0.0), 0.5, *rng.pick(&[[40, 60, 120], [30, 30, 30], [150, 40, 40]])),
        28 => ("suitcase", boxed(0.5, 0.3, 0.0), 0.7, *rng.pick(&[[40, 40, 45], [120, 30, 40], [50, 70, 120]])),
        56 => ("chair", boxed(0.5, 0.5, 0.0), 0.9, *rng.pick(&[[40, 40, 45], [70, 50, 35], [150, 40, 40]])),
        57 => ("couch", boxed(2.0, 0.9, 0.0), 0.85, *rng.pick(&[[90, 70, 60], [60, 70, 100]])),
        58 => ("potted plant", Form::Cylinder { radius: r2(rng.range(0.22, 0.35)) }, 1.0, [40, 125, 45]),
        59 => ("bed", boxed(2.0, 1.5, 0.0), 0.6, [200, 200, 210]),
        60 => ("dining table", boxed(1.6, 0.9, 0.0), 0.75, [120, 95, 70]),
        62 => ("tv", boxed(1.1, 0.3, 0.0), 1.3, [25, 25, 28]),
        _ => ("chair", boxed(0.5, 0.5, 0.0), 0.9, [40, 40, 45]),
    };
    let class =
        if matches!(class, 0 | 1 | 3 | 10 | 11 | 13 | 24 | 28 | 56 | 57 | 58 | 59 | 60 | 62) { class } else { 56 };
    Object { name: name.into(), class_id: class, at: [0.0, 0.0], form, height, color }
}

/// The world under construction, with what placement needs to know.
pub(crate) struct Scene<'a> {
    pub rng: &'a mut Rng,
    pub d: Draft,
    /// Wall segments (for lines of sight) and every structure's bounding box.
    segs: Vec<([f64; 2], [f64; 2])>,
    blocks: Vec<([f64; 2], [f64; 2])>,
    /// Where clutter may go: x0, y0, x1, y1.
    pub area: [f64; 4],
    /// Start, waypoints, target.
    route: Vec<[f64; 2]>,
}

impl<'a> Scene<'a> {
    fn new(rng: &'a mut Rng, name: &str, description: &str, floor: Rgb, area: [f64; 4]) -> Self {
        let d = Draft { name: name.into(), description: description.into(), floor, ..Draft::default() };
        Scene { rng, d, segs: Vec::new(), blocks: Vec::new(), area, route: Vec::new() }
    }

    /// An axis-aligned wall polyline.
    fn wall(&mut self, name: &str, path: Vec<[f64; 2]>, closed: bool, height: f64, color: Rgb) {
        let n = path.len();
        let k = if closed { n } else { n - 1 };
        for i in 0..k {
            let (a, b) = (path[i], path[(i + 1) % n]);
            self.segs.push((a, b));
            let t = 0.1;
            self.blocks.push(([a[0].min(b[0]) - t, a[1].min(b[1]) - t], [a[0].max(b[0]) + t, a[1].max(b[1]) + t]));
        }
        self.d.walls.push(Wall { name: name.into(), path, closed, height, color });
    }

    /// A straight wall with doors: `gaps` are (centre, width) along it.
    fn wall_with_doors(&mut self, name: &str, a: [f64; 2], b: [f64; 2], gaps: &[(f64, f64)], color: Rgb) {
        let horizontal = (a[1] - b[1]).abs() < 1e-9;
        let (lo, hi) = if horizontal { (a[0].min(b[0]), a[0].max(b[0])) } else { (a[1].min(b[1]), a[1].max(b[1])) };
        let mut gaps: Vec<(f64, f64)> = gaps.to_vec();
        gaps.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut from = lo;
        let at = |s: f64| if horizontal { [s, a[1]] } else { [a[0], s] };
        // Wall ends grow by half their thickness: the segment stops that much short of the door.
        for (k, (c, w)) in gaps.iter().enumerate() {
            let to = c - w / 2.0 - 0.075;
            if to - from > 0.05 {
                self.wall(&format!("{name} {k}"), vec![at(r2(from)), at(r2(to))], false, 2.6, color);
            }
            from = c + w / 2.0 + 0.075;
        }
        if hi - from > 0.05 {
            self.wall(&format!("{name} {}", gaps.len()), vec![at(r2(from)), at(r2(hi))], false, 2.6, color);
        }
    }

    fn obstacle(&mut self, name: &str, lo: [f64; 2], hi: [f64; 2], height: f64, color: Rgb) {
        let (lo, hi) = (p2(lo[0], lo[1]), p2(hi[0], hi[1]));
        self.blocks.push((lo, hi));
        self.d.obstacles.push(Obstacle { name: name.into(), polygon: rect(lo[0], lo[1], hi[0], hi[1]), height, color });
    }

    /// Start, waypoints (repeats dropped), target.
    fn set_route(&mut self, wps: &[[f64; 2]], target: [f64; 2]) {
        self.route = vec![[self.d.start[0], self.d.start[1]]];
        for p in wps.iter().chain(std::iter::once(&target)) {
            let l = self.route[self.route.len() - 1];
            if (l[0] - p[0]).hypot(l[1] - p[1]) > 1e-6 {
                self.route.push(*p);
            }
        }
    }

    fn route_distance(&self, p: [f64; 2]) -> f64 {
        let v = Vec2::new(p[0], p[1]);
        self.route
            .windows(2)
            .map(|w| point_segment_distance(v, Vec2::new(w[0][0], w[0][1]), Vec2::new(w[1][0], w[1][1])))
            .fold(f64::INFINITY, f64::min)
    }

    fn in_block(&self, p: [f64; 2], r: f64) -> bool {
        self.blocks.iter().any(|(lo, hi)| p[0] > lo[0] - r && p[0] < hi[0] + r && p[1] > lo[1] - r && p[1] < hi[1] + r)
    }

    /// Free for a disc of radius `r`: in the area, off structure and objects.
    fn free(&self, p: [f64; 2], r: f64) -> bool {
        let [x0, y0, x1, y1] = self.area;
        p[0] - r >= x0
            && p[0] + r <= x1
            && p[1] - r >= y0
            && p[1] + r <= y1
            && !self.in_block(p, r)
            && clear_of(&self.d.objects, p, r, 0.15)
    }

    /// A random free spot for a disc of radius `r`, `keep` metres clear of
    /// the route, 1.2 m clear of the start.
    fn spot(&mut self, r: f64, keep: f64) -> Option<[f64; 2]> {
        let [x0, y0, x1, y1] = self.area;
        for _ in 0..60 {
            let p = p2(self.rng.range(x0 + r, x1 - r), self.rng.range(y0 + r, y1 - r));
            let s = self.d.start;
            if self.free(p, r) && self.route_distance(p) >= r + keep && (p[0] - s[0]).hypot(p[1] - s[1]) >= r + 1.2 {
                return Some(p);
            }
        }
        None
    }

    /// Whether a camera at `a` sees `b`: no wall, tall obstacle or other
    /// object (but those in `ignore`) in between.
    fn sees(&self, a: [f64; 2], b: [f64; 2], ignore: &[usize]) -> bool {
        let (va, vb) = (Vec2::new(a[0], a[1]), Vec2::new(b[0], b[1]));
        let hit = |p: [f64; 2], q: [f64; 2]| segments_intersect(va, vb, Vec2::new(p[0], p[1]), Vec2::new(q[0], q[1]));
        if self.segs.iter().any(|(p, q)| hit(*p, *q)) {
            return false;
        }
        for o in self.d.obstacles.iter().filter(|o| o.height > 0.7) {
            let n = o.polygon.len();
            if (0..n).any(|i| hit(o.polygon[i], o.polygon[(i + 1) % n])) {
                return false;
            }
        }
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        self.d.objects.iter().enumerate().all(|(k, o)| {
            ignore.contains(&k)
                || o.height < 0.5
                || (o.at[0] - b[0]).hypot(o.at[1] - b[1]) < 0.05
                || point_segment_distance(Vec2::new(o.at[0], o.at[1]), va, vb) >= o.reach() * 0.8
                || (o.at[0] - a[0]).hypot(o.at[1] - a[1]) > len
        })
    }

    fn add(&mut self, mut o: Object, at: [f64; 2]) -> usize {
        o.at = at;
        self.d.objects.push(o);
        self.d.objects.len() - 1
    }

    /// Places clutter of `classes` (count drawn in `n`), off the route.
    fn clutter(&mut self, classes: &[i32], n: (i64, i64), keep: f64) {
        for _ in 0..self.rng.int(n.0, n.1) {
            let class = *self.rng.pick(classes);
            let mut o = landmark(class, self.rng);
            if let Form::Box { size, .. } = o.form {
                o.form = Form::Box { size, yaw: r2(self.rng.range(-0.4, 0.4)) + *self.rng.pick(&[0.0, 1.571]) };
            }
            if let Some(at) = self.spot(o.reach(), keep) {
                self.add(o, at);
            }
        }
    }

    /// Everything every family randomises, around a target already placed
    /// (index `target`) at the end of `legs`.
    fn furnish(
        &mut self,
        legs: &[Leg],
        target: usize,
        refs: &[i32],
        clutter: &[i32],
        markings: (i64, i64),
        people: (i64, i64),
    ) -> Option<(Option<usize>, bool)> {
        let (wps, _) = waypoints(self.d.start, legs);
        let last = *wps.last()?;
        let t = self.d.objects[target].clone();
        let d_target = (t.at[0] - last[0]).hypot(t.at[1] - last[1]);
        self.set_route(&wps, t.at);
        if !self.sees(last, t.at, &[target]) {
            return None;
        }
        // A reference next to the target singles it out among near distractors.
        let mut reference = None;
        let refs: Vec<i32> = refs.iter().copied().filter(|c| *c != t.class_id).collect();
        let ambiguous = !refs.is_empty() && self.rng.chance(0.3);
        if ambiguous {
            let class = *self.rng.pick(&refs);
            let r = landmark(class, self.rng);
            let ang = (t.at[1] - last[1]).atan2(t.at[0] - last[0]);
            let side = if self.rng.chance(0.5) { 1.0 } else { -1.0 };
            let gap = t.reach() + r.reach() + self.rng.range(0.25, 0.6);
            let at = p2(t.at[0] - gap * ang.sin() * side, t.at[1] + gap * ang.cos() * side);
            if self.free(at, r.reach()) && !self.in_block(at, r.reach() + 0.1) {
                reference = Some(self.add(r, at));
            }
        }
        // Distractors of the target's class.
        let mut distractors = false;
        for _ in 0..self.rng.int(0, 2) {
            let o = landmark(t.class_id, self.rng);
            let Some(at) = self.spot(o.reach(), 0.9) else { continue };
            let far = (at[0] - last[0]).hypot(at[1] - last[1]) >= d_target + 3.0;
            let ok = match reference {
                // Any place, so long as no object of the reference's class is near it.
                Some(r) => {
                    let rc = self.d.objects[r].class_id;
                    self.d.objects.iter().all(|x| x.class_id != rc || (x.at[0] - at[0]).hypot(x.at[1] - at[1]) > 3.0)
                }
                None => far || !self.sees(last, at, &[]),
            };
            if ok && (at[0] - t.at[0]).hypot(at[1] - t.at[1]) > 1.5 {
                self.add(o, at);
                distractors = true;
            }
        }
        let rc = reference.map(|r| self.d.objects[r].class_id);
        let others: Vec<i32> = clutter.iter().copied().filter(|c| *c != t.class_id && Some(*c) != rc).collect();
        if !others.is_empty() {
            self.clutter(&others, (1, 4), 0.9);
        }
        // Coloured things that are not zones: crates and bins.
        for k in 0..self.rng.int(0, 3) {
            let (l, w) = (r2(self.rng.range(0.4, 0.9)), r2(self.rng.range(0.4, 0.7)));
            let r = l.hypot(w) / 2.0;
            if let Some(at) = self.spot(r, 0.9) {
                let color = *self.rng.pick(&[RED, YELLOW, [40, 90, 200]]);
                let h = r2(self.rng.range(0.3, 0.9));
                self.obstacle(
                    &format!("coloured crate {k}"),
                    [at[0] - l / 2.0, at[1] - w / 2.0],
                    [at[0] + l / 2.0, at[1] + w / 2.0],
                    h,
                    color,
                );
            }
        }
        // Floor markings off the route ...
        for k in 0..self.rng.int(markings.0, markings.1) {
            let (l, w) = (r2(self.rng.range(0.8, 2.4)), r2(self.rng.range(0.6, 1.6)));
            if let Some(at) = self.spot(l.hypot(w) / 2.0, 0.7) {
                self.marking(k, at, l, w);
            }
        }
        // ... and one on it, beside the line the robot would drive.
        if self.rng.chance(0.35) {
            let seg = self.rng.int(0, self.route.len() as i64 - 3).max(0) as usize;
            let (a, b) = (self.route[seg], self.route[seg + 1]);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len > 3.5 {
                let s = self.rng.range(2.0, len - 1.0) / len;
                let (ux, uy) = ((b[0] - a[0]) / len, (b[1] - a[1]) / len);
                let off = self.rng.range(0.45, 0.9) * if self.rng.chance(0.5) { 1.0 } else { -1.0 };
                let at = p2(a[0] + (b[0] - a[0]) * s - uy * off, a[1] + (b[1] - a[1]) * s + ux * off);
                let size = r2(self.rng.range(0.6, 1.0));
                // Not in a doorway or an aisle's mouth: the robot goes round it.
                if !self.in_block(at, size * 0.71 + 0.9) {
                    self.marking(9, at, size, size);
                }
            }
        }
        // People.
        let n = self.rng.int(people.0, people.1);
        let mut k = 0;
        for _ in 0..n * 3 {
            if k >= n {
                break;
            }
            if let Some(p) = self.person(k as usize) {
                self.d.people.push(p);
                k += 1;
            }
        }
        Some((reference, distractors))
    }

    fn marking(&mut self, k: i64, at: [f64; 2], l: f64, w: f64) {
        let (kind, name, color) = match self.rng.int(0, 3) {
            0 => (MarkKind::RestrictedZone, "red-marked zone", RED),
            1 => (MarkKind::RestrictedZone, "yellow hatched zone", YELLOW),
            2 => (MarkKind::Hazard, "oil spill", [30, 25, 20]),
            _ => (MarkKind::Hazard, "wet floor", [70, 110, 190]),
        };
        let polygon = rect(r2(at[0] - l / 2.0), r2(at[1] - w / 2.0), r2(at[0] + l / 2.0), r2(at[1] + w / 2.0));
        self.d.markings.push(Marking { name: format!("{name} {k}"), kind, polygon, color });
    }

    /// A walkable straight line for a person: every point free.
    fn walkable(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = (len / 0.2).ceil().max(1.0) as usize;
        (0..=n).all(|i| {
            let s = i as f64 / n as f64;
            let p = [a[0] + (b[0] - a[0]) * s, a[1] + (b[1] - a[1]) * s];
            !self.in_block(p, 0.3) && clear_of(&self.d.objects, p, 0.3, 0.05)
        })
    }

    /// A person crossing a route leg, coming towards the robot along one, or
    /// walking ahead of it on the first one (the robot overtakes).
    fn person(&mut self, k: usize) -> Option<Person> {
        let legs = self.route.len() - 1;
        let seg = self.rng.int(0, legs as i64 - 1) as usize;
        let (a, b) = (self.route[seg], self.route[seg + 1]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        if len < 2.5 {
            return None;
        }
        let (ux, uy) = ((b[0] - a[0]) / len, (b[1] - a[1]) / len);
        let kind = self.rng.int(0, 2);
        let lateral = self.rng.range(0.3, 0.8) * if self.rng.chance(0.5) { 1.0 } else { -1.0 };
        let (from, to, speed, what) = match kind {
            0 => {
                let s = self.rng.range(1.5, len - 0.5);
                let c = [a[0] + ux * s, a[1] + uy * s];
                let h = self.rng.range(1.5, 3.5);
                let sgn = if self.rng.chance(0.5) { 1.0 } else { -1.0 };
                let mut e1 = [c[0] - uy * h * sgn, c[1] + ux * h * sgn];
                let mut e2 = [c[0] + uy * h * sgn, c[1] - ux * h * sgn];
                // Shorten each end until it is free.
                for e in [&mut e1, &mut e2] {
                    while !self.walkable(c, *e) && (e[0] - c[0]).hypot(e[1] - c[1]) > 1.0 {
                        *e = [c[0] + (e[0] - c[0]) * 0.85, c[1] + (e[1] - c[1]) * 0.85];
                    }
                }
                (e1, e2, self.rng.range(0.6, 1.3), "crossing")
            }
            1 => {
                let f = [b[0] - ux * 0.5 - uy * lateral, b[1] - uy * 0.5 + ux * lateral];
                let t = [a[0] + ux * 1.0 - uy * lateral, a[1] + uy * 1.0 + ux * lateral];
                (f, t, self.rng.range(0.6, 1.2), "coming towards")
            }
            _ => {
                let f = [a[0] + ux * 2.0 - uy * lateral * 0.5, a[1] + uy * 2.0 + ux * lateral * 0.5];
                let t = [b[0] - ux * 0.8 - uy * lateral * 0.5, b[1] - uy * 0.8 + ux * lateral * 0.5];
                (f, t, self.rng.range(0.35, 0.6), "walking ahead")
            }
        };
        let (from, to) = (p2(from[0], from[1]), p2(to[0], to[1]));
        let s = self.d.start;
        if (from[0] - to[0]).hypot(from[1] - to[1]) < 1.5
            || !self.walkable(from, to)
            || (from[0] - s[0]).hypot(from[1] - s[1]) < 1.8
            || (to[0] - s[0]).hypot(to[1] - s[1]) < 1.2
        {
            return None;
        }
        let color = *self.rng.pick(&[[60, 70, 140], [150, 60, 50], [90, 90, 60], [120, 120, 130]]);
        Some(Person { name: format!("person {what} {k}"), waypoints: vec![from, to], speed: r2(speed), color })
    }
}

/// A target class and the reference classes that may single it out.
fn target_class(rng: &mut Rng, classes: &[i32], people: bool) -> i32 {
    loop {
        let c = *rng.pick(classes);
        if !(people && c == 0) {
            return c;
        }
    }
}

/// The layout of `family`, tried until one passes its own checks (the
/// target in view from the last waypoint, the route inside the world).
pub fn layout(family: Family, name: &str, rng: &mut Rng) -> Layout {
    for _ in 0..50 {
        let built = match family {
            Family::Corridor => corridor(name, rng),
            Family::Hall => hall(name, rng),
            Family::Office => office(name, rng),
            Family::Home => home(name, rng),
            Family::Carpark => carpark(name, rng),
            Family::Warehouse => warehouse(name, rng),
        };
        if let Some(l) = built {
            return l;
        }
    }
    // Never reached in practice; a plain hall keeps the generator total.
    hall(name, rng).expect("a hall always lays out")
}

fn finish(
    sc: Scene<'_>,
    legs: Vec<Leg>,
    target: usize,
    d_s: f64,
    found: Option<(Option<usize>, bool)>,
) -> Option<Layout> {
    let (reference, distractors) = found?;
    // Leave at least a metre to drive towards the landmark after the last waypoint.
    let (wps, _) = waypoints(sc.d.start, &legs);
    let last = *wps.last()?;
    let t = &sc.d.objects[target];
    let room = (t.at[0] - last[0]).hypot(t.at[1] - last[1]) - t.reach();
    let d_s = if room >= d_s + 1.0 { d_s } else { 1.0 };
    if room < d_s + 1.0 {
        return None;
    }
    Some(Layout { draft: sc.d, legs, target, d_s, reference, distractors })
}

/// Places the target `dist` ahead of the last waypoint (± a small angle).
fn place_target(sc: &mut Scene<'_>, legs: &[Leg], class: i32, dist: f64, spread_deg: f64) -> Option<usize> {
    let (wps, heading) = waypoints(sc.d.start, legs);
    let last = *wps.last()?;
    let a = heading + sc.rng.symmetric_deg(spread_deg);
    let mut o = landmark(class, sc.rng);
    if let Form::Box { size, .. } = o.form {
        o.form = Form::Box { size, yaw: r2(heading + std::f64::consts::FRAC_PI_2 + sc.rng.range(-0.3, 0.3)) };
    }
    let at = p2(last[0] + dist * a.cos(), last[1] + dist * a.sin());
    if !sc.free(at, o.reach() + 0.1) {
        return None;
    }
    // Every waypoint inside the area, clear of structure for turning.
    for p in &wps {
        if !sc.free(*p, 0.65) {
            return None;
        }
    }
    Some(sc.add(o, at))
}

trait SymDeg {
    fn symmetric_deg(&mut self, a: f64) -> f64;
}

impl SymDeg for Rng {
    fn symmetric_deg(&mut self, a: f64) -> f64 {
        self.range(-a, a).to_radians()
    }
}

fn d_s(rng: &mut Rng) -> f64 {
    *rng.pick(&[1.0, 1.0, 1.5, 2.0])
}

fn people_count(rng: &mut Rng, max: i64) -> i64 {
    rng.int(0, max)
}

// ------------------------------------------------------------------ corridor

fn corridor(name: &str, rng: &mut Rng) -> Option<Layout> {
    let len = r2(rng.range(18.0, 30.0));
    let w = r2(rng.range(1.8, 3.0));
    let depth = r2(rng.range(3.5, 5.0));
    let (yn, ys) = (w / 2.0, -w / 2.0);
    let outer = w / 2.0 + depth;
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Corridor {len:.0} m x {w:.1} m with side rooms behind doors, hazards on the floor"),
        [150, 148, 142],
        [0.2, -outer + 0.2, len - 0.2, outer - 0.2],
    );
    sc.d.start = [1.0, 0.0, 0.0];
    sc.wall("outer walls", rect(0.0, -outer, len, outer), true, 2.6, [200, 196, 188]);
    // Rooms along both sides, a door each.
    let mut doors_n = Vec::new();
    let mut doors_s = Vec::new();
    for (side, doors) in [(1.0, &mut doors_n), (-1.0, &mut doors_s)] {
        let mut x = 0.0;
        while x < len - 2.5 {
            let wr = r2(sc.rng.range(3.0, 5.5)).min(len - x);
            let dw = r2(sc.rng.range(0.9, 1.4));
            let dc = sc.rng.range(x + dw / 2.0 + 0.4, x + wr - dw / 2.0 - 0.4).max(x + wr / 2.0);
            // On the half-metre grid from the start, so a route can stop opposite it.
            let dc = 1.0 + ((dc - 1.0) * 2.0).round() / 2.0;
            doors.push((dc, dw));
            x += wr;
            if x < len - 0.5 {
                let y0 = side * w / 2.0;
                sc.wall(
                    "room partition",
                    vec![[r2(x), r2(y0)], [r2(x), r2(side * outer)]],
                    false,
                    2.6,
                    [185, 180, 170],
                );
            }
        }
    }
    sc.wall_with_doors("corridor wall north", [0.0, yn], [len, yn], &doors_n.clone(), [175, 172, 165]);
    sc.wall_with_doors("corridor wall south", [0.0, ys], [len, ys], &doors_s.clone(), [175, 172, 165]);
    let people = people_count(sc.rng, 4);
    let class = target_class(sc.rng, &[58, 56, 28, 24, 0, 13], people > 0);
    let ds = d_s(sc.rng);
    let (legs, target) = if sc.rng.chance(0.55) {
        // Into a side room through its door.
        let side = if sc.rng.chance(0.5) { 1.0 } else { -1.0 };
        let doors = if side > 0.0 { &doors_n } else { &doors_s };
        let cands: Vec<(f64, f64)> = doors.iter().copied().filter(|(c, _)| *c > 3.0 && *c < len - 1.0).collect();
        if cands.is_empty() {
            return None;
        }
        let (dc, _) = *sc.rng.pick(&cands);
        let a = dc - 1.0;
        let legs =
            vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: if side > 0.0 { 90 } else { -90 }, move_m: 0.0 }];
        let dist = (w / 2.0 + depth * sc.rng.range(0.55, 0.8)).min(w / 2.0 + depth - 0.7);
        let t = place_target(&mut sc, &legs, class, dist, 5.0)?;
        (legs, t)
    } else {
        let a = sc.rng.stepped(4.0, (len - 9.0).max(4.0), 1.0);
        let legs = vec![Leg { turn_deg: 0, move_m: a }];
        let dist = sc.rng.range(3.0, (len - 1.0 - a - 1.6).min(7.0));
        let t = place_target(&mut sc, &legs, class, dist, 4.0)?;
        (legs, t)
    };
    let found = sc.furnish(&legs, target, &[58, 13, 60], &[56, 58, 60, 13, 28], (0, 2), (people, people));
    finish(sc, legs, target, ds, found)
}

// ---------------------------------------------------------------------- hall

fn hall(name: &str, rng: &mut Rng) -> Option<Layout> {
    let lx = r2(rng.range(14.0, 24.0));
    let ly = r2(rng.range(9.0, 16.0));
    let y0 = r2(rng.range(ly * 0.3, ly * 0.7));
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Hall {lx:.0} m x {ly:.0} m: pillars, benches, people crossing"),
        [160, 155, 148],
        [0.2, 0.2, lx - 0.2, ly - 0.2],
    );
    sc.d.start = [1.0, y0, 0.0];
    sc.wall("hall walls", rect(0.0, 0.0, lx, ly), true, 3.0, [195, 192, 185]);
    let people = people_count(sc.rng, 4).max(1);
    let class = target_class(sc.rng, &[13, 58, 56, 0, 28, 24], people > 0);
    let ds = d_s(sc.rng);
    let a = sc.rng.stepped(3.0, (lx - 8.0).clamp(3.0, 10.0), 1.0);
    let turn = *sc.rng.pick(&[0, 30, 45, 60, 90, -30, -45, -60, -90]);
    let b = if turn == 0 { 0.0 } else { sc.rng.stepped(0.0, 4.0, 1.0) };
    let legs = if turn == 0 {
        vec![Leg { turn_deg: 0, move_m: a }]
    } else {
        vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: turn, move_m: b }]
    };
    let dist = sc.rng.range(3.0, 7.0);
    let target = place_target(&mut sc, &legs, class, dist, 10.0)?;
    // Pillars on a grid, off the route.
    let step = sc.rng.range(4.0, 6.0);
    let s = r2(sc.rng.range(0.4, 0.6));
    let mut x = step / 2.0 + 1.0;
    let (wps, _) = waypoints(sc.d.start, &legs);
    let at = sc.d.objects[target].at;
    sc.set_route(&wps, at);
    while x < lx - 1.0 {
        let mut y = step / 2.0;
        while y < ly - 1.0 {
            let p = [x, y];
            if sc.route_distance(p) > 1.3 && sc.free(p, 0.6) && (x - 1.0).hypot(y - y0) > 2.0 {
                sc.obstacle("pillar", [x - s / 2.0, y - s / 2.0], [x + s / 2.0, y + s / 2.0], 3.0, [185, 185, 180]);
            }
            y += step;
        }
        x += step;
    }
    let found = sc.furnish(&legs, target, &[58, 56, 28], &[13, 13, 58, 56, 28, 24], (0, 3), (people, people));
    finish(sc, legs, target, ds, found)
}

// -------------------------------------------------------------------- office

fn office(name: &str, rng: &mut Rng) -> Option<Layout> {
    let lx = r2(rng.range(12.0, 20.0));
    let ly = r2(rng.range(8.0, 13.0));
    let aisle = r2(rng.range(1.6, 2.4));
    let y0 = r2(ly / 2.0 + rng.range(-1.0, 1.0));
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Office {lx:.0} m x {ly:.0} m: desk rows, aisles, cables"),
        [150, 146, 138],
        [0.2, 0.2, lx - 0.2, ly - 0.2],
    );
    sc.d.start = [1.0, y0, 0.0];
    sc.wall("office walls", rect(0.0, 0.0, lx, ly), true, 2.7, [205, 200, 190]);
    // Desk blocks on both sides of the main aisle, cross aisles between them.
    let cross = r2(sc.rng.range(1.2, 1.7));
    let block = r2(sc.rng.range(2.4, 4.0));
    let mut crossings = Vec::new();
    let mut x = 2.5;
    while x + block < lx - 1.0 {
        // The cross aisle's centre on the half-metre grid from the start.
        let c = 1.0 + ((x + block + cross / 2.0 - 1.0) * 2.0).round() / 2.0;
        let block = c - cross / 2.0 - x;
        for side in [1.0, -1.0] {
            let ya = y0 + side * aisle / 2.0;
            let yb = if side > 0.0 { ly - 1.3 } else { 1.3 };
            let (lo_y, hi_y) = (ya.min(yb), ya.max(yb));
            if hi_y - lo_y > 1.0 {
                // Two desk rows facing each other, a gap between them.
                let mid = (lo_y + hi_y) / 2.0;
                sc.obstacle("desk row", [x, lo_y + 0.4], [x + block, mid - 0.35], 0.75, [120, 95, 70]);
                sc.obstacle("desk row", [x, mid + 0.35], [x + block, hi_y - 0.4], 0.75, [120, 95, 70]);
            }
        }
        crossings.push(c);
        x += block + cross;
    }
    let people = people_count(sc.rng, 3);
    let class = target_class(sc.rng, &[58, 56, 28, 24, 0], people > 0);
    let ds = d_s(sc.rng);
    let cands: Vec<f64> = crossings.iter().copied().filter(|c| *c < lx - 2.0).collect();
    let (legs, target) = if !cands.is_empty() && sc.rng.chance(0.6) {
        let c = *sc.rng.pick(&cands);
        let a = c - 1.0;
        let turn = if sc.rng.chance(0.5) { 90 } else { -90 };
        let room = if turn > 0 { ly - y0 } else { y0 };
        let legs = vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: turn, move_m: 0.0 }];
        let dist = (room - 0.6).min(sc.rng.range(2.5, 5.0));
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 3.0)?)
    } else {
        let a = sc.rng.stepped(3.0, (lx - 7.0).max(3.0), 1.0);
        let legs = vec![Leg { turn_deg: 0, move_m: a }];
        let dist = sc.rng.range(2.5, (lx - 1.5 - a - 0.6).clamp(2.6, 7.0));
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 3.0)?)
    };
    // Chairs at the desks (distractors for a chair target are checked in furnish).
    let found = sc.furnish(&legs, target, &[58, 60, 28], &[56, 56, 58, 24, 28], (0, 2), (people, people));
    // Cables: from desk rows to the walls, and now and then from a desk into the main aisle.
    for k in 0..sc.rng.int(1, 3) {
        let x = r2(sc.rng.range(2.5, lx - 1.5));
        let side = if sc.rng.chance(0.5) { 1.0 } else { -1.0 };
        let (ya, yb) = if sc.rng.chance(0.3) {
            let edge = y0 + side * (aisle / 2.0 + 0.3);
            (r2(edge), r2(y0 + side * (aisle / 2.0 - sc.rng.range(0.3, 0.7))))
        } else {
            (r2(ly - 0.1), r2(ly - 1.2))
        };
        let bend = r2(x + sc.rng.range(-0.5, 0.5));
        sc.d.cables
            .push(Cable { name: format!("cable {k}"), path: vec![[x, ya], [bend, r2((ya + yb) / 2.0)], [x, yb]] });
    }
    finish(sc, legs, target, ds, found)
}

// ---------------------------------------------------------------------- home

fn home(name: &str, rng: &mut Rng) -> Option<Layout> {
    let h = r2(rng.range(4.0, 6.5));
    let w1 = r2(rng.range(4.0, 6.0));
    let w2 = r2(rng.range(4.0, 6.5));
    let w3 = if rng.chance(0.5) { r2(rng.range(3.5, 5.5)) } else { 0.0 };
    let lx = w1 + w2 + w3;
    let door = r2(rng.range(0.8, 1.4));
    let yd = r2(rng.range(1.0 + door / 2.0, h - 1.0 - door / 2.0));
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Home: {} rooms joined by doors, furniture", if w3 > 0.0 { 3 } else { 2 }),
        [165, 150, 130],
        [0.2, 0.2, lx - 0.2, h - 0.2],
    );
    sc.d.start = [1.0, yd, 0.0];
    sc.wall("outer walls", rect(0.0, 0.0, lx, h), true, 2.5, [215, 210, 200]);
    sc.wall_with_doors("wall between rooms", [w1, 0.0], [w1, h], &[(yd, door)], [200, 195, 185]);
    if w3 > 0.0 {
        let door2 = r2(sc.rng.range(0.8, 1.4));
        let y2 = r2(sc.rng.range(1.0 + door2 / 2.0, h - 1.0 - door2 / 2.0));
        sc.wall_with_doors("wall between rooms", [w1 + w2, 0.0], [w1 + w2, h], &[(y2, door2)], [200, 195, 185]);
    }
    let people = people_count(sc.rng, 2);
    let class = target_class(sc.rng, &[56, 57, 58, 62, 60, 59], people > 0);
    let ds = *sc.rng.pick(&[1.0, 1.0, 1.5]);
    let a = ((w1 - 1.0 + sc.rng.range(1.5, 2.5)) * 2.0).round() / 2.0;
    let turn = *sc.rng.pick(&[0, 90, -90]);
    let legs = if turn == 0 {
        vec![Leg { turn_deg: 0, move_m: a }]
    } else {
        vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: turn, move_m: 0.0 }]
    };
    let room = match turn {
        0 => w1 + w2 - 1.0 - a,
        t if t > 0 => h - yd,
        _ => yd,
    };
    let dist = sc.rng.range(2.2, (room - 0.7).max(2.3));
    let target = place_target(&mut sc, &legs, class, dist, 4.0)?;
    let found = sc.furnish(&legs, target, &[58, 62, 56], &[56, 57, 58, 60, 59, 62], (0, 1), (people, people));
    finish(sc, legs, target, ds, found)
}

// ------------------------------------------------------------------- carpark

fn carpark(name: &str, rng: &mut Rng) -> Option<Layout> {
    let lx = r2(rng.range(24.0, 36.0));
    let lane = r2(rng.range(4.0, 6.0));
    let bay_d = 5.0;
    let walk = r2(rng.range(2.0, 3.5));
    let ly = lane + 2.0 * (bay_d + walk);
    let y0 = r2(ly / 2.0);
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Car park {lx:.0} m x {ly:.0} m: parked cars, painted zones, hydrants"),
        [115, 115, 118],
        [0.2, 0.2, lx - 0.2, ly - 0.2],
    );
    sc.d.start = [1.0, y0, 0.0];
    sc.wall("kerb and fence", rect(0.0, 0.0, lx, ly), true, 1.2, [150, 150, 140]);
    // Parked cars in bays of 2.6 m on both sides, some bays empty.
    let mut empty = Vec::new();
    let mut x = 2.75;
    while x + 2.5 < lx - 1.0 {
        for side in [1.0, -1.0] {
            let yc = y0 + side * (lane / 2.0 + bay_d / 2.0);
            if sc.rng.chance(0.3) {
                empty.push((x + 1.25, side));
                continue;
            }
            let color = *sc.rng.pick(&[[150, 30, 30], [30, 60, 140], [200, 200, 200], [20, 20, 20], [120, 120, 40]]);
            let mut car = landmark(56, sc.rng);
            car.name = "car".into();
            car.class_id = 2;
            car.form = boxed(4.4, 1.8, r2(std::f64::consts::FRAC_PI_2 + sc.rng.range(-0.08, 0.08)));
            car.height = 1.5;
            car.color = color;
            sc.add(car, p2(x + 1.25, yc));
        }
        x += 2.5;
    }
    let people = people_count(sc.rng, 4);
    let class = target_class(sc.rng, &[10, 11, 1, 3, 13, 0], people > 0);
    let ds = *sc.rng.pick(&[1.0, 1.5, 2.0]);
    let cands: Vec<(f64, f64)> = empty.iter().copied().filter(|(c, _)| *c > 4.0 && *c < lx - 3.0).collect();
    let (legs, target) = if !cands.is_empty() && sc.rng.chance(0.5) {
        let (c, side) = *sc.rng.pick(&cands);
        let a = c - 1.0;
        let turn = if side > 0.0 { 90 } else { -90 };
        let legs = vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: turn, move_m: 0.0 }];
        let dist = lane / 2.0 + bay_d + walk * 0.5;
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 3.0)?)
    } else {
        let a = sc.rng.stepped(5.0, (lx - 10.0).clamp(5.0, 14.0), 1.0);
        let legs = vec![Leg { turn_deg: 0, move_m: a }];
        let dist = sc.rng.range(3.5, 8.0).min(lx - 2.0 - a);
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 6.0)?)
    };
    // Hydrants along the walkways (distractors when the target is one are checked in furnish).
    let found = sc.furnish(&legs, target, &[11, 13], &[10, 13, 1, 3, 11], (1, 3), (people, people));
    finish(sc, legs, target, ds, found)
}

// ----------------------------------------------------------------- warehouse

fn warehouse(name: &str, rng: &mut Rng) -> Option<Layout> {
    let lx = r2(rng.range(20.0, 32.0));
    let ly = r2(rng.range(14.0, 22.0));
    let main = r2(rng.range(2.5, 3.5));
    let y0 = r2(ly / 2.0 + rng.range(-1.0, 1.0));
    let mut sc = Scene::new(
        rng,
        name,
        &format!("Warehouse {lx:.0} m x {ly:.0} m: racks and aisles"),
        [135, 135, 130],
        [0.2, 0.2, lx - 0.2, ly - 0.2],
    );
    sc.d.start = [1.0, y0, 0.0];
    sc.wall("warehouse walls", rect(0.0, 0.0, lx, ly), true, 6.0, [180, 180, 175]);
    let aisle = r2(sc.rng.range(1.6, 2.6));
    let depth = 1.1;
    let mut aisles = Vec::new();
    let mut x = 3.0;
    while x + depth < lx - 1.5 {
        // Racks placed so the aisle after them is centred on the half-metre grid.
        let c = 1.0 + ((x + depth + aisle / 2.0 - 1.0) * 2.0).round() / 2.0;
        let x_rack = c - aisle / 2.0 - depth;
        for side in [1.0, -1.0] {
            let ya = y0 + side * main / 2.0;
            let yb = if side > 0.0 { ly - 1.5 } else { 1.5 };
            let (lo, hi) = (ya.min(yb), ya.max(yb));
            if hi - lo > 1.5 {
                let h = r2(sc.rng.range(2.5, 4.0));
                sc.obstacle("rack", [x_rack, lo], [x_rack + depth, hi], h, [60, 90, 150]);
            }
        }
        aisles.push(c);
        x = c + aisle / 2.0;
    }
    let people = people_count(sc.rng, 3);
    let class = target_class(sc.rng, &[28, 0, 1, 56, 58, 24], people > 0);
    let ds = d_s(sc.rng);
    let cands: Vec<f64> = aisles.iter().copied().filter(|c| *c < lx - 2.5).collect();
    let (legs, target) = if !cands.is_empty() && sc.rng.chance(0.65) {
        let c = *sc.rng.pick(&cands);
        let a = c - 1.0;
        let turn = if sc.rng.chance(0.5) { 90 } else { -90 };
        let b = sc.rng.stepped(0.0, 2.0, 1.0);
        let room = if turn > 0 { ly - y0 } else { y0 };
        let legs = vec![Leg { turn_deg: 0, move_m: a }, Leg { turn_deg: turn, move_m: b }];
        let dist = sc.rng.range(2.5, (room - b - 1.5).clamp(2.6, 6.0));
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 2.0)?)
    } else {
        let a = sc.rng.stepped(4.0, (lx - 9.0).clamp(4.0, 14.0), 1.0);
        let legs = vec![Leg { turn_deg: 0, move_m: a }];
        let dist = sc.rng.range(3.0, 7.0).min(lx - 2.0 - a);
        (legs.clone(), place_target(&mut sc, &legs, class, dist, 3.0)?)
    };
    // Pallets: obstacles, now and then half into an aisle on the route.
    let found = sc.furnish(&legs, target, &[58, 56], &[28, 24, 56, 1], (0, 2), (people, people));
    finish(sc, legs, target, ds, found)
}
