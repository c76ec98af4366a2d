//! Initial Gaussians: from a point cloud (COLMAP points) or random inside the scene bounds, and the
//! scene extent that sets the position learning rate and the densification thresholds.

use crate::io::Dataset;
use crate::rng::Rng;
use glam::{Mat3, Vec3};
use gscodec_decoder::{math::SH_C0, Splats};
use std::collections::HashMap;

/// The reference trainer's "camera extent": 1.1 × the largest distance of a camera centre from
/// the mean centre (at least a tiny positive value).
pub fn camera_extent(ds: &Dataset) -> f32 {
    let centers: Vec<Vec3> = ds.frames.iter().map(|f| f.camera.center()).collect();
    if centers.is_empty() {
        return 1.0;
    }
    let mean = centers.iter().copied().sum::<Vec3>() / centers.len() as f32;
    let r = centers.iter().map(|c| c.distance(mean)).fold(0.0f32, f32::max);
    if r > 0.0 {
        1.1 * r
    } else {
        // One camera (or all at one place): use its distance to the origin.
        (1.1 * centers[0].length()).max(f32::MIN_POSITIVE)
    }
}

/// The point closest (least squares) to all camera optical axes: where an object-centric capture
/// looks. Falls back to the mean camera centre.
pub fn look_at_point(ds: &Dataset) -> Vec3 {
    let mut a = Mat3::ZERO;
    let mut b = Vec3::ZERO;
    let mut mean = Vec3::ZERO;
    for f in &ds.frames {
        let c = f.camera.center();
        let d = f.camera.rotation.transpose() * Vec3::Z; // optical axis in world space
        let p = Mat3::IDENTITY - Mat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * c;
        mean += c;
    }
    let n = ds.frames.len().max(1) as f32;
    if a.determinant().abs() > 1e-6 * n * n * n {
        a.inverse() * b
    } else {
        mean / n
    }
}

fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}

/// Gaussians at `points` with colours `colors` (sRGB in [0,1]), opacity 0.1, isotropic scale from
/// the mean squared distance to the 3 nearest neighbours (as the reference trainer).
pub fn from_points(points: &[[f32; 3]], colors: &[[f32; 3]], sh_degree: u8) -> Splats {
    let scales = knn3_scale(points);
    let mut s = Splats::new(sh_degree);
    let rest = vec![0.0; s.rest_coeffs() * 3];
    for (i, p) in points.iter().enumerate() {
        let dc = colors[i].map(|c| (c - 0.5) / SH_C0);
        s.push(*p, [scales[i].ln(); 3], [1.0, 0.0, 0.0, 0.0], logit(0.1), dc, &rest);
    }
    s
}

/// `n` random Gaussians with random colours, drawn uniformly in the dataset's `bounds` (NeRF
/// `aabb_scale`) or else in the cube of half-size `0.3 × extent` around the cameras' look-at point
/// (for NeRF-synthetic scenes the reference's [-1.3, 1.3]³ cube), keeping only points that some
/// camera sees (in front of its near plane, inside its image): the cameras' frusta bound them.
/// When too few candidates are seen (cameras looking away from the cube), unseen ones fill up.
pub fn random(ds: &Dataset, n: usize, sh_degree: u8, rng: &mut Rng) -> Splats {
    let (c, half) = match ds.bounds {
        Some((c, h)) => (Vec3::from_array(c), h),
        None => (look_at_point(ds), 0.3 * camera_extent(ds)),
    };
    let seen = |p: Vec3| {
        ds.frames.iter().any(|f| {
            let q = f.camera.to_camera(p);
            if q.z <= f.camera.znear {
                return false;
            }
            let (u, v) = (f.camera.fx * q.x / q.z + f.camera.cx, f.camera.fy * q.y / q.z + f.camera.cy);
            (0.0..f.camera.width as f32).contains(&u) && (0.0..f.camera.height as f32).contains(&v)
        })
    };
    let mut pts: Vec<[f32; 3]> = Vec::with_capacity(n);
    let mut unseen: Vec<[f32; 3]> = Vec::new();
    for _ in 0..n.saturating_mul(20) {
        if pts.len() == n {
            break;
        }
        let p = c + Vec3::new(rng.uniform(), rng.uniform(), rng.uniform()) * (2.0 * half) - half;
        if ds.frames.is_empty() || seen(p) {
            pts.push(p.to_array());
        } else if unseen.len() < n {
            unseen.push(p.to_array());
        }
    }
    let missing = n - pts.len();
    pts.extend(unseen.into_iter().take(missing));
    let cols: Vec<[f32; 3]> = (0..pts.len()).map(|_| [rng.uniform(), rng.uniform(), rng.uniform()]).collect();
    from_points(&pts, &cols, sh_degree)
}

/// Initial Gaussians for a dataset: its point cloud when it has one, else `n_random` random ones.
pub fn initial_splats(ds: &Dataset, n_random: usize, sh_degree: u8, rng: &mut Rng) -> Splats {
    if ds.points.is_empty() {
        random(ds, n_random, sh_degree, rng)
    } else {
        let (p, c): (Vec<[f32; 3]>, Vec<[f32; 3]>) = ds.points.iter().copied().unzip();
        from_points(&p, &c, sh_degree)
    }
}

/// Per point: `sqrt(mean squared distance to the 3 nearest other points)` via a hash grid.
fn knn3_scale(points: &[[f32; 3]]) -> Vec<f32> {
    let n = points.len();
    if n < 2 {
        return vec![1e-2; n];
    }
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in points {
        lo = lo.min(Vec3::from_array(*p));
        hi = hi.max(Vec3::from_array(*p));
    }
    let ext = (hi - lo).max(Vec3::splat(1e-30));
    // About 2 points per cell on average for a volume-filling cloud.
    let cell = ((ext.x * ext.y * ext.z) / n as f32 * 2.0).cbrt().max(ext.max_element() / 1024.0).max(f32::MIN_POSITIVE);
    let key = |p: Vec3| ((p - lo) / cell).floor().as_ivec3();
    let mut grid: HashMap<glam::IVec3, Vec<u32>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(Vec3::from_array(*p))).or_default().push(i as u32);
    }
    points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let p = Vec3::from_array(*p);
            let k = key(p);
            let mut best = [f32::MAX; 3];
            let mut ring: i32 = 1;
            loop {
                for dz in -ring..=ring {
                    for dy in -ring..=ring {
                        for dx in -ring..=ring {
                            if ring > 1 && dx.abs().max(dy.abs()).max(dz.abs()) < ring {
                                continue; // scanned in an earlier ring
                            }
                            if let Some(ids) = grid.get(&(k + glam::IVec3::new(dx, dy, dz))) {
                                for &j in ids {
                                    if j as usize == i {
                                        continue;
                                    }
                                    let d2 = p.distance_squared(Vec3::from_array(points[j as usize]));
                                    if d2 < best[2] {
                                        best[2] = d2;
                                        best.sort_by(f32::total_cmp);
                                    }
                                }
                            }
                        }
                    }
                }
                // Points within `ring * cell` are all found; stop once the 3rd is that close.
                if best[2] <= (ring as f32 * cell).powi(2) || ring >= 4 {
                    break;
                }
                ring += 1;
            }
            let found: Vec<f32> = best.iter().copied().filter(|d| *d < f32::MAX).collect();
            let m = if found.is_empty() { cell * cell } else { found.iter().sum::<f32>() / found.len() as f32 };
            m.max(1e-14).sqrt()
        })
        .collect()
}
