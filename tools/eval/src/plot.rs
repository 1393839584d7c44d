//! Top-down trajectory plots as SVG: structure, no-go zones, cables, labelled
//! objects, the true path, the odometry path (drawn in the world through the
//! odom frame's origin), reached subgoals, target estimates (the paper's
//! "golden spheres"), the start and the success circle around the destination.

use std::fmt::Write as _;

use crate::metrics::{Point2, Pose};

/// A labelled object of the world.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotObject {
    pub at: Point2,
    pub radius: f64,
    pub label: String,
    /// The object's footprint; a circle of `radius` when empty.
    pub outline: Vec<Point2>,
}

/// A restricted region and its floor colour (CSS colour, e.g. "#d22").
#[derive(Clone, Debug, PartialEq)]
pub struct PlotZone {
    pub polygon: Vec<Point2>,
    pub colour: String,
}

/// Everything one plot shows, world frame, metres.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlotScene {
    pub title: String,
    pub obstacles: Vec<Vec<Point2>>,
    pub zones: Vec<PlotZone>,
    pub cables: Vec<Vec<Point2>>,
    pub objects: Vec<PlotObject>,
    pub start: Pose,
    pub destination: Point2,
    pub success_radius: f64,
    pub true_path: Vec<Point2>,
    pub odom_path: Vec<Point2>,
    pub subgoals: Vec<Point2>,
    pub target_estimates: Vec<Point2>,
    /// Where the robot was while touching something (hard contact).
    pub hard_contacts: Vec<Point2>,
}

struct Frame {
    min: Point2,
    scale: f64,
    height_px: f64,
}

impl Frame {
    fn px(&self, p: Point2) -> (f64, f64) {
        // World y up → SVG y down.
        ((p.x - self.min.x) * self.scale + MARGIN_PX, self.height_px - ((p.y - self.min.y) * self.scale + MARGIN_PX))
    }
}

const WIDTH_PX: f64 = 900.0;
const MARGIN_PX: f64 = 20.0;
const LEGEND_PX: f64 = 120.0;

