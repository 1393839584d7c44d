//! The D455 depth error model (noise growing with the square of range,
//! dropouts beyond the reliable range, stereo occlusion holes at depth
//! edges) and the visible fraction the renderer reports per instance.

use vlnav_sim::{Pose2, Simulator, World, scenario};

fn world(text: &str) -> World {
    scenario::parse(text).unwrap_or_else(|e| panic!("test scenario invalid: {e}"))
}

/// A wide wall facing the camera at optical depth `z` (the camera sits 0.30 m ahead of base_link).
fn wall_at(z: f64, extra: &str) -> World {
    let x = z + 0.30;
    world(&format!(
        r#"
name = "wall"
[robot]
start = [0.0, 0.0, 0.0]
{extra}
[[obstacles]]
name = "wall ahead"
polygon = [[{x}, -15.0], [{x2}, -15.0], [{x2}, 15.0], [{x}, 15.0]]
height = 3.0
color = [150, 150, 150]
"#,
        x2 = x + 0.02
    ))
}

/// Depths (m) of the middle rows of the central columns, over `frames` renders.
fn centre_depths(w: World, frames: usize) -> (Vec<f64>, usize) {
    let mut sim = Simulator::new(w, 3);
    let (mut out, mut holes) = (Vec::new(), 0);
    for _ in 0..frames {
        let f = sim.render();
        for v in f.height / 2 - 20..f.height / 2 - 5 {
            for u in f.width / 2 - 40..f.width / 2 + 40 {
                let (_, d, _) = f.pixel(u, v);
                if d == 0 {
                    holes += 1;
                } else {
                    out.push(f64::from(d) / 1000.0);
                }
            }
        }
    }
    (out, holes)
}

#[test]
fn depth_noise_is_two_percent_rms_at_four_metres_and_grows_with_the_square_of_range() {
    let rms = |z: f64| {
        let (d, holes) = centre_depths(wall_at(z, ""), 4);
        assert_eq!(holes, 0, "no dropouts within the reliable range");
        (d.iter().map(|x| (x - z) * (x - z)).sum::<f64>() / d.len() as f64).sqrt()
    };
    let at4 = rms(4.0);
    assert!((at4 / 4.0 - 0.02).abs() < 0.002, "RMS at 4 m {at4:.4} m ({:.2} %)", 100.0 * at4 / 4.0);
    let at2 = rms(2.0);
    // σ ∝ z²: a quarter at half the range.
    assert!((at2 / at4 - 0.25).abs() < 0.04, "RMS at 2 m {at2:.4} vs 4 m {at4:.4}");
}

#[test]
fn beyond_the_reliable_range_pixels_lose_their_depth() {
    // 8 m: half way from 6 to 10 m → a quarter of the pixels without depth.
    let (d, holes) = centre_depths(wall_at(8.0, ""), 4);
    let share = holes as f64 / (holes + d.len()) as f64;
    assert!((share - 0.25).abs() < 0.03, "{share}");
}

const NEAR_AND_FAR: &str = r#"
name = "edge"
[robot]
start = [0.0, 0.0, 0.0]
[camera]
depth_noise_k = 0.0
[[obstacles]]
name = "far wall"
polygon = [[5.8, -15.0], [5.82, -15.0], [5.82, 15.0], [5.8, 15.0]]
height = 3.0
color = [150, 150, 150]
[[objects]]
name = "near box"
class_id = 56
position = [2.5, 0.0]
shape = "box"
size = [0.4, 1.0]
height = 1.5
color = [200, 120, 40]
"#;

#[test]
fn a_near_edge_leaves_a_stereo_occlusion_hole_on_its_left() {
    let mut sim = Simulator::new(world(NEAR_AND_FAR), 1);
    let f = sim.render();
    let cam = sim.camera().clone();
    // The row at the camera's height: it meets the box (1.5 m high) at 2.3 m
    // and the wall (3 m high, inside the reliable range) at 5.8 m, never the floor.
    let v = cam.cy as u32;
    let row: Vec<u16> = (0..f.width).map(|u| f.pixel(u, v).1).collect();
    // The box's left edge: first column (from the left) with the box's depth.
    let edge = row.iter().position(|&d| (2000..2400).contains(&d)).expect("the box is in view");
    let band = (cam.fx * 0.095 * (1.0 / 2.3 - 1.0 / 5.8)).round() as usize;
    assert!(band >= 5, "{band}");
    assert!(row[edge - band..edge].iter().all(|&d| d == 0), "{:?}", &row[edge - band - 2..edge + 1]);
    assert!(row[edge - band - 2] > 5000, "the wall keeps its depth beyond the band: {:?}", &row[edge - band - 3..edge]);
    // The box's right edge steps *back* to the wall: no hole there.
    let right = row.iter().rposition(|&d| (2000..2400).contains(&d)).unwrap();
    assert!(row[right + 1] > 5000 && row[right + 2] > 5000, "{:?}", &row[right..right + 3]);

    // The baseline set to 0 turns the holes off.
    let mut w = world(NEAR_AND_FAR);
    w.camera.stereo_baseline_m = 0.0;
    let f = Simulator::new(w, 1).render();
    assert!((0..f.width).all(|u| f.pixel(u, v).1 > 0));
}

#[test]
fn the_visible_fraction_counts_occlusion_and_the_image_border() {
    let text = r#"
name = "vis"
[robot]
start = [0.0, 0.0, 0.0]
[[objects]]
name = "whole"
class_id = 56
position = [4.3, 1.0]
shape = "box"
size = [0.4, 0.4]
height = 0.8
color = [200, 120, 40]
[[objects]]
name = "behind"
class_id = 58
position = [6.3, -1.0]
shape = "box"
size = [0.4, 0.8]
height = 1.0
color = [40, 160, 40]
[[objects]]
name = "in front"
class_id = 13
position = [3.3, -0.35]
shape = "box"
size = [0.2, 0.4]
height = 2.0
color = [90, 60, 30]
[[objects]]
name = "at the border"
class_id = 0
position = [2.3, 2.0]
shape = "box"
size = [0.4, 0.6]
height = 1.7
color = [20, 20, 120]
"#;
    let w = world(text);
    let mut sim = Simulator::new(w.clone(), 1);
    sim.set_camera(sim.camera().clone().with_resolution(320, 240).unwrap());
    let f = sim.render();
    let vis = |name: &str| {
        let i = f.instances.iter().position(|e| e.name == name).unwrap_or_else(|| panic!("{name} not in view"));
        f.visible_fraction[i]
    };
    assert_eq!(f.visible_fraction.len(), f.instances.len());
    assert!(vis("whole") > 0.9, "{}", vis("whole"));
    let behind = vis("behind");
    assert!((0.2..0.8).contains(&behind), "half hidden behind the post: {behind}");
    assert!(vis("in front") > 0.9, "{}", vis("in front"));
    let border = vis("at the border");
    assert!(border < 0.8, "cut by the left border: {border}");
    let _ = Pose2::new(0.0, 0.0, 0.0);
}
