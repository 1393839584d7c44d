//! The segmenter over a real socket on synthetic RGB-D frames ray-cast from
//! a known scene: a floor with a red zone and a yellow hazard-tape line, and
//! a wall carrying a red poster above the floor; optionally a red post
//! standing on the floor and stereo-like depth noise.

use nalgebra::{Rotation3, Vector3};
use tonic::Code;
use vlnav_geometry::camera::{Camera, Intrinsics, Mount};
use vlnav_geometry::convert::camera_to_proto;
use vlnav_proto::v1::segmenter_service_client::SegmenterServiceClient;
use vlnav_proto::v1::{
    DepthImage, FrameInputs, GetSegmenterInfoRequest, Image, ImageEncoding, LabelImage, LabelInstance, Point3,
    RgbdFrame, SegmentRequest,
};
use vlnav_runtime::ServerConfig;
use vlnav_runtime::testing::{self, Connected};

const W: u32 = 640;
const H: u32 = 480;
/// The D455 intrinsics used on the real robot (docs/design.md §1).
const K: (f64, f64, f64, f64) = (388.6187, 388.6187, 320.6609, 239.7847);
/// Camera 0.6 m up, 0.3 m ahead of base_link, pitched 0.35 rad down.
const MOUNT: ([f64; 3], f64) = ([0.3, 0.0, 0.6], 0.35);

/// The red floor zone (x, y ranges in base_link, metres).
const ZONE: ([f64; 2], [f64; 2]) = ([2.0, 2.5], [-0.25, 0.25]);
/// A yellow tape line across the floor.
const TAPE: ([f64; 2], [f64; 2]) = ([3.0, 3.1], [-1.0, 1.0]);
/// The wall plane x = 4 m and the red poster on it (y, z ranges).
const WALL_X: f64 = 4.0;
const POSTER: ([f64; 2], [f64; 2]) = ([-0.5, 0.5], [0.8, 1.3]);
/// A red post standing on the floor, its face the plane x = 3.5 m (y, z
/// ranges): the foot of a red fire hydrant, a walker's red trousers.
const POST_X: f64 = 3.5;
const POST: ([f64; 2], [f64; 2]) = ([0.6, 0.9], [0.0, 0.8]);

#[derive(Clone, Copy, PartialEq)]
enum Surface {
    Floor,
    Zone,
    Tape,
    Wall,
    Poster,
    Post,
}

/// Renders RGB, depth (mm) and per-pixel surfaces by casting each pixel's ray.
fn render() -> (Vec<u8>, Vec<u8>, Vec<Option<Surface>>) {
    render_with(false, 0.0)
}

/// `render`, with the red post if `post`, and each depth off by ±1.5 σ,
/// σ = `noise_k`·z² (the D455's growth with range, docs/perception.md),
/// the sign alternating between blocks of 8 × 8 pixels (a stereo
/// matcher's error is shared by the pixels of one matching window).
fn render_with(post: bool, noise_k: f64) -> (Vec<u8>, Vec<u8>, Vec<Option<Surface>>) {
    let rot = Rotation3::from_euler_angles(0.0, MOUNT.1, 0.0);
    let origin = Vector3::from(MOUNT.0);
    let (mut rgb, mut depth, mut surf) = (Vec::new(), Vec::new(), Vec::new());
    let inside = |v: f64, r: [f64; 2]| v >= r[0] && v <= r[1];
    for v in 0..H {
        for u in 0..W {
            let optical = Vector3::new((u as f64 - K.2) / K.0, (v as f64 - K.3) / K.1, 1.0);
            // optical → body: (z, −x, −y)
            let dir = rot * Vector3::new(optical.z, -optical.x, -optical.y);
            let t_floor = if dir.z < 0.0 { -origin.z / dir.z } else { f64::INFINITY };
            let t_wall = if dir.x > 0.0 { (WALL_X - origin.x) / dir.x } else { f64::INFINITY };
            let t_post = if post && dir.x > 0.0 {
                let t = (POST_X - origin.x) / dir.x;
                let p = origin + dir * t;
                if inside(p.y, POST.0) && inside(p.z, POST.1) { t } else { f64::INFINITY }
            } else {
                f64::INFINITY
            };
            let t = t_floor.min(t_wall).min(t_post);
            let (colour, s, mm) = if t.is_finite() && t < 20.0 {
                let p = origin + dir * t;
                let s = if t == t_post {
                    Surface::Post
                } else if t_floor < t_wall {
                    if inside(p.x, ZONE.0) && inside(p.y, ZONE.1) {
                        Surface::Zone
                    } else if inside(p.x, TAPE.0) && inside(p.y, TAPE.1) {
                        Surface::Tape
                    } else {
                        Surface::Floor
                    }
                } else if inside(p.y, POSTER.0) && inside(p.z, POSTER.1) {
                    Surface::Poster
                } else {
                    Surface::Wall
                };
                let colour = match s {
                    Surface::Floor => [150, 150, 145],
                    Surface::Zone | Surface::Poster | Surface::Post => [205, 25, 30],
                    Surface::Tape => [235, 200, 20],
                    Surface::Wall => [210, 200, 180],
                };
                // t is the optical depth because the optical ray has z = 1.
                let sign = if (u / 8 + v / 8) % 2 == 0 { -1.5 } else { 1.5 };
                let z = t + sign * noise_k * t * t;
                (colour, Some(s), (z * 1000.0).round() as u16)
            } else {
                ([90, 120, 200], None, 0)
            };
            rgb.extend_from_slice(&colour);
            depth.extend_from_slice(&mm.to_le_bytes());
            surf.push(s);
        }
    }
    (rgb, depth, surf)
}

