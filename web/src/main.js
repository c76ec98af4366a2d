// The viewer page: loading (file picker, drag and drop, ?url=), the worker, orbit controls, the
// overlay and a small API on `window.viewer` (used by the browser test).
//
// URL parameters: url (a .gsc to load), up (world up axis: -y default, +y, +z, -z, +x, -x),
// bg (background r,g,b in [0, 1]; default 0,0,0), sh (highest SH degree drawn, 0–3), bare (hide the
// toolbar and overlay).

import { SplatRenderer } from './renderer.js';
import { Orbit, UP_AXES } from './camera.js';

const params = new URLSearchParams(location.search);
const canvas = document.getElementById('view');
const info = document.getElementById('info');
if (params.get('bare')) document.body.classList.add('bare');

function parseRgb(s) {
  const v = (s ?? '').split(',').map(Number);
  return v.length === 3 && v.every((x) => x >= 0 && x <= 1) ? v : null;
}

class Viewer {
  constructor() {
    this.renderer = new SplatRenderer(canvas);
    this.worker = new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
    this.worker.onmessage = (e) => this.onMessage(e.data);
    this.worker.onerror = (e) => this.fail(e.message || 'the worker failed to start');
    this.orbit = new Orbit(UP_AXES[params.get('up')] ?? UP_AXES['-y']);
    this.background = parseRgb(params.get('bg')) ?? [0, 0, 0];
    this.maxShDegree = Math.max(0, Math.min(3, Number(params.get('sh') ?? 3) | 0));
    this.fixed = null; // a camera given by setCamera, until the user moves
    this.generation = 0;
    this.sortId = 0;
    this.sorting = null; // key of the camera whose order is being computed
    this.sortedKey = null; // key of the camera the current order belongs to
    this.waiters = [];
    this.frameQueued = false;
    this.scene = null;
    this.stats = null;
    this.lastError = null;
    this.resetLoaded();
  }

  resetLoaded() {
    this.loaded = new Promise((resolve, reject) => Object.assign(this, { resolveLoaded: resolve, rejectLoaded: reject }));
    this.loaded.catch(() => {});
  }

  /** Loads a .gsc from a URL, decoding while it downloads (coarse scenes appear first). */
  load(url) {
    this.resetLoaded();
    this.show(`loading ${url} …`);
    this.worker.postMessage({ type: 'url', url: new URL(url, location.href).href, maxShDegree: this.maxShDegree });
    return this.loaded;
  }

  /** Loads a File (picker or drop). */
  async loadFile(file) {
    this.resetLoaded();
    this.show(`reading ${file.name} …`);
    const bytes = await file.arrayBuffer();
    this.worker.postMessage({ type: 'bytes', bytes, name: file.name, maxShDegree: this.maxShDegree }, [bytes]);
    return this.loaded;
  }

  /** Shows the scene from a fixed camera (camera.js); resolves once that frame is drawn sorted. */
  setCamera(cam) {
    this.fixed = { ...cam };
    this.orbit.adopt(cam);
    canvas.style.width = `${cam.width / devicePixelRatio}px`;
    canvas.style.height = `${cam.height / devicePixelRatio}px`;
    const done = new Promise((resolve) => this.waiters.push({ key: Viewer.key(cam), resolve }));
    this.requestFrame();
    return done;
  }

  /** Resolves once the current view has been drawn in depth order. */
  drawn() {
    const done = new Promise((resolve) => this.waiters.push({ key: null, resolve }));
    this.requestFrame();
    return done;
  }

  /** What the depth order depends on. */
  static key(cam) {
    return [cam.R[6], cam.R[7], cam.R[8], cam.t[2], cam.znear].join(',');
  }

  camera() {
    if (this.fixed) return this.fixed;
    canvas.style.width = '';
    canvas.style.height = '';
    const w = Math.max(1, Math.round(canvas.clientWidth * devicePixelRatio));
    const h = Math.max(1, Math.round(canvas.clientHeight * devicePixelRatio));
    return this.orbit.camera(w, h);
  }

  requestFrame() {
    if (this.frameQueued) return;
    this.frameQueued = true;
    requestAnimationFrame(() => {
      this.frameQueued = false;
      this.frame();
    });
  }

  frame() {
    const cam = this.camera();
    const key = Viewer.key(cam);
    if (this.scene && key !== this.sortedKey && this.sorting === null) {
      this.sorting = key;
      this.worker.postMessage({ type: 'sort', id: ++this.sortId, view: [cam.R[6], cam.R[7], cam.R[8], cam.t[2]], znear: cam.znear });
    }
    this.renderer.render(cam, this.background, this.maxShDegree);
    if (key === this.sortedKey) {
      const now = (w) => w.key === key || w.key === null;
      const ready = this.waiters.filter(now);
      this.waiters = this.waiters.filter((w) => !now(w));
      ready.forEach((w) => w.resolve());
    }
  }

