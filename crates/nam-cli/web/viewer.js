// nam viewer: the page served by `nam-cli view`. Surface frame (DESIGN §3): the material spans
// [-1, 1]² on z = 0, x right, y up, z towards the camera at (0, 0, d). Frames come from the
// server (`/api/frame`, the CPU fast path) or from WebGPU in this browser (webgpu.js, the
// project's WGSL shaders); "auto" measures both and keeps the faster one per light kind.
import { createWebGpu } from './webgpu.js';

const token = new URLSearchParams(location.search).get('t') || '';
const $ = (id) => document.getElementById(id);
const api = (path, params = {}) => `/api/${path}?${new URLSearchParams({ t: token, ...params })}`;

const ui = {
  name: $('name'), status: $('status'), photo: $('photo'), photoEmpty: $('photo-empty'),
  photoCaption: $('photo-caption'), frame: $('frame'), hemi: $('hemi'),
  elevation: $('elevation'), distance: $('distance'), intensity: $('intensity'),
  directional: $('directional'), ortho: $('ortho'), falloff: $('falloff'),
  orbit: $('orbit'), download: $('download'), renderer: $('renderer'), fov: $('fov'),
  file: $('file'), path: $('path'), timing: $('timing'), readout: $('light-readout'), drop: $('drop'),
};

// What the page shows; `light` is a position (point light) or a direction (directional).
const view = {
  material: null,
  light: [0.5, 0.4, 4.0], orbiting: false, dragging: false,
};
// Exposed for tests and the curious: frames shown, the last frame's scene, path and timing.
const stats = { frames: 0, path: '', lastMs: 0, lastScene: null, fps: 0, renderer: '', errors: 0, busy: false, previews: 0 };
window.__nam = stats;
// The light the page wants shown now (tests wait until the last frame has it).
stats.wanted = () => scene().light;

let gpu = null;          // WebGpuRenderer when the browser has WebGPU, else null
let gpuInfo = 'not available';
const measured = {};     // `${mode}/${renderer}` -> best ms of a full frame (auto picks the lower)
// While the light is dragged or orbits, server frames slower than this come at half resolution
// (a preview, `/api/frame?preview=1`); the full frame follows when the drag ends.
const PREVIEW_ABOVE_MS = 1000 / 15;
// `&preview=0` in the URL: always full frames.
const PREVIEWS = new URLSearchParams(location.search).get('preview') !== '0';

function setStatus(text, error = false) {
  ui.status.textContent = text;
  ui.status.classList.toggle('error', error);
}

const len = (v) => Math.hypot(v[0], v[1], v[2]);

function spherical() {
  const [x, y, z] = view.light;
  const r = len(view.light);
  return { az: Math.atan2(y, x), el: Math.asin(Math.min(1, z / r)), r };
}

function setSpherical(az, el, r) {
  view.light = [r * Math.cos(el) * Math.cos(az), r * Math.cos(el) * Math.sin(az), r * Math.sin(el)];
}

// The scene of the next frame, as the API and webgpu.js take it.
function scene() {
  const d = view.material ? view.material.capture_distance : 4.0;
  return {
    light: view.light.map((v) => +v.toFixed(5)),
    directional: ui.directional.checked,
    view: ui.ortho.checked ? [0, 0, 1] : [0, 0, +d.toFixed(6)],
    ortho: ui.ortho.checked,
    intensity: +ui.intensity.value,
    falloff: ui.falloff.checked,
  };
}

const modeOf = (s) => (s.directional && s.ortho ? 'directional' : 'general');

function chooseRenderer(s) {
  const want = ui.renderer.value;
  if (want !== 'auto') return want === 'webgpu' && !gpu ? 'server' : want;
  if (!gpu) return 'server';
  const mode = modeOf(s);
  // Measure each renderer (twice: the first WebGPU frame compiles its pipelines) before choosing.
  for (const r of ['server', 'webgpu']) {
    if (!(measured[`${mode}/${r}`]?.n >= 2)) return r;
  }
  return measured[`${mode}/server`].ms <= measured[`${mode}/webgpu`].ms ? 'server' : 'webgpu';
}

function record(mode, renderer, ms) {
  const k = `${mode}/${renderer}`;
  const m = measured[k] || { n: 0, ms: Infinity };
  measured[k] = { n: m.n + 1, ms: Math.min(m.ms, ms) };
}

