//! NanoDet with its real COCO weights, through the gRPC service, on real
//! photos (fetched by deploy/fetch-models.sh): cyclists, an astronaut, a cup,
//! a cat, and a real RGB-D frame built from a Middlebury stereo pair.

mod common;

use std::io::Read;

use common::*;
use vlnav_proto::v1;

const PERSON: i32 = 0;
const BICYCLE: i32 = 1;
const MOTORCYCLE: i32 = 3;
const CAT: i32 = 15;
const CUP: i32 = 41;

async fn detect(client: &mut Running, name: &str, class_ids: Vec<i32>, min_score: f32) -> Vec<v1::BoundingBox> {
    let resp = client.client.detect(request(photo_frame(name), class_ids, min_score)).await.unwrap().into_inner();
    assert_eq!(resp.backend, "nanodet");
    resp.boxes
}

fn of_class(boxes: &[v1::BoundingBox], class: i32) -> Vec<&v1::BoundingBox> {
    boxes.iter().filter(|b| b.class_id == class).collect()
}

fn inside(b: &v1::BoundingBox, w: f32, h: f32) -> bool {
    b.x_min >= 0.0 && b.y_min >= 0.0 && b.x_max <= w && b.y_max <= h && b.x_max > b.x_min && b.y_max > b.y_min
}

#[tokio::test]
async fn cyclists_astronaut_cup_and_cat() {
    let mut svc = start(nanodet_options()).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!((info.backend.as_str(), info.input_width, info.classes.len()), ("nanodet", 416, 80));

    // bike.jpg (800×556): riders on bicycles, a motorbike.
    let boxes = detect(&mut svc, "bike.jpg", vec![], 0.3).await;
    let persons: Vec<_> = of_class(&boxes, PERSON).into_iter().filter(|b| b.score >= 0.5).collect();
    let bicycles = of_class(&boxes, BICYCLE);
    assert!(persons.len() >= 2, "persons: {boxes:#?}");
    assert!(bicycles.len() >= 2, "bicycles: {boxes:#?}");
    for b in persons.iter().chain(&bicycles) {
        assert!(inside(b, 800.0, 556.0), "{b:?}");
        assert!(b.label == vlnav_proto::coco::CLASSES[b.class_id as usize]);
    }
    // Riders are upright; each counted bicycle has a rider overlapping it.
    assert!(persons.iter().all(|p| p.y_max - p.y_min > p.x_max - p.x_min), "{persons:#?}");
    let overlaps = |a: &v1::BoundingBox, b: &v1::BoundingBox| {
        a.x_min < b.x_max && b.x_min < a.x_max && a.y_min < b.y_max && b.y_min < a.y_max
    };
    assert!(bicycles.iter().all(|c| persons.iter().any(|p| overlaps(c, p))), "{boxes:#?}");
    // The default threshold (0.4) keeps the confident riders; a class filter keeps only what was asked.
    let default = detect(&mut svc, "bike.jpg", vec![], 0.0).await;
    assert!(default.iter().all(|b| b.score >= 0.4) && of_class(&default, PERSON).len() >= 2);
    let only_bikes = detect(&mut svc, "bike.jpg", vec![BICYCLE], 0.3).await;
    assert!(!only_bikes.is_empty() && only_bikes.iter().all(|b| b.class_id == BICYCLE));

    // astronaut.png (512×512): one person, a large box around the centre.
    let boxes = detect(&mut svc, "astronaut.png", vec![], 0.0).await;
    let best = boxes.iter().max_by(|a, b| a.score.total_cmp(&b.score)).expect("a detection");
    assert_eq!(best.class_id, PERSON, "{boxes:#?}");
    assert!(best.score >= 0.5 && inside(best, 512.0, 512.0));
    assert!(
        best.x_min < 256.0
            && best.x_max > 256.0
            && (best.x_max - best.x_min) * (best.y_max - best.y_min) > 0.25 * 512.0 * 512.0,
        "{best:?}"
    );

    // coffee.png (600×400): a cup, weak for this model with letterboxing (≈0.27).
    let boxes = detect(&mut svc, "coffee.png", vec![], 0.2).await;
    let cups = of_class(&boxes, CUP);
    assert!(!cups.is_empty(), "{boxes:#?}");
    assert!(inside(cups[0], 600.0, 400.0) && cups[0].x_max - cups[0].x_min > 100.0, "{cups:?}");

    // chelsea.png (451×300): a cat.
    let boxes = detect(&mut svc, "chelsea.png", vec![], 0.0).await;
    assert!(of_class(&boxes, CAT).first().is_some_and(|c| c.score >= 0.5), "{boxes:#?}");

    // Concurrent requests are batched by the actor and each gets its own answer.
    let frames = ["astronaut.png", "chelsea.png", "bike.jpg", "astronaut.png"];
    let calls = frames.iter().map(|name| {
        let mut c = svc.client.clone();
        let req = request(photo_frame(name), vec![], 0.0);
        async move { c.detect(req).await.unwrap().into_inner().boxes }
    });
    let results = futures::future::join_all(calls).await;
    assert_eq!(results[0], results[3]);
    assert!(of_class(&results[1], CAT).len() == 1 && of_class(&results[2], PERSON).len() >= 2);
    svc.stop().await.unwrap();
}

