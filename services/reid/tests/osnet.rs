//! OSNet x0_25 and x1_0 load torchreid-format state dicts (written here with
//! generated weights — no trained OSNet ships in any package) and produce
//! 512-d embeddings; malformed checkpoints are refused with the tensor named.

use candle_core::{Device, Tensor};
use vlnav_reid::embedder::{Embedder, LoadError, ModelKind};
use vlnav_reid::osnet::{OsnetVariant, random_state_dict, torchreid_state_dict_shapes};
use vlnav_reid::preprocess::CropBox;

fn write(path: &std::path::Path, tensors: &std::collections::HashMap<String, Tensor>) {
    candle_core::safetensors::save(tensors, path).unwrap();
}

/// Parameters of the backbone + fc (no classifier, no BN counters).
fn backbone_parameters(v: OsnetVariant) -> usize {
    torchreid_state_dict_shapes(v, 751)
        .iter()
        .filter(|(n, _)| !n.starts_with("classifier") && !n.ends_with("num_batches_tracked") && !n.contains("running_"))
        .map(|(_, s)| s.iter().product::<usize>())
        .sum()
}

#[test]
fn parameter_counts_match_the_osnet_paper() {
    // Zhou et al. 2019, Table: OSNet x1.0 has 2.2 M parameters, x0.25 0.2 M.
    let big = backbone_parameters(OsnetVariant::X1_0) as f64 / 1e6;
    let small = backbone_parameters(OsnetVariant::X0_25) as f64 / 1e6;
    println!("osnet_x1_0 {big:.3} M, osnet_x0_25 {small:.3} M parameters");
    assert!((big - 2.2).abs() < 0.1, "osnet_x1_0 has {big:.3} M parameters");
    assert!((small - 0.2).abs() < 0.05, "osnet_x0_25 has {small:.3} M parameters");
}

#[test]
fn both_variants_load_torchreid_checkpoints_and_embed_in_512_d() {
    let dir = tempfile::tempdir().unwrap();
    let img =
        image::RgbImage::from_fn(64, 160, |x, y| image::Rgb([(x * 3) as u8, (y + 40) as u8, ((x * y) % 251) as u8]));
    for variant in [OsnetVariant::X0_25, OsnetVariant::X1_0] {
        let path = dir.path().join(format!("{}.safetensors", variant.name()));
        // 751 identities: a Market-1501 classifier, which the extractor ignores.
        write(&path, &random_state_dict(variant, 751, 7, &Device::Cpu).unwrap());
        let e = Embedder::load(ModelKind::Osnet(variant), &path, &Device::Cpu).unwrap();
        let regions = [
            CropBox::full(&img),
            CropBox { x_min: 0.0, y_min: 0.0, x_max: 32.0, y_max: 80.0 },
            CropBox { x_min: 32.0, y_min: 80.0, x_max: 64.0, y_max: 160.0 },
        ];
        let out = e.embed_regions(&img, &regions).unwrap();
        assert_eq!(out.len(), 3);
        for v in &out {
            assert_eq!(v.len(), 512, "{}", variant.name());
            assert!(v.iter().all(|x| x.is_finite()));
            let norm: f32 = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-4, "norm {norm}");
        }
        let sim: f32 = out[1].iter().zip(&out[2]).map(|(a, b)| a * b).sum();
        assert!(sim < 0.9999, "different regions must embed differently ({sim})");
        // Batching does not change a crop's embedding.
        let alone = e.embed_regions(&img, &regions[1..2]).unwrap();
        let diff = alone[0].iter().zip(&out[1]).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(diff < 1e-4, "batched vs single differ by {diff}");
    }
}

#[test]
fn a_checkpoint_with_a_missing_or_misshapen_tensor_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = random_state_dict(OsnetVariant::X0_25, 10, 1, &Device::Cpu).unwrap();
    t.remove("conv3.1.gate.fc2.bias");
    let path = dir.path().join("missing.safetensors");
    write(&path, &t);
    let err = Embedder::load(ModelKind::Osnet(OsnetVariant::X0_25), &path, &Device::Cpu).err().expect("must fail");
    assert!(matches!(err, LoadError::Invalid { .. }));
    assert!(err.to_string().contains("conv3.1.gate.fc2.bias"), "{err}");

    // x1_0 weights are not x0_25 weights.
    let path = dir.path().join("big.safetensors");
    write(&path, &random_state_dict(OsnetVariant::X1_0, 10, 1, &Device::Cpu).unwrap());
    let err = Embedder::load(ModelKind::Osnet(OsnetVariant::X0_25), &path, &Device::Cpu).err().expect("must fail");
    assert!(err.to_string().contains("shape"), "{err}");

    let err = Embedder::load(ModelKind::Osnet(OsnetVariant::X1_0), &dir.path().join("nope.safetensors"), &Device::Cpu)
        .err()
        .expect("must fail");
    assert!(matches!(err, LoadError::Missing { .. }));
    assert!(err.to_string().contains("deploy/fetch-models.sh"), "{err}");
}