fn frame(rgb: Vec<u8>, depth: Vec<u8>) -> RgbdFrame {
    RgbdFrame {
        robot_id: "husky-1".into(),
        seq: 1,
        stamp: 12.5,
        camera: Some(camera_to_proto(&Camera {
            width: W,
            height: H,
            intrinsics: Intrinsics { fx: K.0, fy: K.1, cx: K.2, cy: K.3 },
            mount: Mount { translation: Vector3::from(MOUNT.0), roll: 0.0, pitch: MOUNT.1, yaw: 0.0 },
            depth_min_m: 0.4,
            depth_max_m: 12.0,
        })),
        rgb: Some(Image { width: W, height: H, encoding: ImageEncoding::Rgb8 as i32, data: rgb.into() }),
        depth: Some(DepthImage { width: W, height: H, data_mm: depth.into(), encoding: 0, disparity_step: 0.0 }),
        ..Default::default()
    }
}

async fn start(opts: vlnav_segmenter::Options) -> Connected<SegmenterServiceClient<tonic::transport::Channel>> {
    let cfg = ServerConfig::default();
    let set = vlnav_segmenter::services(&opts, &cfg).await.unwrap();
    let make =
        |ch| SegmenterServiceClient::new(ch).max_decoding_message_size(64 << 20).max_encoding_message_size(64 << 20);
    testing::start_client(&cfg, set, make).await.unwrap()
}