/// Splits `text` into lines of at most `width` characters at spaces.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split(' ') {
        if !line.is_empty() && line.chars().count() + 1 + word.chars().count() > width {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    lines.push(line);
    lines
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn points_attr(frame: &Frame, pts: &[Point2]) -> String {
    let mut s = String::new();
    for p in pts {
        let (x, y) = frame.px(*p);
        let _ = write!(s, "{x:.1},{y:.1} ");
    }
    s.trim_end().to_string()
}

fn bounds(scene: &PlotScene) -> (Point2, Point2) {
    let mut min = Point2::new(f64::INFINITY, f64::INFINITY);
    let mut max = Point2::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut add = |p: Point2, r: f64| {
        if p.x.is_finite() && p.y.is_finite() {
            min.x = min.x.min(p.x - r);
            min.y = min.y.min(p.y - r);
            max.x = max.x.max(p.x + r);
            max.y = max.y.max(p.y + r);
        }
    };
    for poly in scene.obstacles.iter().chain(scene.zones.iter().map(|z| &z.polygon)).chain(scene.cables.iter()) {
        for p in poly {
            add(*p, 0.0);
        }
    }
    for o in &scene.objects {
        add(o.at, o.radius);
    }
    for p in scene.true_path.iter().chain(&scene.odom_path).chain(&scene.subgoals).chain(&scene.target_estimates) {
        add(*p, 0.0);
    }
    add(scene.start.position().into(), 0.5);
    add(scene.destination, scene.success_radius);
    if !min.x.is_finite() {
        return (Point2::new(-1.0, -1.0), Point2::new(1.0, 1.0));
    }
    (Point2::new(min.x - 0.5, min.y - 0.5), Point2::new(max.x + 0.5, max.y + 0.5))
}

/// Renders the scene as a standalone SVG document.
pub fn render_svg(scene: &PlotScene) -> String {
    let (min, max) = bounds(scene);
    let span_x = (max.x - min.x).max(1.0);
    let span_y = (max.y - min.y).max(1.0);
    let scale = (WIDTH_PX - 2.0 * MARGIN_PX) / span_x;
    let plot_h = span_y * scale + 2.0 * MARGIN_PX;
    let frame = Frame { min, scale, height_px: plot_h };
    let total_h = plot_h + LEGEND_PX + 16.0 * (wrap(&scene.title, 115).len().max(1) - 1) as f64;

    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH_PX:.0}" height="{total_h:.0}" viewBox="0 0 {WIDTH_PX:.0} {total_h:.0}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r##"<rect width="100%" height="100%" fill="#fafafa"/>"##);
    let _ = writeln!(s, "<title>{}</title>", escape(&scene.title));

    // One-metre grid.
    let _ = writeln!(s, r##"<g stroke="#e4e4e4" stroke-width="1">"##);
    let mut gx = min.x.ceil();
    while gx <= max.x {
        let (x0, y0) = frame.px(Point2::new(gx, min.y));
        let (x1, y1) = frame.px(Point2::new(gx, max.y));
        let _ = writeln!(s, r#"<line x1="{x0:.1}" y1="{y0:.1}" x2="{x1:.1}" y2="{y1:.1}"/>"#);
        gx += 1.0;
    }
    let mut gy = min.y.ceil();
    while gy <= max.y {
        let (x0, y0) = frame.px(Point2::new(min.x, gy));
        let (x1, y1) = frame.px(Point2::new(max.x, gy));
        let _ = writeln!(s, r#"<line x1="{x0:.1}" y1="{y0:.1}" x2="{x1:.1}" y2="{y1:.1}"/>"#);
        gy += 1.0;
    }
    let _ = writeln!(s, "</g>");

    for z in &scene.zones {
        let _ = writeln!(
            s,
            r#"<polygon class="zone" points="{}" fill="{}" fill-opacity="0.35" stroke="{}" stroke-width="1.5"/>"#,
            points_attr(&frame, &z.polygon),
            escape(&z.colour),
            escape(&z.colour)
        );
    }
    for o in &scene.obstacles {
        let _ = writeln!(
            s,
            r##"<polygon class="obstacle" points="{}" fill="#444" stroke="#222"/>"##,
            points_attr(&frame, o)
        );
    }
    for c in &scene.cables {
        let _ = writeln!(
            s,
            r##"<polyline class="cable" points="{}" fill="none" stroke="#8a5a00" stroke-width="3" stroke-dasharray="2 3"/>"##,
            points_attr(&frame, c)
        );
    }
    for o in &scene.objects {
        let (x, y) = frame.px(o.at);
        let r = (o.radius * scale).max(3.0);
        if o.outline.len() >= 3 {
            let _ = write!(
                s,
                r##"<polygon class="object" points="{}" fill="#6aa84f" stroke="#38761d"/>"##,
                points_attr(&frame, &o.outline)
            );
        } else {
            let _ = write!(
                s,
                r##"<circle class="object" cx="{x:.1}" cy="{y:.1}" r="{r:.1}" fill="#6aa84f" stroke="#38761d"/>"##
            );
        }
        let _ = writeln!(
            s,
            r##"<text x="{:.1}" y="{:.1}" fill="#274e13">{}</text>"##,
            x + r + 2.0,
            y - 2.0,
            escape(&o.label)
        );
    }

    // Success circle around the destination.
    let (dx, dy) = frame.px(scene.destination);
    let _ = writeln!(
        s,
        r##"<circle class="destination" cx="{dx:.1}" cy="{dy:.1}" r="{:.1}" fill="#ffd966" fill-opacity="0.35" stroke="#bf9000" stroke-dasharray="4 3"/>"##,
        scene.success_radius * scale
    );

    if scene.odom_path.len() > 1 {
        let _ = writeln!(
            s,
            r##"<polyline class="odom-path" points="{}" fill="none" stroke="#e69138" stroke-width="2" stroke-dasharray="6 4"/>"##,
            points_attr(&frame, &scene.odom_path)
        );
    }
    if scene.true_path.len() > 1 {
        let _ = writeln!(
            s,
            r##"<polyline class="true-path" points="{}" fill="none" stroke="#1155cc" stroke-width="2.5"/>"##,
            points_attr(&frame, &scene.true_path)
        );
    }
    for p in &scene.hard_contacts {
        let (x, y) = frame.px(*p);
        let _ = writeln!(
            s,
            r##"<path class="hard-contact" d="M{:.1} {:.1}L{:.1} {:.1}M{:.1} {:.1}L{:.1} {:.1}" stroke="#cc0000" stroke-width="2"/>"##,
            x - 4.0,
            y - 4.0,
            x + 4.0,
            y + 4.0,
            x - 4.0,
            y + 4.0,
            x + 4.0,
            y - 4.0
        );
    }
    for p in &scene.target_estimates {
        let (x, y) = frame.px(*p);
        let _ = writeln!(
            s,
            r##"<circle class="target-estimate" cx="{x:.1}" cy="{y:.1}" r="3" fill="#f1c232" stroke="#7f6000" stroke-width="0.5"/>"##
        );
    }
    for (i, p) in scene.subgoals.iter().enumerate() {
        let (x, y) = frame.px(*p);
        let _ = writeln!(
            s,
            r##"<rect class="subgoal" x="{:.1}" y="{:.1}" width="9" height="9" fill="#cc0000"/><text x="{:.1}" y="{:.1}" fill="#990000">G{}</text>"##,
            x - 4.5,
            y - 4.5,
            x + 6.0,
            y + 12.0,
            i + 1
        );
    }
    // Start: a triangle pointing along the start heading.
    let st = scene.start;
    let corner = |x: f64, y: f64| Point2::from(st.transform(&Point2::new(x, y).into()));
    let (tip, left, right) = (corner(0.6, 0.0), corner(-0.3, 0.3), corner(-0.3, -0.3));
    let _ = writeln!(
        s,
        r##"<polygon class="start" points="{}" fill="#1155cc" stroke="#0b3d91"/>"##,
        points_attr(&frame, &[tip, left, right])
    );

    // Legend.
    let title_lines = wrap(&scene.title, 115);
    let mut ly = plot_h + 18.0;
    for line in &title_lines {
        let _ = writeln!(s, r#"<text x="{MARGIN_PX}" y="{ly:.0}" font-weight="bold">{}</text>"#, escape(line));
        ly += 16.0;
    }
    ly -= 16.0;
    let items: [(&str, &str); 9] = [
        (r##"<line x1="0" y1="0" x2="24" y2="0" stroke="#1155cc" stroke-width="2.5"/>"##, "true path"),
        (
            r##"<line x1="0" y1="0" x2="24" y2="0" stroke="#e69138" stroke-width="2" stroke-dasharray="6 4"/>"##,
            "odometry path",
        ),
        (r##"<rect x="7" y="-4.5" width="9" height="9" fill="#cc0000"/>"##, "subgoal reached"),
        (r##"<circle cx="12" cy="0" r="3" fill="#f1c232" stroke="#7f6000"/>"##, "target estimate"),
        (r##"<path d="M8 -4L16 4M8 4L16 -4" stroke="#cc0000" stroke-width="2"/>"##, "hard contact"),
        (r##"<rect x="0" y="-6" width="24" height="12" fill="#444"/>"##, "structure"),
        (r##"<rect x="0" y="-6" width="24" height="12" fill="#cc0000" fill-opacity="0.35"/>"##, "no-go zone"),
        (r##"<circle cx="12" cy="0" r="6" fill="#6aa84f"/>"##, "object"),
        (
            r##"<circle cx="12" cy="0" r="6" fill="#ffd966" stroke="#bf9000" stroke-dasharray="4 3"/>"##,
            "success radius",
        ),
    ];
    for (i, (glyph, label)) in items.iter().enumerate() {
        let col = (i % 4) as f64;
        let row = (i / 4) as f64;
        let x = MARGIN_PX + col * 215.0;
        let y = ly + 26.0 + row * 24.0;
        let _ = writeln!(s, r#"<g transform="translate({x:.0},{y:.0})">{glyph}<text x="30" y="4">{label}</text></g>"#);
    }
    let _ = writeln!(
        s,
        r##"<text x="{MARGIN_PX}" y="{:.0}" fill="#666">grid 1 m; world frame, x right, y up</text>"##,
        ly + 90.0
    );
    s.push_str("</svg>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> PlotScene {
        PlotScene {
            title: "Indoor <trial 0>".into(),
            obstacles: vec![vec![Point2::new(2.0, 1.0), Point2::new(3.0, 1.0), Point2::new(3.0, 2.0)]],
            zones: vec![PlotZone {
                polygon: vec![Point2::new(4.0, -1.0), Point2::new(5.0, -1.0), Point2::new(5.0, 0.0)],
                colour: "#d22".into(),
            }],
            cables: vec![vec![Point2::new(1.0, -2.0), Point2::new(2.0, -2.0)]],
            objects: vec![
                PlotObject { at: Point2::new(8.0, 0.0), radius: 0.4, label: "chair".into(), outline: vec![] },
                PlotObject {
                    at: Point2::new(6.0, 2.0),
                    radius: 0.5,
                    label: "bench".into(),
                    outline: vec![
                        Point2::new(5.5, 1.8),
                        Point2::new(6.5, 1.8),
                        Point2::new(6.5, 2.2),
                        Point2::new(5.5, 2.2),
                    ],
                },
            ],
            start: Pose::new(0.0, 0.0, 0.0),
            destination: Point2::new(8.0, 0.0),
            success_radius: 1.5,
            true_path: vec![Point2::new(0.0, 0.0), Point2::new(6.6, 0.1)],
            odom_path: vec![Point2::new(0.0, 0.0), Point2::new(6.5, 0.3)],
            subgoals: vec![Point2::new(6.6, 0.1)],
            target_estimates: vec![Point2::new(8.1, 0.1), Point2::new(7.9, -0.1)],
            hard_contacts: vec![Point2::new(6.6, 0.1)],
        }
    }

    #[test]
    fn every_layer_is_drawn() {
        let svg = render_svg(&scene());
        assert!(svg.starts_with("<svg"));
        assert!(svg.trim_end().ends_with("</svg>"));
        for class in
            ["zone", "obstacle", "cable", "object", "destination", "odom-path", "true-path", "subgoal", "start"]
        {
            assert!(svg.contains(&format!("class=\"{class}\"")), "missing {class}");
        }
        assert_eq!(svg.matches("class=\"target-estimate\"").count(), 2);
        assert_eq!(svg.matches("class=\"hard-contact\"").count(), 1);
        assert_eq!(svg.matches("class=\"object\"").count(), 2, "a circle and an outline");
        assert!(svg.contains("Indoor &lt;trial 0&gt;"), "titles are escaped");
    }

    #[test]
    fn world_y_up_is_svg_y_down() {
        let f = Frame { min: Point2::new(0.0, 0.0), scale: 10.0, height_px: 100.0 };
        let (_, low) = f.px(Point2::new(0.0, 0.0));
        let (_, high) = f.px(Point2::new(0.0, 5.0));
        assert!(high < low);
    }

    #[test]
    fn everything_fits_inside_the_canvas() {
        let sc = scene();
        let (min, max) = bounds(&sc);
        for p in sc.true_path.iter().chain(&sc.target_estimates) {
            assert!(p.x > min.x && p.x < max.x && p.y > min.y && p.y < max.y);
        }
        // The success circle is inside too.
        assert!(max.x >= sc.destination.x + sc.success_radius);
    }

    #[test]
    fn long_titles_wrap_at_spaces() {
        let lines = wrap("aaa bbb ccc ddd", 7);
        assert_eq!(lines, vec!["aaa bbb", "ccc ddd"]);
        assert_eq!(wrap("", 10), vec![""]);
    }

    #[test]
    fn an_empty_scene_still_renders() {
        let svg = render_svg(&PlotScene::default());
        assert!(svg.contains("class=\"start\""));
    }
}
