// The viewer's Web Worker: decodes .gsc files with the gscodec-wasm package, packs the scene into
// float textures for the renderer and sorts the Gaussians by depth for each new camera.
//
// Messages in:  { type: 'bytes', bytes: ArrayBuffer, name, maxShDegree }
//               { type: 'url', url, maxShDegree }      (fetched and decoded as it streams in)
//               { type: 'sort', id, view: [r20, r21, r22, tz], znear }
// Messages out: { type: 'scene', generation, final, name, fileBytes, receivedBytes, decodeMs, scene, gpu }
//               { type: 'order', id, generation, order: Uint32Array }   (back to front)
// `generation` numbers the scenes sent; an order belongs to the scene of the same generation.
//               { type: 'error', message, kind }

import init, { decode, StreamDecoder } from '../../wasm/pkg/gscodec_wasm.js';

const ready = init();
/** Positions of the scene on screen (for sorting). */
let positions = new Float32Array(0);
let generation = 0;

/** Texture width in texels; rows follow from the scene size. */
export const TEX_WIDTH = 2048;

/**
 * Per Gaussian: 3 RGBA32F texels (x, y, z, opacity), (Σxx, Σxy, Σxz, Σyy), (Σyz, Σzz, 0, 0), with
 * Σ = R diag(s)² Rᵀ the world covariance (decoder/src/math.rs covariance_3d); and ⌈3(d+1)²/4⌉
 * texels of SH coefficients (DC first, RGB interleaved, as the scene's `sh`).
 */
function pack(scene) {
  const n = scene.count;
  const coeffs = (scene.shDegree + 1) ** 2;
  const shStride = Math.ceil((coeffs * 3) / 4);
  const rows = (texels) => Math.max(1, Math.ceil(texels / TEX_WIDTH));
  const splatRows = rows(n * 3);
  const shRows = rows(n * shStride);
  const splats = new Float32Array(TEX_WIDTH * splatRows * 4);
  const sh = new Float32Array(TEX_WIDTH * shRows * 4);
  const { positions: p, scales: s, rotations: q, opacities: o } = scene;
  for (let i = 0; i < n; i++) {
    const [x, y, z, w] = [q[i * 4], q[i * 4 + 1], q[i * 4 + 2], q[i * 4 + 3]]; // unit (x, y, z, w)
    const [sx, sy, sz] = [s[i * 3], s[i * 3 + 1], s[i * 3 + 2]]; // linear scales
    // Columns of R·diag(s) (quat_to_mat3).
    const m0 = [(1 - 2 * (y * y + z * z)) * sx, 2 * (x * y + w * z) * sx, 2 * (x * z - w * y) * sx];
    const m1 = [2 * (x * y - w * z) * sy, (1 - 2 * (x * x + z * z)) * sy, 2 * (y * z + w * x) * sy];
    const m2 = [2 * (x * z + w * y) * sz, 2 * (y * z - w * x) * sz, (1 - 2 * (x * x + y * y)) * sz];
    const cov = (r, c) => m0[r] * m0[c] + m1[r] * m1[c] + m2[r] * m2[c];
    const b = i * 12;
    splats.set([p[i * 3], p[i * 3 + 1], p[i * 3 + 2], o[i], cov(0, 0), cov(0, 1), cov(0, 2), cov(1, 1), cov(1, 2), cov(2, 2), 0, 0], b);
  }
  for (let i = 0; i < n; i++) sh.set(scene.sh.subarray(i * coeffs * 3, (i + 1) * coeffs * 3), i * shStride * 4);
  return { count: n, shDegree: scene.shDegree, width: TEX_WIDTH, splats, splatRows, sh, shRows, shStride };
}

/**
 * Indices of the Gaussians in front of the near plane, sorted back to front by camera depth
 * z = r20 x + r21 y + r22 z + tz (in f32, as the CPU renderer computes it). The sort is a stable
 * LSD radix sort on the depth's float bits, ascending, then reversed: equal depths keep the CPU
 * renderer's front-to-back index order.
 */
