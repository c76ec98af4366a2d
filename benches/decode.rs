//! Decode throughput (Gaussians/s): `.gsc` with 1 thread and all threads, SH0 and SH3, against
//! SPZ decode of the same scene. Uses `../shared/data/scenes/k7000.ply` (or `$GSCODEC_DATA`)
//! when present, else `samples/tiny/truth.ply`.
//!
//! `decode_proxy`: the same on the 124,000-Gaussian proxy of docs/codec.md ("Encode speed at
//! scale": playbot-lod3 tiled 2 × 2, built here, nothing committed), coded as `gscodec encode`
//! does by default (RD search at λ 20); skipped without `../shared/data`. Throughput counts the
//! input's Gaussians for both codecs.
//!
//! `cargo bench --bench decode`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use gscodec::decoder::{Decoder, Splats};
use gscodec::io::ply::read_ply;
use gscodec::io::spz::{decode_spz, encode_spz, SpzVersion};
use gscodec::rate;
use std::path::Path;

#[path = "common/proxy.rs"]
mod proxy;

/// The λ of the README's SPZ comparison on k7000 (a file half the `.spz`'s size, at a higher PSNR).
const LAMBDA: f64 = 24.0;

fn scene() -> (String, Splats) {
    let k7000 = gscodec::testkit::data_dir().join("scenes/k7000.ply");
    if k7000.exists() {
        ("k7000".into(), read_ply(&k7000).unwrap())
    } else {
        ("tiny".into(), read_ply(&Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply")).unwrap())
    }
}

fn bench_decode(c: &mut Criterion) {
    let (name, sh3) = scene();
    let mut g = c.benchmark_group("decode");
    for (label, s) in [("sh3", sh3.clone()), ("sh0", sh3.with_sh_degree(0))] {
        // The configuration `gscodec encode --lambda LAMBDA` chooses (RD search over renders).
        let lambda = rate::Lambda::new(LAMBDA).expect("a valid λ");
        let (config, _) = rate::rd::search(&s, lambda, |_| {}).expect("rd search");
        let (gsc, _, _) = rate::encode(&s, &config).expect("encode");
        let spz = encode_spz(&s, SpzVersion::V4).unwrap();
        let n = s.len() as u64;
        eprintln!("{name} {label}: {n} Gaussians, .gsc {} bytes, .spz {} bytes", gsc.len(), spz.len());
        g.throughput(Throughput::Elements(n));
        for threads in [1usize, 0] {
            let id = if threads == 1 { "gsc_1_thread" } else { "gsc_all_threads" };
            let decode = |bytes: &[u8]| {
                let mut d = Decoder::new(bytes);
                d.set_threads(threads);
                d.read_info().and_then(|r| r.decode()).unwrap()
            };
            g.bench_with_input(BenchmarkId::new(id, format!("{name}_{label}")), &gsc, |b, bytes| b.iter(|| decode(bytes)));
        }
        g.bench_with_input(BenchmarkId::new("spz_v4", format!("{name}_{label}")), &spz, |b, bytes| b.iter(|| decode_spz(bytes).unwrap()));
    }
    g.finish();
}

fn bench_decode_proxy(c: &mut Criterion) {
    let playbot = gscodec::testkit::data_dir().join("scenes/playbot-lod3.ply");
    if !playbot.exists() {
        eprintln!("decode_proxy: skipped ({} not found)", playbot.display());
        return;
    }
    let s = proxy::tiled(&read_ply(&playbot).unwrap(), 2, 2);
    let (config, _) = rate::rd::search(&s, rate::Lambda::new(20.0).expect("a valid λ"), |_| {}).expect("rd search");
    let (gsc, report, _) = rate::encode(&s, &config).expect("encode");
    let spz = encode_spz(&s, SpzVersion::V4).unwrap();
    let n = s.len() as u64;
    eprintln!("proxy: {n} Gaussians ({} kept), .gsc {} bytes, .spz {} bytes", report.gaussians, gsc.len(), spz.len());
    let mut g = c.benchmark_group("decode_proxy");
    g.sample_size(10);
    g.throughput(Throughput::Elements(n));
    for threads in [1usize, 0] {
        let id = if threads == 1 { "gsc_1_thread" } else { "gsc_all_threads" };
        g.bench_with_input(BenchmarkId::new(id, "playbot_2x2"), &gsc, |b, bytes| {
            b.iter(|| {
                let mut d = Decoder::new(&bytes[..]);
                d.set_threads(threads);
                d.read_info().and_then(|r| r.decode()).unwrap()
            })
        });
    }
    g.bench_with_input(BenchmarkId::new("spz_v4", "playbot_2x2"), &spz, |b, bytes| b.iter(|| decode_spz(bytes).unwrap()));
    g.finish();
}

criterion_group!(benches, bench_decode, bench_decode_proxy);
criterion_main!(benches);