#[tokio::test]
async fn a_red_floor_zone_becomes_a_wall_of_points_where_it_lies_and_the_poster_does_not() {
    let (rgb, depth, surf) = render();
    let s = start(Default::default()).await;
    let mut client = s.client.clone();
    let r = client
        .segment(SegmentRequest { frame: Some(frame(rgb, depth)), classes: vec![], return_mask: true, point_stride: 2 })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.backend, "colour");
    assert_eq!(r.classes, vec!["restricted_zone", "hazard", "cable"]);
    assert_eq!((r.width, r.height, r.mask.len()), (W, H, (W * H) as usize));
    let count = |s: Surface| surf.iter().filter(|x| **x == Some(s)).count();
    let (zone_px, poster_px, tape_px) = (count(Surface::Zone), count(Surface::Poster), count(Surface::Tape));
    assert!(zone_px > 2000 && poster_px > 2000 && tape_px > 500, "scene visible: {zone_px} {poster_px} {tape_px}");
    // The mask holds the zone (class 1) and the tape (class 2), never the poster.
    let mut confusion = [[0usize; 4]; 5];
    for (m, s) in r.mask.iter().zip(&surf) {
        let row = match s {
            Some(Surface::Zone) => 0,
            Some(Surface::Tape) => 1,
            Some(Surface::Poster) => 2,
            Some(Surface::Floor) | Some(Surface::Wall) | Some(Surface::Post) => 3,
            None => 4,
        };
        confusion[row][*m as usize] += 1;
    }
    assert!(confusion[0][1] as f64 >= 0.98 * zone_px as f64, "zone recall: {confusion:?}");
    assert!(confusion[1][2] as f64 >= 0.95 * tape_px as f64, "tape recall: {confusion:?}");
    assert_eq!(confusion[2][1], 0, "the wall poster is not a floor zone: {confusion:?}");
    assert_eq!(confusion[3].iter().skip(1).sum::<usize>(), 0, "plain floor and wall are not hazards: {confusion:?}");
    assert_eq!(r.class_pixels[0] as usize, confusion.iter().map(|row| row[1]).sum::<usize>());

    // Points: every restricted-zone point lies over the zone, at the stacked heights.
    let tol = 0.05;
    let zone_pts: Vec<&Point3> = r.virtual_points.iter().filter(|p| p.x < 2.8).collect();
    let tape_pts: Vec<&Point3> = r.virtual_points.iter().filter(|p| p.x >= 2.8).collect();
    assert!(zone_pts.len() > 300, "{} zone points", zone_pts.len());
    assert_eq!(zone_pts.len() % 3, 0);
    for p in &zone_pts {
        assert!(
            p.x > ZONE.0[0] - tol && p.x < ZONE.0[1] + tol && p.y > ZONE.1[0] - tol && p.y < ZONE.1[1] + tol,
            "{p:?}"
        );
        assert!([0.0, 0.25, 0.5].iter().any(|z| (p.z - z).abs() < 1e-9), "{p:?}");
    }
    for p in &tape_pts {
        assert!(p.x > TAPE.0[0] - tol && p.x < TAPE.0[1] + tol && p.y.abs() < 1.0 + tol, "{p:?}");
    }
    let n = zone_pts.len() as f64;
    let (mx, my) = (zone_pts.iter().map(|p| p.x).sum::<f64>() / n, zone_pts.iter().map(|p| p.y).sum::<f64>() / n);
    assert!((mx - 2.25).abs() < 0.06 && my.abs() < 0.03, "zone centre ({mx:.3}, {my:.3})");
    // Stride 2 keeps about a quarter of the zone's pixels, three points each.
    let expect = confusion[0][1] as f64 / 4.0 * 3.0;
    assert!((n - expect).abs() < 0.1 * expect, "{n} points for {expect:.0} expected");
    s.stop().await.unwrap();
}

#[tokio::test]
async fn the_foot_of_a_red_post_is_no_zone_and_depth_noise_does_not_move_the_zone() {
    // The post's lowest 10 cm are red and within the floor tolerance, but
    // the surface rises there: not a marking. With the D455's depth off by
    // 1.5 σ, the zone's points still lie over the zone: on the floor the
    // pixel's ray places them.
    let (rgb, depth, surf) = render_with(true, 0.005);
    let s = start(Default::default()).await;
    let r = s
        .client
        .clone()
        .segment(SegmentRequest { frame: Some(frame(rgb, depth)), classes: vec![], return_mask: true, point_stride: 1 })
        .await
        .unwrap()
        .into_inner();
    let post_px = surf.iter().filter(|x| **x == Some(Surface::Post)).count();
    assert!(post_px > 2000, "the post is in view: {post_px} px");
    // Marked: only where the ray grazes the post's corner with the floor
    // above it in the image (a pixel of the post's silhouette edge).
    let w = W as usize;
    let marked: Vec<usize> = (0..surf.len()).filter(|&i| surf[i] == Some(Surface::Post) && r.mask[i] != 0).collect();
    assert!(marked.iter().all(|&i| i < w || surf[i - w] != Some(Surface::Post)), "only silhouette edges: {marked:?}");
    assert!(marked.len() * 100 < post_px, "{} of {post_px} post pixels marked", marked.len());
    let zone_px = r.mask.iter().zip(&surf).filter(|(m, s)| **s == Some(Surface::Zone) && **m == 1).count();
    assert!(zone_px > 2000, "the zone is still found: {zone_px} px");
    // Placed by the ray, a zone pixel's point lies over the zone exactly;
    // placed by its depth, 1.5 σ (3.8 cm at 2.25 m) would move it off.
    let tol = 0.01;
    for p in r.virtual_points.iter().filter(|p| p.x < 2.8) {
        assert!(
            p.x > ZONE.0[0] - tol && p.x < ZONE.0[1] + tol && p.y > ZONE.1[0] - tol && p.y < ZONE.1[1] + tol,
            "{p:?} off the zone"
        );
    }
    let at_post =
        r.virtual_points.iter().filter(|p| p.x > TAPE.0[1] + tol && p.y > POST.0[0] - tol && p.y < POST.0[1] + tol);
    assert!(at_post.count() <= 3 * marked.len(), "points at the post's foot come only from its edge pixels");
    s.stop().await.unwrap();
}

