//! ReID on real photos with DeepSORT's MobileNetV2 weights: augmented crops
//! of one person are closer to each other than to anyone else, and the
//! service identifies enrolled people in the original frames.

mod common;

use common::{augmented_crop, boxes, photo, require, start};
use vlnav_proto::v1::{BoundingBox, EnrollPersonRequest, IdentifyRequest, Image, ImageEncoding, RgbdFrame};
use vlnav_reid::embedder::{Embedder, ModelKind, default_device};
use vlnav_reid::gallery::cosine;

fn people() -> Vec<(&'static str, &'static str, [f32; 4])> {
    let mut v = Vec::new();
    v.extend(boxes::BUS.iter().map(|(n, b)| ("bus.jpg", *n, *b)));
    v.extend(boxes::ZIDANE.iter().map(|(n, b)| ("zidane.jpg", *n, *b)));
    v.extend(boxes::BIKE.iter().map(|(n, b)| ("bike.jpg", *n, *b)));
    v
}

#[test]
fn augmented_crops_of_one_person_are_closer_than_crops_of_others() {
    let weights = require("reid/mobilenetv2.safetensors");
    let embedder = Embedder::load(ModelKind::MobileNetV2, &weights, &default_device()).unwrap();
    let people = people();
    let (mut first, mut second) = (Vec::new(), Vec::new());
    for (i, (file, _, b)) in people.iter().enumerate() {
        let img = photo(file);
        first.push(augmented_crop(&img, *b, 10 + i as u64, false));
        second.push(augmented_crop(&img, *b, 1000 + i as u64, true));
    }
    let a = embedder.embed_images(&first).unwrap();
    let b = embedder.embed_images(&second).unwrap();
    for e in a.iter().chain(&b) {
        assert_eq!(e.len(), 1280);
        let norm: f32 = e.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-4, "embeddings are L2-normalised, got norm {norm}");
    }
    let (mut min_same, mut max_other) = (f32::MAX, f32::MIN);
    for (i, (_, name, _)) in people.iter().enumerate() {
        let same = cosine(&a[i], &b[i]);
        let (other, closest) = (0..people.len())
            .filter(|&j| j != i)
            .flat_map(|j| [(cosine(&a[i], &b[j]), j), (cosine(&a[i], &a[j]), j)])
            .fold((f32::MIN, 0), |m, x| if x.0 > m.0 { x } else { m });
        println!("{name:>18}: same person {same:.3}, closest other {other:.3} ({})", people[closest].1);
        assert!(same > other, "{name}: its two crops score {same:.3}, but {} scores {other:.3}", people[closest].1);
        min_same = min_same.min(same);
        max_other = max_other.max(other);
    }
    println!(
        "same-person similarity ≥ {min_same:.3}; different people ≤ {max_other:.3}; default threshold {}",
        vlnav_reid::MOBILENETV2_THRESHOLD
    );
}

fn jpeg_frame(file: &str) -> RgbdFrame {
    let bytes = std::fs::read(require(&format!("photos/{file}"))).unwrap();
    RgbdFrame {
        stamp: 1.0,
        rgb: Some(Image { width: 0, height: 0, encoding: ImageEncoding::Jpeg as i32, data: bytes.into() }),
        ..Default::default()
    }
}

fn png(img: &image::RgbImage) -> Image {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png).unwrap();
    Image {
        width: img.width(),
        height: img.height(),
        encoding: ImageEncoding::Png as i32,
        data: buf.into_inner().into(),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_service_names_enrolled_people_in_the_original_photos() {
    require("reid/mobilenetv2.safetensors");
    let data = tempfile::tempdir().unwrap();
    let opts = vlnav_reid::Options {
        models_dir: common::models_dir(),
        data_dir: data.path().to_path_buf(),
        ..Default::default()
    };
    let mut running = start(&opts).await;
    // Enroll the bus.jpg and zidane.jpg people from two mirrored, jittered crops each.
    let enrolled: Vec<_> = people().into_iter().filter(|(f, _, _)| *f != "bike.jpg").collect();
    for (i, (file, name, b)) in enrolled.iter().enumerate() {
        let img = photo(file);
        let images = vec![
            png(&augmented_crop(&img, *b, 50 + i as u64, true)),
            png(&augmented_crop(&img, *b, 70 + i as u64, true)),
        ];
        let r = running
            .client
            .enroll_person(EnrollPersonRequest { name: name.to_string(), images })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.embeddings, 2);
        assert_eq!(r.gallery_size, i as u32 + 1);
    }
    for file in ["bus.jpg", "zidane.jpg"] {
        let mine: Vec<_> = enrolled.iter().filter(|(f, _, _)| *f == file).collect();
        // Boxes a detector might give: the hand-drawn ones shrunk by 3 %.
        let boxes = mine
            .iter()
            .map(|(_, _, b)| {
                let (dx, dy) = (0.03 * (b[2] - b[0]), 0.03 * (b[3] - b[1]));
                BoundingBox {
                    x_min: b[0] + dx,
                    y_min: b[1] + dy,
                    x_max: b[2] - dx,
                    y_max: b[3] - dy,
                    class_id: 0,
                    score: 0.9,
                    label: "person".into(),
                }
            })
            .collect();
        let r = running
            .client
            .identify(IdentifyRequest { frame: Some(jpeg_frame(file)), boxes, threshold: 0.0, name: String::new() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.identities.len(), mine.len());
        for (id, (_, name, _)) in r.identities.iter().zip(&mine) {
            println!("{file}: box {} → {:?} {:.3} matched={}", id.box_index, id.name, id.similarity, id.matched);
            assert!(id.matched, "{name} not recognised: best {:?} at {:.3}", id.name, id.similarity);
            assert_eq!(id.name, *name);
        }
    }
    // The bike riders were never enrolled: nobody may be matched to them.
    let boxes = boxes::BIKE
        .iter()
        .map(|(_, b)| BoundingBox {
            x_min: b[0],
            y_min: b[1],
            x_max: b[2],
            y_max: b[3],
            class_id: 0,
            score: 0.9,
            label: "person".into(),
        })
        .collect();
    let r = running
        .client
        .identify(IdentifyRequest { frame: Some(jpeg_frame("bike.jpg")), boxes, threshold: 0.0, name: String::new() })
        .await
        .unwrap()
        .into_inner();
    for id in &r.identities {
        println!("bike.jpg: box {} → best {:?} {:.3} matched={}", id.box_index, id.name, id.similarity, id.matched);
        assert!(!id.matched, "unenrolled rider {} matched as {:?} at {:.3}", id.box_index, id.name, id.similarity);
    }
    running.stop().await.unwrap();
}
