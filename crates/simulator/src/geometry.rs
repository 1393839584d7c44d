//! Planar geometry for a 2.5-D world: points, simple polygons and circles,
//! ray crossings and footprint overlap tests. Poses are `vlnav_geometry`'s.

use nalgebra::Vector2;
pub use vlnav_geometry::{Pose2, wrap_angle};

/// A point or vector in the plane, metres.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Vec2 {
    pub x: f64,
    pub y: f64,
}

impl Vec2 {
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }
    pub fn scale(self, k: f64) -> Vec2 {
        Vec2::new(self.x * k, self.y * k)
    }
    pub fn dot(self, o: Vec2) -> f64 {
        self.x * o.x + self.y * o.y
    }
    pub fn cross(self, o: Vec2) -> f64 {
        self.x * o.y - self.y * o.x
    }
    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }
    pub fn rotate(self, theta: f64) -> Vec2 {
        let (s, c) = theta.sin_cos();
        Vec2::new(c * self.x - s * self.y, s * self.x + c * self.y)
    }
}

impl std::ops::Add for Vec2 {
    type Output = Vec2;
    fn add(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x + o.x, self.y + o.y)
    }
}

impl std::ops::Sub for Vec2 {
    type Output = Vec2;
    fn sub(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x - o.x, self.y - o.y)
    }
}

impl From<Vector2<f64>> for Vec2 {
    fn from(v: Vector2<f64>) -> Self {
        Vec2::new(v.x, v.y)
    }
}

impl From<Vec2> for Vector2<f64> {
    fn from(v: Vec2) -> Self {
        Vector2::new(v.x, v.y)
    }
}

/// A ground-plane shape: a simple polygon or a circle.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    Polygon(Vec<Vec2>),
    Circle { centre: Vec2, radius: f64 },
}

/// Where a horizontal ray crosses a shape's outline: ray parameter and the
/// outline's outward-ish normal there (unit length, sign unspecified for
/// polygons — shading uses |n·l|).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    pub t: f64,
    pub normal: Vec2,
}

/// An interval of a ray inside a shape, `t_in < t_out`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Span {
    pub t_in: f64,
    pub t_out: f64,
    pub normal_in: Vec2,
}

impl Shape {
    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> (Vec2, Vec2) {
        match self {
            Shape::Polygon(pts) => {
                let mut lo = Vec2::new(f64::INFINITY, f64::INFINITY);
                let mut hi = Vec2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
                for p in pts {
                    lo = Vec2::new(lo.x.min(p.x), lo.y.min(p.y));
                    hi = Vec2::new(hi.x.max(p.x), hi.y.max(p.y));
                }
                (lo, hi)
            }
            Shape::Circle { centre, radius } => {
                (Vec2::new(centre.x - radius, centre.y - radius), Vec2::new(centre.x + radius, centre.y + radius))
            }
        }
    }

    pub fn contains(&self, p: Vec2) -> bool {
        match self {
            Shape::Polygon(pts) => point_in_polygon(p, pts),
            Shape::Circle { centre, radius } => (p - *centre).norm() <= *radius,
        }
    }

