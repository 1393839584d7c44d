//! The ReID service over a real socket: validation, status codes, the
//! persistent gallery, and the simulation backend.

mod common;

use common::start;
use tonic::Code;
use vlnav_proto::v1::{
    BoundingBox, EmbedRequest, EnrollPersonRequest, IdentifyRequest, Image, ImageEncoding, LabelImage, LabelInstance,
    ListGalleryRequest, RemovePersonRequest, RgbdFrame,
};

fn sim_opts(dir: &std::path::Path) -> vlnav_reid::Options {
    // The oracle: identities as labelled (the realistic draws are tested in `sim.rs`).
    vlnav_reid::Options {
        backend: "sim".into(),
        sim_profile: "oracle".into(),
        data_dir: dir.to_path_buf(),
        ..Default::default()
    }
}

fn rgb8(w: u32, h: u32) -> Image {
    Image { width: w, height: h, encoding: ImageEncoding::Rgb8 as i32, data: vec![128; (w * h * 3) as usize].into() }
}

fn bx(x0: f32, y0: f32, x1: f32, y1: f32) -> BoundingBox {
    BoundingBox { x_min: x0, y_min: y0, x_max: x1, y_max: y1, class_id: 0, score: 0.9, label: "person".into() }
}

/// A 40×20 label image: ana (id 2) fills x 0–9, bo (id 3) x 20–29, an
/// unnamed person (id 4) x 30–39, a wall (id 1) the rest.
fn labelled_frame() -> RgbdFrame {
    let (w, h) = (40u32, 20u32);
    let mut ids = Vec::with_capacity((w * h * 2) as usize);
    for _y in 0..h {
        for x in 0..w {
            let id: u16 = match x {
                0..=9 => 2,
                20..=29 => 3,
                30..=39 => 4,
                _ => 1,
            };
            ids.extend_from_slice(&id.to_le_bytes());
        }
    }
    let inst = |id, class_id, identity: &str, semantic: &str| LabelInstance {
        instance_id: id,
        class_id,
        identity: identity.into(),
        semantic: semantic.into(),

        ..Default::default()
    };
    RgbdFrame {
        stamp: 3.5,
        rgb: Some(rgb8(w, h)),
        labels: Some(LabelImage {
            width: w,
            height: h,
            instance_ids: ids.into(),
            instances: vec![
                inst(1, -1, "", "wall"),
                inst(2, 0, "ana", "object"),
                inst(3, 0, "bo", "object"),
                inst(4, 0, "", "object"),
            ],
        }),
        ..Default::default()
    }
}

