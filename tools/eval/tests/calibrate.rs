//! `vlnav calibrate-perception` on the real NanoDet, the real MobileNetV2 and
//! the registry's real photos, in small (72 canvases, about a hundred objects).

use std::path::PathBuf;

use vlnav_eval::calibrate::{self, CalibrateArgs, HEIGHT_BINS};
use vlnav_runtime::perception::Profile;

fn models_dir() -> PathBuf {
    let dir = std::env::var_os("VLNAV_MODELS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"));
    for f in ["nanodet/nanodet.safetensors", "reid/mobilenetv2.safetensors", "photos/bus.jpg"] {
        assert!(
            dir.join(f).is_file(),
            "{} is missing: run deploy/fetch-models.sh (it fetches the models and the test photos)",
            dir.join(f).display()
        );
    }
    dir
}

#[test]
fn a_small_calibration_on_the_real_photos_measures_a_valid_profile() {
    let out = tempfile::tempdir().unwrap();
    let args = CalibrateArgs {
        models_dir: models_dir(),
        canvases: 72,
        seed: 5,
        out: out.path().join("p.toml"),
        date: Some("2026-01-01".into()),
    };
    let summary = calibrate::run(&args).expect("the calibration runs");
    println!("{summary}");
    let text = std::fs::read_to_string(&args.out).unwrap();
    assert!(text.starts_with("# Perception error model"), "a provenance header");
    let p = Profile::parse(&text).expect("the written profile parses and validates");
    assert_eq!(p.provenance.tool, "vlnav calibrate-perception");
    assert_eq!(p.provenance.canvases, 72);
    assert_eq!(p.provenance.weights_sha256.len(), 64);
    // Up to three per canvas, where they fit beside the background's own objects.
    assert!(p.provenance.objects >= 72, "objects pasted: {}", p.provenance.objects);
    let d = &p.detector;
    assert_eq!(d.height_px, HEIGHT_BINS.to_vec());
    // People are in most photos: the person class is measured.
    assert!(d.class.iter().any(|c| c.class_id == 0 && c.samples.iter().sum::<u32>() > 5), "{:?}", d.class);
    // The detector sees big objects far more often than tiny ones.
    assert!(d.recall_all[0] < d.recall_all[HEIGHT_BINS.len() - 1], "{:?}", d.recall_all);
    assert!(d.recall_all[HEIGHT_BINS.len() - 1] >= 0.5, "{:?}", d.recall_all);
    assert!(d.iou_mean > 0.5 && d.iou_mean <= 1.0);
    let r = p.reid.as_ref().expect("a ReID section");
    assert!(r.same[5] > r.different[5], "same person {:?} vs different {:?}", r.same, r.different);
    assert!(r.same_pairs > 0 && r.different_pairs > r.same_pairs);

    // The same seed measures the same profile.
    let again = calibrate::calibrate(&CalibrateArgs { out: out.path().join("q.toml"), ..args.clone() }).unwrap();
    assert_eq!(again, p);
}

#[test]
fn missing_models_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let args = CalibrateArgs { models_dir: dir.path().to_path_buf(), canvases: 1, ..CalibrateArgs::default() };
    let e = format!("{:#}", calibrate::run(&args).unwrap_err());
    assert!(e.contains("nanodet") && e.contains("fetch-models"), "{e}");
}

#[test]
fn the_committed_profile_is_the_tools_output() {
    let text = include_str!("../../../deploy/perception/nanodet-realistic.toml");
    let p = Profile::parse(text).unwrap();
    assert_eq!(text, calibrate::profile_file(&p), "deploy/perception/nanodet-realistic.toml was edited by hand");
    assert!(p.provenance.canvases >= 200, "the shipped profile comes from a full calibration run");
}