    /// The point of the outline nearest to `p`, and whether `p` is inside.
    pub fn nearest_boundary_point(&self, p: Vec2) -> (Vec2, bool) {
        match self {
            Shape::Polygon(pts) => {
                let n = pts.len();
                let mut best = pts[0];
                let mut best_d2 = f64::INFINITY;
                for i in 0..n {
                    let q = closest_on_segment(p, pts[i], pts[(i + 1) % n]);
                    let d2 = (p - q).dot(p - q);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = q;
                    }
                }
                (best, point_in_polygon(p, pts))
            }
            Shape::Circle { centre, radius } => {
                let d = p - *centre;
                let l = d.norm();
                let dir = if l > 0.0 { d.scale(1.0 / l) } else { Vec2::new(1.0, 0.0) };
                (*centre + dir.scale(*radius), l <= *radius)
            }
        }
    }

    /// The intervals of the line `o + t·d` (all real t) inside the shape,
    /// sorted by `t_in`. `d` need not be unit length; `t` is in units of `d`.
    pub fn ray_spans(&self, o: Vec2, d: Vec2, out: &mut Vec<Span>) {
        match self {
            Shape::Polygon(pts) => {
                let mut xs: [Crossing; 16] = [Crossing { t: 0.0, normal: Vec2::default() }; 16];
                let mut heap: Vec<Crossing> = Vec::new();
                let mut n = 0usize;
                let len = pts.len();
                for i in 0..len {
                    let a = pts[i];
                    let b = pts[(i + 1) % len];
                    // Signed side of each endpoint relative to the line.
                    let sa = d.cross(a - o);
                    let sb = d.cross(b - o);
                    if (sa > 0.0) == (sb > 0.0) {
                        continue;
                    }
                    let e = b - a;
                    let denom = d.cross(e);
                    if denom == 0.0 {
                        continue;
                    }
                    let t = (a - o).cross(e) / denom;
                    let nl = e.norm();
                    let c = Crossing { t, normal: Vec2::new(e.y / nl, -e.x / nl) };
                    if n < xs.len() {
                        xs[n] = c;
                    } else {
                        if heap.is_empty() {
                            heap.extend_from_slice(&xs);
                        }
                        heap.push(c);
                    }
                    n += 1;
                }
                let list: &mut [Crossing] = if n <= xs.len() { &mut xs[..n] } else { &mut heap[..] };
                list.sort_by(|p, q| p.t.total_cmp(&q.t));
                for pair in list.chunks_exact(2) {
                    if pair[1].t > pair[0].t {
                        out.push(Span { t_in: pair[0].t, t_out: pair[1].t, normal_in: pair[0].normal });
                    }
                }
            }
            Shape::Circle { centre, radius } => {
                // |o + t d − c|² = r²
                let f = o - *centre;
                let a = d.dot(d);
                let b = 2.0 * f.dot(d);
                let c = f.dot(f) - radius * radius;
                let disc = b * b - 4.0 * a * c;
                if disc > 0.0 {
                    let s = disc.sqrt();
                    let t0 = (-b - s) / (2.0 * a);
                    let t1 = (-b + s) / (2.0 * a);
                    let p = o + d.scale(t0) - *centre;
                    out.push(Span { t_in: t0, t_out: t1, normal_in: p.scale(1.0 / radius) });
                }
            }
        }
    }
}

/// Even-odd point-in-polygon test.
pub fn point_in_polygon(p: Vec2, pts: &[Vec2]) -> bool {
    let mut inside = false;
    let n = pts.len();
    let mut j = n - 1;
    for i in 0..n {
        let (a, b) = (pts[i], pts[j]);
        if (a.y > p.y) != (b.y > p.y) && p.x < (b.x - a.x) * (p.y - a.y) / (b.y - a.y) + a.x {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// Do the closed segments `a–b` and `c–d` intersect?
pub fn segments_intersect(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let o1 = orient(a, b, c);
    let o2 = orient(a, b, d);
    let o3 = orient(c, d, a);
    let o4 = orient(c, d, b);
    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
        return true;
    }
    (o1 == 0.0 && on_segment(a, b, c))
        || (o2 == 0.0 && on_segment(a, b, d))
        || (o3 == 0.0 && on_segment(c, d, a))
        || (o4 == 0.0 && on_segment(c, d, b))
}

fn orient(a: Vec2, b: Vec2, c: Vec2) -> f64 {
    (b - a).cross(c - a)
}

fn on_segment(a: Vec2, b: Vec2, p: Vec2) -> bool {
    p.x >= a.x.min(b.x) && p.x <= a.x.max(b.x) && p.y >= a.y.min(b.y) && p.y <= a.y.max(b.y)
}

/// Distance from `p` to the segment `a–b`.
pub fn point_segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    (p - closest_on_segment(p, a, b)).norm()
}

/// The point of the segment `a–b` nearest to `p`.
pub fn closest_on_segment(p: Vec2, a: Vec2, b: Vec2) -> Vec2 {
    let ab = b - a;
    let l2 = ab.dot(ab);
    let t = if l2 == 0.0 { 0.0 } else { ((p - a).dot(ab) / l2).clamp(0.0, 1.0) };
    a + ab.scale(t)
}

/// Twice the signed area (positive when counter-clockwise).
pub fn signed_area2(pts: &[Vec2]) -> f64 {
    let n = pts.len();
    (0..n).map(|i| pts[i].cross(pts[(i + 1) % n])).sum()
}

/// Index pair of two non-adjacent edges that cross, if the polygon is not simple.
pub fn self_intersection(pts: &[Vec2]) -> Option<(usize, usize)> {
    let n = pts.len();
    for i in 0..n {
        for j in i + 1..n {
            let adjacent = j == i + 1 || (i == 0 && j == n - 1);
            if adjacent {
                continue;
            }
            if segments_intersect(pts[i], pts[(i + 1) % n], pts[j], pts[(j + 1) % n]) {
                return Some((i, j));
            }
        }
    }
    None
}

/// A rectangle of `length × width` centred on `pose` (the robot footprint).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrientedRect {
    pub pose: Pose2,
    pub half_length: f64,
    pub half_width: f64,
}

