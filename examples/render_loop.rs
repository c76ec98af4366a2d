//! CPU render time of a scene: R rounds of N orbit views at S×S, on the current rayon pool
//! (`RAYON_NUM_THREADS`) (profiling aid). Prints the mean per frame and a checksum of the frames.
use gscodec::decoder::{render::render, RenderOptions};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let scene = gscodec::io::read_scene(std::path::Path::new(&a[1])).unwrap();
    let (n, size, rounds): (usize, u32, usize) = (a[2].parse().unwrap(), a[3].parse().unwrap(), a[4].parse().unwrap());
    let cams = gscodec::views::orbit_cameras(&scene, n, size, size, glam::Vec3::Y);
    let t = std::time::Instant::now();
    let mut sum = 0.0f64;
    for _ in 0..rounds {
        for cam in &cams {
            sum += render(&scene, cam, &RenderOptions::default()).data.iter().map(|&v| f64::from(v)).sum::<f64>();
        }
    }
    let e = t.elapsed().as_secs_f64();
    println!("{:.3} ms per frame, checksum {sum:.6}", 1e3 * e / (n * rounds) as f64);
}
