// Pinhole cameras in gscodec's convention (DESIGN §3, decoder/src/camera.rs): OpenCV camera axes
// (x right, y down, z forward), `p_cam = R p_world + t`, a camera-space point projects to pixel
// coordinates (fx x/z + cx, fy y/z + cy), pixel (i, j) has its centre at (i + 0.5, j + 0.5).
//
// A camera is a plain object: { width, height, fx, fy, cx, cy, R: [9 numbers, row-major], t: [3],
// znear } (Gaussians whose centre has depth z <= znear are not drawn).

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(a[0], a[1], a[2]);
const normalize = (a) => scale(a, 1 / norm(a));

/** Camera centre in world space: -Rᵀ t. */
export function cameraCenter(cam) {
  const { R, t } = cam;
  return [
    -(R[0] * t[0] + R[3] * t[1] + R[6] * t[2]),
    -(R[1] * t[0] + R[4] * t[1] + R[7] * t[2]),
    -(R[2] * t[0] + R[5] * t[1] + R[8] * t[2]),
  ];
}

/** A camera at `eye` looking at `target`, `up` appearing up in the image, horizontal field of view
 *  `fovX` (Camera::look_at). */
export function lookAt(eye, target, up, width, height, fovX, znear) {
  const z = normalize(sub(target, eye));
  let x = cross(z, up);
  if (!(norm(x) > 0)) x = cross(z, [1, 0, 0]);
  x = norm(x) > 0 ? normalize(x) : [0, 1, 0];
  const y = cross(z, x);
  const R = [...x, ...y, ...z];
  const t = [-dot(x, eye), -dot(y, eye), -dot(z, eye)];
  const f = width / (2 * Math.tan(fovX / 2));
  return { width, height, fx: f, fy: f, cx: width / 2, cy: height / 2, R, t, znear };
}

/** glam's Vec3::any_orthonormal_vector, so that orbits start where Camera::orbit's do. */
function anyOrthonormal(v) {
  const sign = v[2] < 0 || Object.is(v[2], -0) ? -1 : 1; // f32::signum
  const a = -1 / (sign + v[2]);
  const b = v[0] * v[1] * a;
  return [b, sign + v[1] * v[1] * a, -v[1]];
}

/**
 * The camera of a NeRF/Blender frame (`transform_matrix`: camera-to-world, OpenGL axes) at
 * width × height, as gscodec's dataset loader makes it (src/io/nerf.rs, Camera::from_nerf_c2w):
 * fx from camera_angle_x at the declared size, scaled to the requested one.
 */
export function nerfCamera(c2w, angleX, declared, width, height, znear) {
  const f = (0.5 * declared[0]) / Math.tan(0.5 * angleX);
  const [sx, sy] = [width / declared[0], height / declared[1]];
  // OpenGL -> OpenCV: negate the y and z columns; R is the transpose of that rotation.
  const col = (j, s) => [c2w[0][j] * s, c2w[1][j] * s, c2w[2][j] * s];
  const R = [...col(0, 1), ...col(1, -1), ...col(2, -1)];
  const c = [c2w[0][3], c2w[1][3], c2w[2][3]];
  const t = [-(R[0] * c[0] + R[1] * c[1] + R[2] * c[2]), -(R[3] * c[0] + R[4] * c[1] + R[5] * c[2]), -(R[6] * c[0] + R[7] * c[1] + R[8] * c[2])];
  return { width, height, fx: f * sx, fy: f * sy, cx: (declared[0] / 2) * sx, cy: (declared[1] / 2) * sy, R, t, znear };
}

/** World up axes a scene may use: the CLI's `--up` values. 3DGS/COLMAP scenes are -y up. The
 *  negative axes carry -0 components, as `-Vec3::Y` does in Rust (it decides anyOrthonormal's sign). */