#[tokio::test]
async fn class_selection_stride_and_mask_flag_are_honoured() {
    let (rgb, depth, _) = render();
    let s = start(Default::default()).await;
    let mut client = s.client.clone();
    let req = SegmentRequest {
        frame: Some(frame(rgb, depth)),
        classes: vec!["hazard".into()],
        return_mask: false,
        point_stride: 0,
    };
    let r = client.segment(req.clone()).await.unwrap().into_inner();
    assert_eq!(r.classes, vec!["hazard"]);
    assert!(r.mask.is_empty(), "no mask unless asked");
    assert!(r.class_pixels[0] > 500);
    assert!(r.virtual_points.iter().all(|p| p.x >= TAPE.0[0] - 0.05), "only the tape is reported");
    let coarse = client.segment(SegmentRequest { point_stride: 8, ..req.clone() }).await.unwrap().into_inner();
    assert!(coarse.virtual_points.len() * 3 < r.virtual_points.len(), "stride 8 thins the default stride 4");
    let err = client.segment(SegmentRequest { classes: vec!["lava".into()], ..req }).await.unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("classes[0]") && err.message().contains("restricted_zone"), "{}", err.message());
    s.stop().await.unwrap();
}

#[tokio::test]
async fn malformed_frames_get_invalid_argument_naming_the_field() {
    let (rgb, depth, _) = render();
    let s = start(Default::default()).await;
    let mut client = s.client.clone();
    let good = frame(rgb.clone(), depth.clone());
    let with = |f: &dyn Fn(&mut RgbdFrame)| {
        let mut fr = good.clone();
        f(&mut fr);
        SegmentRequest { frame: Some(fr), classes: vec![], return_mask: false, point_stride: 0 }
    };
    let cases: Vec<(SegmentRequest, &str)> = vec![
        (
            with(&|f| {
                f.rgb = Some(Image {
                    width: 320,
                    height: 240,
                    encoding: ImageEncoding::Rgb8 as i32,
                    data: vec![0; 320 * 240 * 3].into(),
                })
            }),
            "frame.rgb",
        ),
        (with(&|f| f.rgb.as_mut().unwrap().data = vec![0; (W * H * 4) as usize].into()), "4-channel"),
        (with(&|f| f.depth.as_mut().unwrap().width = 320), "frame.depth"),
        (with(&|f| f.depth.as_mut().unwrap().data_mm.truncate(1000)), "frame.depth.data_mm"),
        (with(&|f| f.depth = None), "frame.depth"),
        (with(&|f| f.camera.as_mut().unwrap().intrinsics.as_mut().unwrap().fx = 0.0), "intrinsics"),
        (with(&|f| f.camera = None), "frame.camera"),
        (with(&|f| f.rgb.as_mut().unwrap().encoding = ImageEncoding::Png as i32), "cannot decode the PNG"),
        (SegmentRequest { frame: None, classes: vec![], return_mask: false, point_stride: 0 }, "frame"),
        (SegmentRequest { point_stride: 100_000, ..with(&|_| {}) }, "point_stride"),
    ];
    for (req, needle) in cases {
        let err = client.segment(req).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{needle}: {err:?}");
        assert!(err.message().contains(needle), "{needle:?} not in {:?}", err.message());
    }
    // A PNG-encoded colour image of the right size is accepted.
    let mut png = std::io::Cursor::new(Vec::new());
    image::RgbImage::from_raw(W, H, rgb).unwrap().write_to(&mut png, image::ImageFormat::Png).unwrap();
    let req = with(&|f| {
        f.rgb =
            Some(Image { width: 0, height: 0, encoding: ImageEncoding::Png as i32, data: png.get_ref().clone().into() })
    });
    let r = client.segment(req).await.unwrap().into_inner();
    assert!(r.class_pixels[0] > 2000);
    s.stop().await.unwrap();
}