  onMessage(m) {
    if (m.type === 'scene') {
      this.generation = m.generation;
      const first = this.scene === null || this.stats?.final;
      this.scene = m.scene;
      this.renderer.setScene(m.gpu);
      this.sortedKey = null;
      this.sorting = null;
      if (first && !this.fixed) this.orbit.frame(m.scene.positions);
      this.stats = { final: m.final, name: m.name, count: m.scene.count, shDegree: m.scene.shDegree, fileBytes: m.fileBytes, receivedBytes: m.receivedBytes, decodeMs: m.decodeMs, streamDecodeMs: m.streamDecodeMs, loadMs: m.loadMs, target: this.renderer.target };
      this.showStats();
      if (m.final) this.resolveLoaded(this.stats);
      this.requestFrame();
    } else if (m.type === 'order') {
      const key = this.sorting;
      this.sorting = null;
      if (m.generation === this.generation) {
        this.renderer.setOrder(m.order);
        this.sortedKey = key;
      }
      this.requestFrame();
    } else if (m.type === 'error') {
      this.sorting = null;
      this.fail(`${m.kind} error: ${m.message}`);
    }
  }

  fail(message) {
    this.lastError = message;
    this.show(message, true);
    this.rejectLoaded(new Error(message));
  }

  show(text, error = false) {
    info.textContent = text;
    info.classList.toggle('error', error);
  }

  showStats() {
    const s = this.stats;
    const kb = (b) => `${(b / 1024).toFixed(1)} KiB`;
    const lines = [`${s.name.split('/').pop()}`, `${s.count.toLocaleString('en')} Gaussians · SH degree ${s.shDegree}`];
    if (s.final) {
      lines.push(`${kb(s.fileBytes)} · decode ${s.decodeMs.toFixed(1)} ms (WASM, worker)`);
      if (s.loadMs !== undefined) lines.push(`download + streaming decode ${s.loadMs.toFixed(0)} ms`);
    } else {
      lines.push(`streaming: ${kb(s.receivedBytes)}${s.fileBytes ? ` of ${kb(s.fileBytes)}` : ''} · coarse scene`);
    }
    lines.push(`${s.target} accumulation`);
    this.show(lines.join('\n'));
  }
}

const viewer = new Viewer();
window.viewer = viewer;

// Orbit controls: left drag orbits, right or shift drag pans, the wheel zooms.
let drag = null;
canvas.addEventListener('pointerdown', (e) => {
  drag = { x: e.clientX, y: e.clientY, pan: e.button !== 0 || e.shiftKey };
  canvas.setPointerCapture(e.pointerId);
});
canvas.addEventListener('pointermove', (e) => {
  if (!drag) return;
  const [dx, dy] = [e.clientX - drag.x, e.clientY - drag.y];
  [drag.x, drag.y] = [e.clientX, e.clientY];
  viewer.fixed = null;
  if (drag.pan) viewer.orbit.pan(dx * devicePixelRatio, dy * devicePixelRatio, canvas.height);
  else viewer.orbit.rotate(dx, dy);
  viewer.requestFrame();
});
canvas.addEventListener('pointerup', () => (drag = null));
canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener(
  'wheel',
  (e) => {
    e.preventDefault();
    viewer.fixed = null;
    viewer.orbit.zoom(Math.exp(e.deltaY * 0.001));
    viewer.requestFrame();
  },
  { passive: false },
);
window.addEventListener('resize', () => viewer.requestFrame());

// Loading: picker, drag and drop, ?url=.
document.getElementById('file').addEventListener('change', (e) => e.target.files[0] && viewer.loadFile(e.target.files[0]));
window.addEventListener('dragover', (e) => e.preventDefault());
window.addEventListener('drop', (e) => {
  e.preventDefault();
  const file = e.dataTransfer?.files?.[0];
  if (file) viewer.loadFile(file);
});
const up = document.getElementById('up');
up.value = UP_AXES[params.get('up')] ? params.get('up') : '-y';
up.addEventListener('change', () => {
  viewer.orbit.setUp(UP_AXES[up.value]);
  viewer.fixed = null;
  viewer.requestFrame();
});
if (params.get('url')) viewer.load(params.get('url'));
else viewer.show('Open a .gsc file, drop one here, or add ?url=FILE.gsc');
viewer.requestFrame();
