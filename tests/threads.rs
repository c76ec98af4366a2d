//! CPU training is bit-identical whatever the thread count (fixed reduction orders in SSIM,
//! Adam, the rasterizer and its backward pass).

use gscodec::loss::{ssim::ssim_and_grad, L1Ssim};
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::targets::render_targets;
use gscodec::train::{train, TrainConfig};

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(f)
}

#[test]
fn ssim_and_training_are_identical_on_1_and_4_threads() {
    let ds = render_targets(&random_splats(120, 1, 3), &rig_cameras(8, 3.5, 72, 40), [0.0; 3]);
    let (a, b) = (ds.frames[0].image.get().unwrap(), ds.frames[1].image.get().unwrap());
    let (a, b) = (&*a, &*b);
    let (s1, g1) = in_pool(1, || ssim_and_grad(a, b));
    let (s4, g4) = in_pool(4, || ssim_and_grad(a, b));
    assert_eq!(s1.to_bits(), s4.to_bits());
    assert!(g1.iter().zip(&g4).all(|(x, y)| x.to_bits() == y.to_bits()));
    let cfg = TrainConfig { iters: 120, seed: 2, init_points: 400, eval_interval: 0, ..Default::default() };
    let run = |threads| in_pool(threads, || train(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}).unwrap().0);
    let (one, four) = (run(1), run(4));
    assert!(one.len() > 400, "densification ran");
    assert_eq!(one, four);
}

/// The tile binning and depth sort (`bin_tiles`, parallel over bands of tile rows and over tiles)
/// gives the same lists on any thread count, equal to a direct per-tile filter and stable sort.
#[test]
fn tile_binning_is_identical_on_any_thread_count_and_matches_a_direct_sort() {
    use gscodec_decoder::math::{reaches_box, tile_rect, TILE};
    use gscodec_decoder::render::{bin_tiles, preprocess};
    let splats = random_splats(3000, 1, 7);
    for cam in rig_cameras(3, 3.0, 131, 77) {
        let proj = preprocess(&splats, &cam, 1);
        let (w, h) = (cam.width, cam.height);
        let bins = in_pool(1, || bin_tiles(&proj, w, h));
        for threads in [2, 3, 8] {
            let other = in_pool(threads, || bin_tiles(&proj, w, h));
            assert_eq!((&bins.ranges, &bins.ids), (&other.ranges, &other.ids), "{threads} threads");
        }
        assert!(bins.ids.len() > 3000, "a busy scene: {} pairs", bins.ids.len());
        for ty in 0..bins.tiles_y {
            for tx in 0..bins.tiles_x {
                let (x0, y0) = (tx * TILE, ty * TILE);
                let bx = [x0 as f32, y0 as f32, ((x0 + TILE).min(w) - 1) as f32, ((y0 + TILE).min(h) - 1) as f32];
                let mut want: Vec<u32> = (0..proj.len() as u32)
                    .filter(|&g| {
                        let p = &proj[g as usize];
                        let r = tile_rect(p.mean, p.radius, w, h);
                        p.radius > 0.0
                            && (r[0]..r[2]).contains(&tx)
                            && (r[1]..r[3]).contains(&ty)
                            && reaches_box(p.mean, p.conic, p.opacity, bx)
                    })
                    .collect();
                want.sort_by(|&a, &b| proj[a as usize].depth.total_cmp(&proj[b as usize].depth));
                assert_eq!(bins.tile((ty * bins.tiles_x + tx) as usize), &want[..], "tile ({tx}, {ty})");
            }
        }
    }
}