#[tokio::test]
async fn bad_requests_get_invalid_argument_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = start(&sim_opts(dir.path())).await;
    let enroll = |name: &str, images: Vec<Image>| EnrollPersonRequest { name: name.into(), images };
    let cases = [
        (enroll("", vec![rgb8(4, 4)]), "name"),
        (enroll("ana", vec![]), "images"),
        (enroll("ana", vec![Image { data: vec![0; 4 * 4 * 4].into(), ..rgb8(4, 4) }]), "4-channel"),
        (enroll("ana", vec![Image { data: vec![0; 10].into(), ..rgb8(4, 4) }]), "images[0].data"),
        (
            enroll(
                "ana",
                vec![Image {
                    width: 0,
                    height: 0,
                    encoding: ImageEncoding::Jpeg as i32,
                    data: vec![0xFF, 0xD8, 0xFF, 0xE0, 0, 16].into(),
                }],
            ),
            "cannot decode the JPEG",
        ),
        (enroll("ana", vec![Image { encoding: ImageEncoding::Unspecified as i32, ..rgb8(4, 4) }]), "encoding"),
    ];
    for (req, needle) in cases {
        let err = s.client.enroll_person(req).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
        assert!(err.message().contains(needle), "{needle:?} not in {:?}", err.message());
    }
    // A PNG whose declared size disagrees with its content.
    let mut png = std::io::Cursor::new(Vec::new());
    image::RgbImage::new(5, 3).write_to(&mut png, image::ImageFormat::Png).unwrap();
    let img = Image { width: 6, height: 3, encoding: ImageEncoding::Png as i32, data: png.into_inner().into() };
    let err = s.client.enroll_person(enroll("ana", vec![img])).await.unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("decodes to 5×3, but the request says 6×3"), "{}", err.message());

    s.client.enroll_person(enroll("ana", vec![rgb8(4, 4)])).await.unwrap();
    let identify =
        |boxes, threshold| IdentifyRequest { frame: Some(labelled_frame()), boxes, threshold, name: String::new() };
    for (req, needle) in [
        (identify(vec![bx(0.0, 0.0, 5.0, 5.0), bx(50.0, 0.0, 60.0, 10.0)], 0.0), "boxes[1]"),
        (identify(vec![bx(5.0, 0.0, 2.0, 5.0)], 0.0), "boxes[0]"),
        (identify(vec![bx(f32::NAN, 0.0, 2.0, 5.0)], 0.0), "finite"),
        (identify(vec![bx(0.0, 0.0, 5.0, 5.0)], 1.5), "threshold"),
        (IdentifyRequest { frame: None, ..identify(vec![], 0.0) }, "frame"),
    ] {
        let err = s.client.identify(req).await.unwrap_err();
        assert_eq!(err.code(), Code::InvalidArgument, "{err:?}");
        assert!(err.message().contains(needle), "{needle:?} not in {:?}", err.message());
    }
    let mut frame = labelled_frame();
    frame.labels.as_mut().unwrap().instance_ids.truncate(100);
    let err = s
        .client
        .identify(IdentifyRequest {
            frame: Some(frame),
            boxes: vec![bx(0.0, 0.0, 5.0, 5.0)],
            threshold: 0.0,
            name: String::new(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("frame.labels.instance_ids"), "{}", err.message());
    s.stop().await.unwrap();
}

#[tokio::test]
async fn an_empty_gallery_unknown_names_and_embeddings_on_sim_are_state_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = start(&sim_opts(dir.path())).await;
    let req = IdentifyRequest {
        frame: Some(labelled_frame()),
        boxes: vec![bx(0.0, 0.0, 10.0, 20.0)],
        threshold: 0.0,
        name: String::new(),
    };
    let err = s.client.identify(req.clone()).await.unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition);
    assert!(err.message().contains("EnrollPerson"), "{}", err.message());
    let err = s.client.remove_person(RemovePersonRequest { name: "nobody".into() }).await.unwrap_err();
    assert_eq!(err.code(), Code::NotFound);
    s.client.enroll_person(EnrollPersonRequest { name: "ana".into(), images: vec![rgb8(2, 2)] }).await.unwrap();
    let err = s.client.identify(IdentifyRequest { name: "carl".into(), ..req }).await.unwrap_err();
    assert_eq!(err.code(), Code::NotFound);
    assert!(err.message().contains("carl"));
    let err = s.client.embed(EmbedRequest { images: vec![rgb8(2, 2)] }).await.unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition);
    s.stop().await.unwrap();
}