async function serverFrame(s) {
  const params = {
    light: s.light.join(','), view: s.view.join(','), intensity: s.intensity, fmt: 'rgb8',
    directional: +s.directional, ortho: +s.ortho, falloff: +s.falloff, preview: +!!s.preview,
  };
  const res = await fetch(api('frame', params));
  if (!res.ok) throw new Error((await res.json()).error || res.statusText);
  return {
    rgb: new Uint8Array(await res.arrayBuffer()),
    width: +res.headers.get('X-Nam-Width'), height: +res.headers.get('X-Nam-Height'),
    renderMs: +res.headers.get('X-Nam-Render-Ms'), path: res.headers.get('X-Nam-Path'),
    preview: res.headers.get('X-Nam-Preview') === '1',
  };
}

// Draws an 8-bit RGB frame into a canvas: at its size, or, for a half-resolution preview,
// scaled up into the canvas as it is (its size stays the material's). Every 2D context is a CPU
// one (willReadFrequently): an accelerated canvas would wait behind WebGPU work in the GPU process.
function show(canvas, frame, keepSize = false) {
  const { width, height, rgb } = frame;
  const img = new ImageData(width, height);
  for (let p = 0, q = 0; p < width * height * 3; p += 3, q += 4) {
    img.data[q] = rgb[p]; img.data[q + 1] = rgb[p + 1]; img.data[q + 2] = rgb[p + 2]; img.data[q + 3] = 255;
  }
  const ctx = canvas.getContext('2d', { willReadFrequently: true });
  if (keepSize && (canvas.width !== width || canvas.height !== height)) {
    const small = document.createElement('canvas');
    small.width = width;
    small.height = height;
    small.getContext('2d', { willReadFrequently: true }).putImageData(img, 0, 0);
    ctx.drawImage(small, 0, 0, canvas.width, canvas.height);
    return;
  }
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  ctx.putImageData(img, 0, 0);
}

// One frame at a time: a light change while a frame renders replaces the pending request
// (stale positions are dropped, never queued).
let inFlight = false;
let pending = false;
const recent = [];

function requestFrame() {
  updateReadouts();
  if (!view.material) return;
  if (inFlight) { pending = true; stats.busy = true; return; }
  renderNow();
}

async function renderNow() {
  inFlight = true;
  pending = false;
  stats.busy = true;
  const s = scene();
  const renderer = chooseRenderer(s);
  const full = measured[`${modeOf(s)}/server`];
  s.preview = PREVIEWS && renderer === 'server' && (view.dragging || view.orbiting) && !!full && full.ms > PREVIEW_ABOVE_MS;
  const t0 = performance.now();
  try {
    let frame;
    if (renderer === 'webgpu') {
      frame = await gpu.render(s);
      frame.path = `WebGPU in the browser (${gpuInfo}), ${modeOf(s) === 'directional' ? 'directional fast path' : 'general path'}`;
    } else {
      frame = await serverFrame(s);
    }
    show(ui.frame, frame, !!frame.preview);
    const total = performance.now() - t0;
    if (!s.preview) record(modeOf(s), renderer, total);
    const now = performance.now();
    recent.push(now);
    while (recent.length && now - recent[0] > 2000) recent.shift();
    stats.frames += 1;
    if (frame.preview) stats.previews += 1;
    stats.lastScene = s;
    stats.path = frame.path;
    stats.renderer = renderer;
    stats.lastMs = total;
    stats.fps = recent.length > 1 ? (recent.length - 1) / ((now - recent[0]) / 1000) : 0;
    const preview = frame.preview ? ` · ${frame.width}² preview while the light moves` : '';
    ui.path.textContent = `${ui.renderer.value === 'auto' ? 'auto → ' : ''}${frame.path}${preview}`;
    ui.timing.textContent = `${total.toFixed(1)} ms per frame` +
      (frame.renderMs ? ` (render ${frame.renderMs.toFixed(1)} ms)` : '') +
      (stats.fps ? `, ${stats.fps.toFixed(1)} frames/s` : '');
    if (ui.status.classList.contains('error')) setStatus('');
  } catch (e) {
    stats.errors += 1;
    setStatus(`frame failed: ${e.message}`, true);
  } finally {
    // A request that came during this frame runs next; the page stays "in flight" until it
    // starts, so that no second frame can start beside it.
    if (pending) {
      requestAnimationFrame(() => renderNow());
    } else {
      inFlight = false;
      stats.busy = false;
    }
  }
}