export const UP_AXES = { '-y': [-0, -1, -0], '+y': [0, 1, 0], '+z': [0, 0, 1], '-z': [-0, -0, -1], '+x': [1, 0, 0], '-x': [-1, -0, -0] };

/**
 * Orbit controls: a target, a distance, yaw around the up axis and pitch above the plane
 * orthogonal to it, placed as Camera::orbit places its views. Left drag orbits, right or shift
 * drag pans, the wheel zooms. A framed scene is first seen as view 0 of `gscodec render --orbit N`
 * (src/views.rs: robust centre, 2.5 × the robust extent away, 25° up, 0.8 rad horizontal FOV,
 * near plane 0.05 × the distance).
 */
export class Orbit {
  constructor(up = UP_AXES['-y']) {
    this.setUp(up);
    this.target = [0, 0, 0];
    this.distance = 4;
    this.yaw = 0;
    this.pitch = (25 * Math.PI) / 180;
    this.fovX = 0.8;
  }

  setUp(up) {
    this.up = normalize(up);
    this.a = anyOrthonormal(this.up);
    this.b = cross(this.up, this.a);
  }

  /** Frames points (positions, 3 per point): target = per-axis median, distance = 2.5 × the
   *  90th-percentile distance to it (views.rs robust_frame; large scenes are sampled). */
  frame(positions) {
    const n = positions.length / 3;
    if (n === 0) return;
    const step = Math.max(1, Math.floor(n / 20000)); // a sample is enough for medians
    const axis = (k) => {
      const v = [];
      for (let i = 0; i < n; i += step) v.push(positions[i * 3 + k]);
      return v.sort((p, q) => p - q);
    };
    this.target = [0, 1, 2].map((k) => axis(k)).map((v) => v[v.length >> 1]);
    const d = [];
    for (let i = 0; i < n; i += step) d.push(norm(sub([positions[i * 3], positions[i * 3 + 1], positions[i * 3 + 2]], this.target)));
    d.sort((p, q) => p - q);
    const r = d[Math.min(d.length - 1, Math.floor((d.length * 9) / 10))];
    this.distance = 2.5 * (r > 0 && Number.isFinite(r) ? r : 1);
    this.yaw = 0;
    this.pitch = (25 * Math.PI) / 180;
  }

  eye() {
    const [ca, sa, cp, sp] = [Math.cos(this.yaw), Math.sin(this.yaw), Math.cos(this.pitch), Math.sin(this.pitch)];
    const dir = add(scale(add(scale(this.a, ca), scale(this.b, sa)), cp), scale(this.up, sp));
    return add(this.target, scale(dir, this.distance));
  }

  camera(width, height) {
    return lookAt(this.eye(), this.target, this.up, width, height, this.fovX, 0.05 * this.distance);
  }

  /** Continues orbiting from a given camera: target on its view axis at the current distance. */
  adopt(cam) {
    const eye = cameraCenter(cam);
    const forward = [cam.R[6], cam.R[7], cam.R[8]];
    this.distance = Math.max(1e-6, Math.abs(dot(sub(this.target, eye), forward)) || this.distance);
    this.target = add(eye, scale(forward, this.distance));
    const dir = normalize(sub(eye, this.target));
    this.pitch = Math.asin(Math.max(-1, Math.min(1, dot(dir, this.up))));
    this.yaw = Math.atan2(dot(dir, this.b), dot(dir, this.a));
  }

  rotate(dx, dy) {
    this.yaw -= dx * 0.005;
    this.pitch = Math.max(-1.55, Math.min(1.55, this.pitch + dy * 0.005));
  }

  pan(dx, dy, height) {
    const cam = this.camera(1, height);
    const s = this.distance / cam.fy;
    const right = [cam.R[0], cam.R[1], cam.R[2]];
    const down = [cam.R[3], cam.R[4], cam.R[5]];
    this.target = add(this.target, add(scale(right, -dx * s), scale(down, -dy * s)));
  }

  zoom(factor) {
    this.distance *= factor;
  }
}