#[tokio::test]
async fn the_simulation_backend_reads_identities_under_each_box() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = start(&sim_opts(dir.path())).await;
    for name in ["ana", "bo"] {
        s.client.enroll_person(EnrollPersonRequest { name: name.into(), images: vec![rgb8(2, 2)] }).await.unwrap();
    }
    let boxes = vec![
        bx(0.0, 0.0, 10.0, 20.0),  // ana only
        bx(5.0, 0.0, 25.0, 20.0),  // ana 5 columns, bo 5 columns → tie, lower id (ana), purity 0.5
        bx(18.0, 0.0, 36.0, 20.0), // bo 10 columns, unnamed 6 → bo, purity 10/16
        bx(30.0, 0.0, 40.0, 20.0), // the unnamed person
        bx(10.0, 0.0, 20.0, 20.0), // wall only
    ];
    let r = s
        .client
        .identify(IdentifyRequest {
            frame: Some(labelled_frame()),
            boxes: boxes.clone(),
            threshold: 0.0,
            name: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    let got: Vec<_> = r
        .identities
        .iter()
        .map(|i| (i.box_index, i.name.as_str(), i.matched, (i.similarity * 1000.0).round() / 1000.0))
        .collect();
    assert_eq!(
        got,
        vec![
            (0, "ana", true, 1.0),
            (1, "ana", true, 0.5),
            (2, "bo", true, 0.625),
            (3, "", false, 0.0),
            (4, "", false, 0.0)
        ]
    );
    // A stricter threshold rejects the mixed boxes; a name filter ignores everyone else.
    let r = s
        .client
        .identify(IdentifyRequest {
            frame: Some(labelled_frame()),
            boxes: boxes.clone(),
            threshold: 0.7,
            name: "bo".into(),
        })
        .await
        .unwrap()
        .into_inner();
    let matched: Vec<_> = r.identities.iter().map(|i| i.matched).collect();
    assert_eq!(matched, vec![false, false, false, false, false]);
    let r = s
        .client
        .identify(IdentifyRequest { frame: Some(labelled_frame()), boxes, threshold: 0.6, name: "bo".into() })
        .await
        .unwrap()
        .into_inner();
    let named: Vec<_> = r.identities.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(named, vec!["", "", "bo", "", ""]);
    // Without labels the simulation backend cannot answer.
    let mut frame = labelled_frame();
    frame.labels = None;
    let err = s
        .client
        .identify(IdentifyRequest {
            frame: Some(frame),
            boxes: vec![bx(0.0, 0.0, 4.0, 4.0)],
            threshold: 0.0,
            name: String::new(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("frame.labels"));
    s.stop().await.unwrap();
}

#[tokio::test]
async fn the_gallery_survives_a_restart_and_removal_persists() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = start(&sim_opts(dir.path())).await;
    s.client
        .enroll_person(EnrollPersonRequest { name: "ana".into(), images: vec![rgb8(2, 2), rgb8(3, 3)] })
        .await
        .unwrap();
    let r = s
        .client
        .enroll_person(EnrollPersonRequest { name: " bo ".into(), images: vec![rgb8(2, 2)] })
        .await
        .unwrap()
        .into_inner();
    assert_eq!((r.name.as_str(), r.embeddings, r.gallery_size), ("bo", 1, 2));
    s.stop().await.unwrap();

    let mut s = start(&sim_opts(dir.path())).await;
    let people = s.client.list_gallery(ListGalleryRequest {}).await.unwrap().into_inner().people;
    let got: Vec<_> = people.iter().map(|p| (p.name.as_str(), p.embeddings)).collect();
    assert_eq!(got, vec![("ana", 2), ("bo", 1)]);
    let left = s.client.remove_person(RemovePersonRequest { name: "ana".into() }).await.unwrap().into_inner().people;
    assert_eq!(left.len(), 1);
    s.stop().await.unwrap();

    let mut s = start(&sim_opts(dir.path())).await;
    let people = s.client.list_gallery(ListGalleryRequest {}).await.unwrap().into_inner().people;
    assert_eq!(people.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(), vec!["bo"]);
    s.stop().await.unwrap();
    assert!(dir.path().join("gallery-sim.json").is_file());
}

#[tokio::test]
async fn a_missing_model_fails_at_start_naming_the_setup_step() {
    let dir = tempfile::tempdir().unwrap();
    let opts = vlnav_reid::Options {
        models_dir: dir.path().join("no-models"),
        data_dir: dir.path().into(),
        ..Default::default()
    };
    let err = vlnav_reid::services(&opts, &Default::default()).await.err().expect("must fail");
    let msg = format!("{err:#}");
    assert!(msg.contains("deploy/fetch-models.sh") && msg.contains("mobilenetv2.safetensors"), "{msg}");
    let opts = vlnav_reid::Options { backend: "resnet".into(), ..opts };
    let err = vlnav_reid::services(&opts, &Default::default()).await.err().expect("must fail");
    assert!(err.to_string().contains("unknown ReID backend"), "{err}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn embed_returns_unit_mobilenetv2_vectors() {
    common::require("reid/mobilenetv2.safetensors");
    let dir = tempfile::tempdir().unwrap();
    let opts =
        vlnav_reid::Options { models_dir: common::models_dir(), data_dir: dir.path().into(), ..Default::default() };
    let mut s = start(&opts).await;
    let img = |v: u8| Image {
        width: 8,
        height: 16,
        encoding: ImageEncoding::Rgb8 as i32,
        data: (0..8 * 16 * 3).map(|i| (i as u8).wrapping_mul(v)).collect(),
    };
    let r = s.client.embed(EmbedRequest { images: vec![img(3), img(7)] }).await.unwrap().into_inner();
    assert_eq!(r.model, "mobilenetv2");
    assert_eq!(r.embeddings.len(), 2);
    for e in &r.embeddings {
        assert_eq!(e.values.len(), 1280);
        let n: f32 = e.values.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((n - 1.0).abs() < 1e-4);
    }
    // Empty gallery with a real model: FAILED_PRECONDITION too.
    let frame = RgbdFrame { rgb: Some(img(3)), ..Default::default() };
    let err = s
        .client
        .identify(IdentifyRequest {
            frame: Some(frame),
            boxes: vec![bx(0.0, 0.0, 4.0, 8.0)],
            threshold: 0.0,
            name: String::new(),
        })
        .await
        .unwrap_err();
    assert_eq!(err.code(), Code::FailedPrecondition);
    s.stop().await.unwrap();
}
