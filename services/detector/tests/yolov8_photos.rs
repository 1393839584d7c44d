//! The trained YOLOv8s (classes Normal and Fall, both reported as COCO person)
//! through the gRPC service and through `vlnav detect`'s library function, on
//! the registry's real photos; user models whose class names do not fit.

mod common;

use common::*;
use tonic::Code;
use vlnav_detector::cli::{DetectArgs, PhotoBackend, run_detect};
use vlnav_detector::{BackendKind, Options};
use vlnav_proto::v1;

const PERSON: i32 = 0;

fn people(boxes: &[v1::BoundingBox]) -> Vec<&v1::BoundingBox> {
    boxes.iter().filter(|b| b.class_id == PERSON).collect()
}

fn centre_inside(b: &v1::BoundingBox, (x0, y0, x1, y1): (f32, f32, f32, f32)) -> bool {
    let (cx, cy) = ((b.x_min + b.x_max) / 2.0, (b.y_min + b.y_max) / 2.0);
    (x0..=x1).contains(&cx) && (y0..=y1).contains(&cy)
}

#[tokio::test]
async fn trained_yolov8s_finds_the_people_over_grpc() {
    let mut svc = start(trained_yolo_options()).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!((info.backend.as_str(), info.model.as_str(), info.input_width), ("yolov8", "yolov8s", 640));
    assert_eq!(info.classes, vec!["Normal", "Fall"]);

    let mut detect = async |name: &str, class_ids: Vec<i32>| {
        let resp = svc.client.detect(request(photo_frame(name), class_ids, 0.0)).await.unwrap().into_inner();
        assert_eq!(resp.backend, "yolov8");
        resp.boxes
    };
    // Every box is a person (class 0) that keeps the model's class name.
    for name in ["bus.jpg", "zidane.jpg", "astronaut.png", "bike.jpg"] {
        let boxes = detect(name, vec![]).await;
        assert!(
            boxes.iter().all(|b| b.class_id == PERSON && ["Normal", "Fall"].contains(&b.label.as_str())),
            "{name}: {boxes:#?}"
        );
    }
    // bus.jpg (810×1080): the three people standing in front of the bus, upright, "Normal".
    let bus = detect("bus.jpg", vec![PERSON]).await;
    let standing: Vec<_> = people(&bus).into_iter().filter(|b| b.label == "Normal" && b.x_min > 20.0).collect();
    assert!(standing.len() >= 3, "{bus:#?}");
    for b in &standing {
        assert!(b.y_max - b.y_min > 1.5 * (b.x_max - b.x_min) && b.y_max > 800.0, "{b:?}");
    }
    // zidane.jpg (1280×720): the two men, left and right of centre.
    let zidane = detect("zidane.jpg", vec![]).await;
    let men = people(&zidane);
    assert!(men.iter().any(|b| centre_inside(b, (0.0, 0.0, 640.0, 720.0))), "{zidane:#?}");
    assert!(men.iter().any(|b| centre_inside(b, (640.0, 0.0, 1280.0, 720.0))), "{zidane:#?}");
    // astronaut.png (512×512): one person filling much of the picture.
    let astronaut = detect("astronaut.png", vec![]).await;
    let best = astronaut.iter().max_by(|a, b| a.score.total_cmp(&b.score)).expect("the astronaut");
    assert!(best.score >= 0.4 && (best.x_max - best.x_min) * (best.y_max - best.y_min) > 0.2 * 512.0 * 512.0);
    // FIND chair: the model knows no chairs, so nothing comes back.
    assert!(detect("bus.jpg", vec![56]).await.is_empty());
    svc.stop().await.unwrap();
}

#[test]
fn vlnav_detect_prints_and_draws_the_people() {
    let dir = tempfile::tempdir().unwrap();
    let photos: Vec<_> = ["bus.jpg", "zidane.jpg"].iter().map(|n| require(&format!("photos/{n}"))).collect();
    let out_dir = dir.path().join("annotated");
    let args = DetectArgs {
        backend: PhotoBackend::Yolov8,
        out: Some(out_dir.clone()),
        models_dir: models_dir(),
        ..DetectArgs::new(photos.clone())
    };
    let mut text = Vec::new();
    let results = run_detect(&args, &mut text).unwrap();
    let text = String::from_utf8(text).unwrap();
    assert!(text.lines().count() >= 5, "{text}");
    assert!(
        text.lines().all(|l| l.contains("→ person") && (l.contains("bus.jpg") || l.contains("zidane.jpg"))),
        "{text}"
    );
    for (r, photo) in results.iter().zip(&photos) {
        assert!(r.detections.len() >= 2, "{r:?}");
        let drawn = image::open(r.annotated.as_ref().unwrap()).unwrap().into_rgb8();
        let original = image::open(photo).unwrap().into_rgb8();
        assert_eq!(drawn.dimensions(), original.dimensions());
        assert_ne!(drawn, original, "boxes are drawn");
    }
    // JSON: one document with every photo and box.
    let mut json = Vec::new();
    run_detect(&DetectArgs { json: true, out: None, ..args }, &mut json).unwrap();
    let doc: serde_json::Value = serde_json::from_slice(&json).unwrap();
    assert_eq!(doc.as_array().unwrap().len(), 2);
    assert_eq!(doc[0]["model"], "yolov8s");
    assert_eq!(doc[0]["detections"][0]["coco_class"], "person");
    assert!(["Normal", "Fall"].contains(&doc[0]["detections"][0]["label"].as_str().unwrap()));
}

#[tokio::test]
async fn class_names_that_do_not_fit_the_head_fail_at_start() {
    let trained = trained_yolo_options();
    let dir = tempfile::tempdir().unwrap();
    let three = dir.path().join("three.yaml");
    std::fs::write(&three, "names: [standing, sitting, lying]\n").unwrap();
    let opts = Options { yolo_names: Some(three), ..trained.clone() };
    let err = vlnav_detector::services(&opts, &Default::default()).await.err().expect("must fail").to_string();
    assert!(err.contains("three.yaml names 3 classes") && err.contains("has 2"), "{err}");

    // Two-class weights with no names file beside them.
    let copy = dir.path().join("mine.safetensors");
    std::fs::copy(trained.yolo_weights_path(), &copy).unwrap();
    let opts = Options { backend: BackendKind::Yolov8, yolo_weights: Some(copy), ..Default::default() };
    let err = vlnav_detector::services(&opts, &Default::default()).await.err().expect("must fail").to_string();
    assert!(
        err.contains("mine.safetensors") && err.contains("2 classes") && err.contains("--detector-yolo-names"),
        "{err}"
    );

    // A names file beside the weights is found; JSON works as well as YAML.
    std::fs::write(dir.path().join("mine.names.json"), r#"{"names": {"0": "upright", "1": "down"}, "coco": {"0": 0}}"#)
        .unwrap();
    let mut svc = start(opts).await;
    let info = svc.client.get_model_info(v1::GetModelInfoRequest {}).await.unwrap().into_inner();
    assert_eq!(info.classes, vec!["upright", "down"]);
    let boxes = svc.client.detect(request(photo_frame("bus.jpg"), vec![], 0.0)).await.unwrap().into_inner().boxes;
    assert!(boxes.iter().any(|b| b.label == "upright" && b.class_id == PERSON), "{boxes:#?}");
    assert!(boxes.iter().filter(|b| b.label == "down").all(|b| b.class_id == -1), "{boxes:#?}");
    let e = svc.client.detect(request(photo_frame("bus.jpg"), vec![80], 0.0)).await.unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    svc.stop().await.unwrap();
}