impl OrientedRect {
    pub fn new(pose: Pose2, length: f64, width: f64) -> Self {
        Self { pose, half_length: length / 2.0, half_width: width / 2.0 }
    }

    pub fn inflate(&self, margin: f64) -> Self {
        Self { pose: self.pose, half_length: self.half_length + margin, half_width: self.half_width + margin }
    }

    pub fn corners(&self) -> [Vec2; 4] {
        let (l, w) = (self.half_length, self.half_width);
        [Vec2::new(l, w), Vec2::new(-l, w), Vec2::new(-l, -w), Vec2::new(l, -w)]
            .map(|c| self.pose.transform(&c.into()).into())
    }

    pub fn contains(&self, p: Vec2) -> bool {
        let q = self.pose.inverse_transform(&p.into());
        q.x.abs() <= self.half_length && q.y.abs() <= self.half_width
    }

    /// The point of the rectangle (boundary or inside) nearest to `p`; `p`
    /// itself when it is inside.
    pub fn nearest_point(&self, p: Vec2) -> Vec2 {
        let q = self.pose.inverse_transform(&p.into());
        let c = Vec2::new(q.x.clamp(-self.half_length, self.half_length), q.y.clamp(-self.half_width, self.half_width));
        self.pose.transform(&c.into()).into()
    }

    /// Does the rectangle overlap (touch or contain, either way) the shape?
    pub fn overlaps(&self, shape: &Shape) -> bool {
        match shape {
            Shape::Circle { centre, radius } => {
                let q = self.pose.inverse_transform(&(*centre).into());
                let dx = (q.x.abs() - self.half_length).max(0.0);
                let dy = (q.y.abs() - self.half_width).max(0.0);
                dx.hypot(dy) <= *radius
            }
            Shape::Polygon(pts) => {
                let c = self.corners();
                // Cheap reject on bounding circles.
                let (lo, hi) = shape.bounds();
                let r = self.half_length.hypot(self.half_width);
                let p = self.pose.position();
                if p.x + r < lo.x || p.x - r > hi.x || p.y + r < lo.y || p.y - r > hi.y {
                    return false;
                }
                let n = pts.len();
                for i in 0..4 {
                    for j in 0..n {
                        if segments_intersect(c[i], c[(i + 1) % 4], pts[j], pts[(j + 1) % n]) {
                            return true;
                        }
                    }
                }
                point_in_polygon(c[0], pts) || self.contains(pts[0])
            }
        }
    }
}

/// A closed rectangle polygon for a box of `size` centred on `centre`, rotated by `yaw`.
pub fn box_polygon(centre: Vec2, size: [f64; 2], yaw: f64) -> Vec<Vec2> {
    let (hx, hy) = (size[0] / 2.0, size[1] / 2.0);
    [Vec2::new(hx, hy), Vec2::new(-hx, hy), Vec2::new(-hx, -hy), Vec2::new(hx, -hy)]
        .map(|c| c.rotate(yaw) + centre)
        .to_vec()
}

