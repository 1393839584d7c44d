//! Criterion benches of the audio front end (decode, resample, trim).

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vlnav_ingress::audio::{SampleEncoding, decode_wav, encode_wav};
use vlnav_ingress::resample::resample;
use vlnav_ingress::trim::{TrimConfig, speech_range};

fn ten_seconds(rate: u32) -> Vec<f32> {
    (0..rate as usize * 10).map(|i| ((i as f32) * 0.031).sin() * 0.3 * ((i / 4000) % 2) as f32).collect()
}

fn front_end(c: &mut Criterion) {
    let x44 = ten_seconds(44_100);
    let x22 = ten_seconds(22_050);
    let x16 = ten_seconds(16_000);
    let wav = encode_wav(&x44.iter().flat_map(|s| [*s, *s]).collect::<Vec<_>>(), 2, 44_100, SampleEncoding::I16);
    c.bench_function("decode_wav_10s_44k1_stereo", |b| b.iter(|| decode_wav(black_box(&wav)).unwrap()));
    c.bench_function("resample_10s_44k1_to_16k", |b| b.iter(|| resample(black_box(&x44), 44_100, 16_000)));
    c.bench_function("resample_10s_22k05_to_16k", |b| b.iter(|| resample(black_box(&x22), 22_050, 16_000)));
    c.bench_function("trim_10s_16k", |b| b.iter(|| speech_range(black_box(&x16), 16_000, &TrimConfig::default())));
}

criterion_group!(benches, front_end);
criterion_main!(benches);