function updateReadouts() {
  const { el, r } = spherical();
  ui.elevation.value = (el * 180 / Math.PI).toFixed(1);
  ui.distance.value = r.toFixed(2);
  ui.elevation.nextElementSibling.textContent = `${(el * 180 / Math.PI).toFixed(1)}°`;
  ui.distance.nextElementSibling.textContent = r.toFixed(2);
  ui.intensity.nextElementSibling.textContent = (+ui.intensity.value).toFixed(2);
  const kind = ui.directional.checked ? 'direction' : 'position';
  ui.readout.textContent = `${kind} (${view.light.map((v) => v.toFixed(2)).join(', ')})`;
  drawHemisphere();
}

function drawHemisphere() {
  const c = ui.hemi.getContext('2d', { willReadFrequently: true });
  const { width: w, height: h } = ui.hemi;
  const R = w / 2 - 4;
  c.clearRect(0, 0, w, h);
  c.fillStyle = '#23252a';
  c.beginPath(); c.arc(w / 2, h / 2, R, 0, 2 * Math.PI); c.fill();
  c.strokeStyle = '#3a3d44';
  for (const f of [1 / 3, 2 / 3]) { c.beginPath(); c.arc(w / 2, h / 2, R * f, 0, 2 * Math.PI); c.stroke(); }
  const { az, el } = spherical();
  const rr = R * Math.cos(el);
  c.fillStyle = '#f0b040';
  c.beginPath(); c.arc(w / 2 + rr * Math.cos(az), h / 2 - rr * Math.sin(az), 6, 0, 2 * Math.PI); c.fill();
}

// Dragging on the material puts the light above the pointer at its current height.
function pointerOnMaterial(ev) {
  const rect = ui.frame.getBoundingClientRect();
  const x = 2 * (ev.clientX - rect.left) / rect.width - 1;
  const y = 1 - 2 * (ev.clientY - rect.top) / rect.height;
  view.light = [x, y, view.light[2]];
  requestFrame();
}

function pointerOnHemisphere(ev) {
  const rect = ui.hemi.getBoundingClientRect();
  const R = rect.width / 2 - 4;
  let x = (ev.clientX - rect.left - rect.width / 2) / R;
  let y = -(ev.clientY - rect.top - rect.height / 2) / R;
  const rho = Math.hypot(x, y);
  if (rho > 0.999) { x *= 0.999 / rho; y *= 0.999 / rho; }
  const el = Math.acos(Math.min(1, Math.hypot(x, y)));
  setSpherical(Math.atan2(y, x), Math.max(el, Math.PI / 180), spherical().r);
  requestFrame();
}

function dragWith(el, handler) {
  el.addEventListener('pointerdown', (ev) => {
    el.setPointerCapture(ev.pointerId);
    stopOrbit();
    view.dragging = true;
    handler(ev);
  });
  el.addEventListener('pointermove', (ev) => { if (el.hasPointerCapture(ev.pointerId)) handler(ev); });
  const end = () => {
    if (!view.dragging) return;
    view.dragging = false;
    requestFrame(); // the full frame
  };
  el.addEventListener('pointerup', end);
  el.addEventListener('pointercancel', end);
  el.addEventListener('lostpointercapture', end);
}

let orbitLast = 0;
function orbitTick(now) {
  if (!view.orbiting) return;
  const dt = orbitLast ? (now - orbitLast) / 1000 : 0;
  orbitLast = now;
  const { az, el, r } = spherical();
  setSpherical(az + dt * 0.8, el, r);
  requestFrame();
  requestAnimationFrame(orbitTick);
}

function stopOrbit() {
  if (!view.orbiting) return;
  view.orbiting = false;
  ui.orbit.setAttribute('aria-pressed', 'false');
  requestFrame(); // the full frame
}