fn median(mut v: Vec<f32>) -> f32 {
    assert!(!v.is_empty());
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

/// Middlebury 2014 "Motorcycle", downsampled ×4 as scikit-image ships it (its
/// `stereo_motorcycle` docs): f = 994.978 px, baseline 193.001 mm, principal
/// point offset between the cameras doffs = 31.086 px; Z = f·B / (d + doffs).
const FOCAL_PX: f32 = 994.978;
const BASELINE_M: f32 = 0.193001;
const DOFFS_PX: f32 = 31.086;

#[tokio::test]
async fn motorcycle_depth_from_the_stereo_ground_truth() {
    let npz = std::fs::File::open(require("photos/motorcycle_disp.npz")).unwrap();
    let mut zip = zip::ZipArchive::new(npz).unwrap();
    let index = zip.index_for_name("arr_0.npy").expect("arr_0.npy in the archive");
    let entry = zip.by_index_raw(index).unwrap();
    let mut npy = Vec::new();
    let method = entry.compression();
    if method == zip::CompressionMethod::STORE {
        entry.take(u64::MAX).read_to_end(&mut npy)
    } else if method == zip::CompressionMethod::DEFLATE {
        flate2::read::DeflateDecoder::new(entry).read_to_end(&mut npy)
    } else {
        panic!("arr_0.npy is compressed with {method:?}; expected stored or deflated")
    }
    .unwrap();
    let (shape, disparity) = parse_npy_f32(&npy);
    assert_eq!(shape, vec![500, 741]);
    let (h, w) = (shape[0], shape[1]);
    // Ground-truth depth, metres (NaN/inf disparity: no ground truth).
    let depth_m: Vec<f32> = disparity
        .iter()
        .map(|&d| if d.is_finite() && d > 0.0 { FOCAL_PX * BASELINE_M / (d + DOFFS_PX) } else { 0.0 })
        .collect();
    // The frame a D455 would deliver: u16 millimetres, 0 = no return.
    let depth_mm: Vec<u8> =
        depth_m.iter().flat_map(|&z| ((z * 1000.0).round().clamp(0.0, 65535.0) as u16).to_le_bytes()).collect();

    let mut frame = photo_frame("motorcycle_left.png");
    frame.depth = Some(v1::DepthImage {
        width: w as u32,
        height: h as u32,
        data_mm: depth_mm.clone().into(),
        encoding: 0,
        disparity_step: 0.0,
    });
    let mut svc = start(nanodet_options()).await;
    let boxes = svc.client.detect(request(frame, vec![MOTORCYCLE], 0.3)).await.unwrap().into_inner().boxes;
    svc.stop().await.unwrap();
    let moto = boxes.first().unwrap_or_else(|| panic!("no motorcycle: {boxes:?}"));
    assert_eq!(moto.class_id, MOTORCYCLE);
    // The motorcycle spans most of the frame (hand-checked extent ≈ x 95–685, y 75–450).
    let truth_box = (95.0, 75.0, 685.0, 450.0);
    let iou = {
        let iw = (moto.x_max.min(truth_box.2) - moto.x_min.max(truth_box.0)).max(0.0);
        let ih = (moto.y_max.min(truth_box.3) - moto.y_min.max(truth_box.1)).max(0.0);
        let inter = iw * ih;
        let area = |x0: f32, y0: f32, x1: f32, y1: f32| (x1 - x0) * (y1 - y0);
        inter
            / (area(moto.x_min, moto.y_min, moto.x_max, moto.y_max)
                + area(truth_box.0, truth_box.1, truth_box.2, truth_box.3)
                - inter)
    };
    assert!(iou > 0.6, "box {moto:?}, IoU with the hand-checked extent {iou}");

    // Median of the valid depth (as the subgoal estimator reads it: > 0.5 m) inside the detected box.
    let mut in_box = Vec::new();
    for y in moto.y_min.floor() as usize..(moto.y_max.ceil() as usize).min(h) {
        for x in moto.x_min.floor() as usize..(moto.x_max.ceil() as usize).min(w) {
            let mm = u16::from_le_bytes([depth_mm[2 * (y * w + x)], depth_mm[2 * (y * w + x) + 1]]);
            if mm > 500 {
                in_box.push(mm as f32 / 1000.0);
            }
        }
    }
    let measured = median(in_box);

    // Ground truth: the paper's target depth (median depth in the target's box) from the true
    // disparity over the hand-checked box.
    let region = |(x0, y0, x1, y1): (usize, usize, usize, usize)| {
        let mut v = Vec::new();
        for y in y0..y1 {
            for x in x0..x1 {
                if depth_m[y * w + x] > 0.0 {
                    v.push(depth_m[y * w + x]);
                }
            }
        }
        median(v)
    };
    let truth = region((95, 75, 685, 450));
    let rel = (measured - truth).abs() / truth;
    assert!(rel < 0.05, "median box depth {measured:.3} m vs ground truth {truth:.3} m ({:.1} %)", rel * 100.0);
    // And the estimate lies on the motorcycle: between its nearest and farthest parts
    // (headlight, front wheel, engine, seat, rear wheel; hand-marked regions of the image).
    let parts =
        [(505, 120, 565, 185), (515, 290, 680, 445), (330, 240, 470, 350), (150, 150, 350, 230), (125, 240, 275, 400)];
    let depths: Vec<f32> = parts.into_iter().map(region).collect();
    let (near, far) = depths.iter().fold((f32::MAX, 0.0f32), |(a, b), &d| (a.min(d), b.max(d)));
    assert!((near..=far).contains(&measured), "{measured:.3} m outside the motorcycle's {near:.3}–{far:.3} m");
}

/// The actor runs queued requests as one batch; a batch must give each image
/// what it gets alone.
#[test]
fn a_batched_forward_equals_single_images() {
    use vlnav_detector::detection::DetectFilter;
    use vlnav_detector::nanodet::{NanoDet, NanoDetFiles};
    nanodet_options();
    let model = NanoDet::load(&NanoDetFiles::in_dir(&models_dir().join("nanodet")), &candle_core::Device::Cpu).unwrap();
    let a = image::open(require("photos/astronaut.png")).unwrap().into_rgb8();
    let b = image::open(require("photos/chelsea.png")).unwrap().into_rgb8();
    let all = DetectFilter { class_ids: vec![], min_score: 0.3 };
    let cats = DetectFilter { class_ids: vec![CAT], min_score: 0.3 };
    let batch = model.detect(&[&a, &b], &[all.clone(), cats.clone()], 0.45).unwrap();
    let alone =
        [model.detect(&[&a], &[all], 0.45).unwrap().remove(0), model.detect(&[&b], &[cats], 0.45).unwrap().remove(0)];
    for (got, want) in batch.iter().zip(&alone) {
        assert!(!want.is_empty());
        assert_eq!(got.len(), want.len(), "{got:?} vs {want:?}");
        for (g, w) in got.iter().zip(want) {
            assert_eq!(g.class_id, w.class_id);
            assert!(
                (g.score - w.score).abs() < 1e-4
                    && (g.x_min - w.x_min).abs() < 0.05
                    && (g.y_max - w.y_max).abs() < 0.05,
                "{g:?} vs {w:?}"
            );
        }
    }
    assert!(batch[1].iter().all(|d| d.class_id == CAT));
}
