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