async function loadState() {
  const res = await fetch(api('state'));
  if (!res.ok) throw new Error((await res.json()).error || res.statusText);
  const st = await res.json();
  view.material = st.material;
  ui.fov.value = st.material ? st.material.fov : st.default_fov;
  if (!st.material) {
    ui.name.textContent = 'no material: drop a photo';
    ui.photo.hidden = true;
    ui.photoEmpty.hidden = false;
    return;
  }
  const m = st.material;
  ui.name.textContent = `${m.name}: ${m.width}×${m.height}, model C = ${st.model.width} (${st.model.backend})`;
  ui.photoEmpty.hidden = true;
  ui.photo.hidden = false;
  if (m.has_photo) {
    ui.photoCaption.textContent = 'Photo (as the estimator saw it)';
    const res = await fetch(api('photo', { g: st.generation }));
    if (!res.ok) throw new Error((await res.json()).error || res.statusText);
    const bitmap = await createImageBitmap(await res.blob());
    ui.photo.width = bitmap.width;
    ui.photo.height = bitmap.height;
    ui.photo.getContext('2d', { willReadFrequently: true }).drawImage(bitmap, 0, 0);
  } else {
    // A .nam file holds no photo: show the material under its own capture flash instead.
    const d = m.capture_distance;
    ui.photoCaption.textContent = 'Material under the capture flash (a .nam file has no photo)';
    show(ui.photo, await serverFrame({ light: [0, 0, d], view: [0, 0, d], intensity: 1, directional: false, ortho: false, falloff: false }));
  }
  if (gpu) await gpu.load(api, st);
  for (const k of Object.keys(measured)) delete measured[k];
  requestFrame();
}

async function upload(file) {
  if (!file) return;
  setStatus(`estimating ${file.name}…`);
  try {
    const name = file.name.replace(/[^A-Za-z0-9._-]/g, '_').slice(0, 80);
    const res = await fetch(api('estimate', { fov: ui.fov.value, name }), { method: 'POST', body: file });
    if (!res.ok) {
      let msg = res.statusText;
      try { msg = (await res.json()).error; } catch { /* not JSON */ }
      throw new Error(msg);
    }
    await loadState();
    setStatus(`estimated ${file.name}`);
  } catch (e) {
    setStatus(`${file.name}: ${e.message}`, true);
  }
}

function wire() {
  dragWith(ui.frame, pointerOnMaterial);
  dragWith(ui.hemi, pointerOnHemisphere);
  ui.elevation.addEventListener('input', () => {
    const { az, r } = spherical();
    setSpherical(az, ui.elevation.value * Math.PI / 180, r);
    requestFrame();
  });
  ui.distance.addEventListener('input', () => {
    const { az, el } = spherical();
    setSpherical(az, el, +ui.distance.value);
    requestFrame();
  });
  for (const el of [ui.intensity, ui.directional, ui.ortho, ui.falloff, ui.renderer]) {
    el.addEventListener('input', requestFrame);
  }
  ui.orbit.addEventListener('click', () => {
    if (view.orbiting) { stopOrbit(); return; }
    view.orbiting = true;
    ui.orbit.setAttribute('aria-pressed', 'true');
    orbitLast = 0;
    requestAnimationFrame(orbitTick);
  });
  ui.download.addEventListener('click', () => {
    ui.frame.toBlob((blob) => {
      const a = document.createElement('a');
      a.href = URL.createObjectURL(blob);
      a.download = 'nam-frame.png';
      a.click();
      setTimeout(() => URL.revokeObjectURL(a.href), 1000);
    }, 'image/png');
  });
  ui.file.addEventListener('change', () => upload(ui.file.files[0]));
  ui.drop.addEventListener('dragover', (ev) => { ev.preventDefault(); ui.drop.classList.add('dragover'); });
  ui.drop.addEventListener('dragleave', () => ui.drop.classList.remove('dragover'));
  ui.drop.addEventListener('drop', (ev) => {
    ev.preventDefault();
    ui.drop.classList.remove('dragover');
    upload(ev.dataTransfer.files[0]);
  });
}

async function main() {
  wire();
  updateReadouts();
  try {
    const g = await createWebGpu();
    if (g) { gpu = g; gpuInfo = g.describe(); }
  } catch (e) {
    gpuInfo = `failed: ${e.message}`;
  }
  const opt = ui.renderer.querySelector('option[value=webgpu]');
  opt.disabled = !gpu;
  opt.textContent = gpu ? `WebGPU in this browser (${gpuInfo})` : 'WebGPU (not available in this browser)';
  try {
    await loadState();
    if (view.material) {
      const d = view.material.capture_distance;
      view.light = [0.5, 0.4, d];
    }
    stats.ready = true;
    requestFrame();
  } catch (e) {
    setStatus(e.message, true);
  }
}

main();