export function sortBackToFront(pos, view, znear) {
  const n = pos.length / 3;
  const f = Math.fround;
  const [r0, r1, r2, tz] = view.map(f);
  const depth = new Float32Array(n);
  const keys = new Uint32Array(depth.buffer);
  let idx = new Uint32Array(n);
  let m = 0;
  for (let i = 0; i < n; i++) {
    const z = f(f(f(f(r0 * pos[i * 3]) + f(r1 * pos[i * 3 + 1])) + f(r2 * pos[i * 3 + 2])) + tz);
    if (z > znear) {
      depth[m] = z; // positive: its bits order like the value
      idx[m++] = i;
    }
  }
  let k = keys.subarray(0, m);
  idx = idx.subarray(0, m);
  let k2 = new Uint32Array(m);
  let idx2 = new Uint32Array(m);
  const count = new Uint32Array(65536);
  for (const shift of [0, 16]) {
    count.fill(0);
    for (let i = 0; i < m; i++) count[(k[i] >>> shift) & 0xffff]++;
    let sum = 0;
    for (let d = 0; d < 65536; d++) {
      const c = count[d];
      count[d] = sum;
      sum += c;
    }
    for (let i = 0; i < m; i++) {
      const at = count[(k[i] >>> shift) & 0xffff]++;
      k2[at] = k[i];
      idx2[at] = idx[i];
    }
    [k, k2, idx, idx2] = [k2, k, idx2, idx];
  }
  return idx.slice().reverse();
}

function post(type, fields, transfer = []) {
  self.postMessage({ type, ...fields }, transfer);
}

/** Sends a decoded scene: its arrays (for API users) and the packed textures. */
function sendScene(scene, fields) {
  positions = scene.positions.slice();
  generation++;
  const gpu = pack(scene);
  const arrays = [scene.positions, scene.scales, scene.rotations, scene.opacities, scene.sh].map((a) => a.buffer);
  post('scene', { ...fields, generation, scene, gpu }, [...arrays, gpu.splats.buffer, gpu.sh.buffer]);
}

async function loadUrl(url, maxShDegree) {
  const t0 = performance.now();
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  const total = Number(response.headers.get('content-length')) || 0;
  const stream = new StreamDecoder({ maxShDegree });
  const reader = response.body.getReader();
  let decodeMs = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    const t = performance.now();
    const coarse = stream.push(value);
    decodeMs += performance.now() - t;
    if (coarse) sendScene(coarse, { final: false, name: url, fileBytes: total, receivedBytes: stream.bytesReceived, decodeMs });
  }
  const received = stream.bytesReceived;
  const t = performance.now();
  const scene = stream.finish();
  const finishMs = performance.now() - t;
  stream.free();
  sendScene(scene, { final: true, name: url, fileBytes: received, receivedBytes: received, decodeMs: finishMs, streamDecodeMs: decodeMs + finishMs, loadMs: performance.now() - t0 });
}

function loadBytes(bytes, name, maxShDegree) {
  const t = performance.now();
  const scene = decode(new Uint8Array(bytes), { maxShDegree });
  const decodeMs = performance.now() - t;
  sendScene(scene, { final: true, name, fileBytes: bytes.byteLength, receivedBytes: bytes.byteLength, decodeMs });
}

self.onmessage = async (e) => {
  const m = e.data;
  try {
    await ready;
    if (m.type === 'bytes') loadBytes(m.bytes, m.name, m.maxShDegree ?? 3);
    else if (m.type === 'url') await loadUrl(m.url, m.maxShDegree ?? 3);
    else if (m.type === 'sort') {
      const order = sortBackToFront(positions, m.view, m.znear);
      post('order', { id: m.id, generation, order }, [order.buffer]);
    }
  } catch (err) {
    post('error', { message: err.message ?? String(err), kind: err.kind ?? 'io', request: m.type });
  }
};