/// The quadrilateral covering the segment `a–b` widened to `width`.
pub fn segment_quad(a: Vec2, b: Vec2, width: f64) -> Vec<Vec2> {
    let d = b - a;
    let l = d.norm().max(1e-9);
    let n = Vec2::new(-d.y / l, d.x / l).scale(width / 2.0);
    vec![a + n, b + n, b - n, a - n]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Vec<Vec2> {
        vec![Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0), Vec2::new(2.0, 2.0), Vec2::new(0.0, 2.0)]
    }

    #[test]
    fn ray_through_a_square_enters_and_leaves_at_its_sides() {
        let mut spans = Vec::new();
        Shape::Polygon(square()).ray_spans(Vec2::new(-1.0, 1.0), Vec2::new(1.0, 0.0), &mut spans);
        assert_eq!(spans.len(), 1);
        assert!((spans[0].t_in - 1.0).abs() < 1e-12 && (spans[0].t_out - 3.0).abs() < 1e-12);
        assert!((spans[0].normal_in.x.abs() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ray_through_a_u_shape_yields_two_spans() {
        // A U open towards +y: the line y = 1.5 crosses both arms.
        let u = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(3.0, 0.0),
            Vec2::new(3.0, 2.0),
            Vec2::new(2.0, 2.0),
            Vec2::new(2.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 2.0),
            Vec2::new(0.0, 2.0),
        ];
        let mut spans = Vec::new();
        Shape::Polygon(u).ray_spans(Vec2::new(-1.0, 1.5), Vec2::new(1.0, 0.0), &mut spans);
        assert_eq!(spans.len(), 2);
        assert!((spans[0].t_in - 1.0).abs() < 1e-12 && (spans[0].t_out - 2.0).abs() < 1e-12);
        assert!((spans[1].t_in - 3.0).abs() < 1e-12 && (spans[1].t_out - 4.0).abs() < 1e-12);
    }

    #[test]
    fn ray_grazing_a_vertex_gives_no_span_and_a_circle_gives_its_chord() {
        let mut spans = Vec::new();
        Shape::Polygon(square()).ray_spans(Vec2::new(-1.0, 2.0), Vec2::new(1.0, 0.0), &mut spans);
        assert!(spans.iter().all(|s| s.t_out - s.t_in >= 0.0));
        spans.clear();
        Shape::Circle { centre: Vec2::new(5.0, 0.0), radius: 1.0 }.ray_spans(
            Vec2::default(),
            Vec2::new(2.0, 0.0),
            &mut spans,
        );
        assert_eq!(spans.len(), 1);
        // t is in units of d (2 m): the circle spans x ∈ [4, 6].
        assert!((spans[0].t_in - 2.0).abs() < 1e-12 && (spans[0].t_out - 3.0).abs() < 1e-12);
    }

    #[test]
    fn rectangle_overlap_detects_touching_containment_and_separation() {
        let rect = OrientedRect::new(Pose2::new(0.0, 0.0, 0.3), 1.0, 0.6);
        assert!(rect.overlaps(&Shape::Polygon(box_polygon(Vec2::new(0.6, 0.0), [0.4, 0.4], 0.0))));
        assert!(!rect.overlaps(&Shape::Polygon(box_polygon(Vec2::new(2.0, 0.0), [0.4, 0.4], 0.0))));
        // A big polygon containing the rectangle entirely.
        assert!(rect.overlaps(&Shape::Polygon(box_polygon(Vec2::default(), [10.0, 10.0], 0.0))));
        // A small polygon inside the rectangle.
        assert!(rect.overlaps(&Shape::Polygon(box_polygon(Vec2::default(), [0.1, 0.1], 0.0))));
        assert!(rect.overlaps(&Shape::Circle { centre: Vec2::new(0.0, 0.5), radius: 0.25 }));
        assert!(!rect.overlaps(&Shape::Circle { centre: Vec2::new(0.0, 0.8), radius: 0.25 }));
    }

    #[test]
    fn self_intersections_and_orientation() {
        let bowtie = vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0)];
        assert!(self_intersection(&bowtie).is_some());
        assert!(self_intersection(&square()).is_none());
        assert!(signed_area2(&square()) > 0.0);
    }
}