#[tokio::test]
async fn the_simulation_backend_reads_semantics_from_the_label_image() {
    let (rgb, depth, surf) = render();
    let s = start(vlnav_segmenter::Options { backend: "sim".into(), ..Default::default() }).await;
    let mut client = s.client.clone();
    // Label the zone as restricted_zone (id 7) and the poster too (id 8, as if
    // mislabelled): only the floor one survives the floor check.
    let ids: Vec<u8> = surf
        .iter()
        .flat_map(|s| {
            let id: u16 = match s {
                Some(Surface::Zone) => 7,
                Some(Surface::Poster) => 8,
                Some(_) => 1,
                None => 0,
            };
            id.to_le_bytes()
        })
        .collect();
    let inst = |id, semantic: &str| LabelInstance {
        instance_id: id,
        class_id: -1,
        identity: String::new(),
        semantic: semantic.into(),

        ..Default::default()
    };
    let mut f = frame(rgb.iter().map(|_| 128).collect(), depth);
    f.labels = Some(LabelImage {
        width: W,
        height: H,
        instance_ids: ids.into(),
        instances: vec![inst(1, "floor"), inst(7, "restricted_zone"), inst(8, "restricted_zone")],
    });
    let r = client
        .segment(SegmentRequest { frame: Some(f.clone()), classes: vec![], return_mask: true, point_stride: 3 })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.backend, "sim");
    let zone_px = surf.iter().filter(|s| **s == Some(Surface::Zone)).count();
    assert_eq!(r.class_pixels[0] as usize, zone_px);
    assert!(!r.virtual_points.is_empty());
    assert!(r.virtual_points.iter().all(|p| p.x > ZONE.0[0] - 0.05 && p.x < ZONE.0[1] + 0.05));
    // It says it reads labels and depth, and a frame cut to them gives the same answer.
    let info = client.get_segmenter_info(GetSegmenterInfoRequest {}).await.unwrap().into_inner();
    assert_eq!(info.backend, "sim");
    assert_eq!(info.inputs, Some(FrameInputs { rgb: false, depth: true, labels: true }));
    let cut = RgbdFrame { rgb: None, ..f.clone() };
    let same = client
        .segment(SegmentRequest { frame: Some(cut), classes: vec![], return_mask: true, point_stride: 3 })
        .await
        .unwrap()
        .into_inner();
    assert_eq!((same.mask, same.virtual_points), (r.mask, r.virtual_points));
    f.labels = None;
    let err = client
        .segment(SegmentRequest { frame: Some(f), classes: vec![], return_mask: false, point_stride: 0 })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("frame.labels"));
    s.stop().await.unwrap();
}

#[tokio::test]
async fn a_bad_class_table_or_backend_fails_at_start() {
    let dir = std::env::temp_dir().join(format!("vlnav-seg-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("classes.json");
    std::fs::write(&path, r#"[{"name": "blue_zone", "ranges": [{"h": [100, 200], "s": [0, 255], "v": [0, 255]}]}]"#)
        .unwrap();
    let opts = vlnav_segmenter::Options { classes_file: Some(path.clone()), ..Default::default() };
    let err = vlnav_segmenter::services(&opts, &ServerConfig::default()).await.err().expect("H > 180 is refused");
    assert!(err.to_string().contains("H ≤ 180"), "{err}");
    std::fs::write(&path, r#"[{"name": "blue_zone", "ranges": [{"h": [100, 130], "s": [100, 255], "v": [50, 255]}]}]"#)
        .unwrap();
    let opts = vlnav_segmenter::Options { classes_file: Some(path), ..Default::default() };
    assert!(vlnav_segmenter::services(&opts, &ServerConfig::default()).await.is_ok());
    let opts = vlnav_segmenter::Options { backend: "esanet".into(), ..Default::default() };
    assert!(vlnav_segmenter::services(&opts, &ServerConfig::default()).await.is_err());
    let _ = std::fs::remove_dir_all(dir);
}
