// Browser test of `nam-cli view` in headless Chromium (Debian's package, driven by
// playwright-core over the DevTools protocol; no browser is downloaded).
//
//   node tests/browser/view.mjs --bin target/release/nam-cli --photo assets/example_photo.png \
//        [--max-side 256] [--renderers server,webgpu] [--no-preview] [--screenshots docs/figures]
//        [--min-fps 15]
//
// For each renderer the page offers here (the server, and WebGPU when Chromium exposes it) and
// each light kind, a scripted drag moves the light across the material at 60 input events per
// second; the test checks that the light followed the pointer, that the canvas changed, and
// that the frame on the canvas equals the server's frame for the light the page reports (the
// server renderer: identical bytes; WebGPU: within the tolerances below), and prints the
// frames per second shown during the drag.
import { spawn } from 'node:child_process';
import { createInterface } from 'node:readline';
import { mkdirSync } from 'node:fs';
import { chromium } from 'playwright-core';

// WebGPU (the project's WGSL on the browser's adapter) vs the server's CPU frame, 8-bit sRGB
// levels: different summation orders and f32 expm1/pow in JS vs Rust move a few values by a
// level or two; a wrong layer, slope or direction moves most pixels by many.
const WEBGPU_MEAN_LEVELS = 0.5;
const WEBGPU_P99_LEVELS = 3;
// Each drag ends somewhere else, so every drag must change the canvas.
const DRAGS = {
  'server/point': [[-0.6, -0.5], [0.6, 0.5]],
  'server/directional': [[-0.4, 0.5], [0.5, -0.4]],
  'webgpu/point': [[0.6, -0.5], [-0.5, 0.6]],
  'webgpu/directional': [[0.5, 0.5], [-0.6, -0.3]],
};
const DRAG_EVENTS = 90;          // pointer moves per drag, one every INPUT_MS
const INPUT_MS = 1000 / 60;

function args() {
  const a = process.argv.slice(2);
  const opt = (name, dflt) => {
    const i = a.indexOf(`--${name}`);
    return i >= 0 ? a[i + 1] : dflt;
  };
  return {
    bin: opt('bin', 'target/release/nam-cli'),
    photo: opt('photo', 'assets/example_photo.png'),
    screenshots: opt('screenshots', null),
    minFps: Number(opt('min-fps', '0')),
    maxSide: opt('max-side', '256'),
    renderers: opt('renderers', 'server,webgpu').split(','),
    noPreview: process.argv.includes('--no-preview'),
    chromium: opt('chromium', process.env.CHROMIUM || '/usr/bin/chromium'),
  };
}

function fail(msg) {
  console.error(`FAIL: ${msg}`);
  process.exitCode = 1;
}

async function startViewer(bin, photo, maxSide) {
  const child = spawn(bin, ['view', photo, '--port', '0', '--backend', 'cpu', '--max-side', maxSide], {
    stdio: ['ignore', 'pipe', 'inherit'],
    env: { ...process.env, XDG_RUNTIME_DIR: process.env.XDG_RUNTIME_DIR || '/tmp' },
  });
  const lines = createInterface({ input: child.stdout });
  const url = await new Promise((resolve, reject) => {
    child.on('exit', (code) => reject(new Error(`nam-cli view exited with ${code}`)));
    lines.on('line', (l) => { if (l.startsWith('nam viewer: ')) resolve(l.slice(12).trim()); });
  });
  return { child, url };
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Waits until no frame is in flight and the last shown frame is a full one with the light the
// page wants, and stays so for 400 ms (a drag's last input may still be on its way).
async function settle(page) {
  const t0 = Date.now();
  for (;;) {
    const ok = await page.waitForFunction(() => {
      const s = window.__nam;
      const same = s.lastScene && s.wanted().every((v, k) => v === s.lastScene.light[k]);
      return s.ready && s.frames > 0 && !s.busy && same && !s.lastScene.preview;
    }, null, { timeout: 10000 }).then(() => true, () => false);
    if (!ok) {
      const st = await page.evaluate(() => {
        const s = window.__nam;
        return { frames: s.frames, busy: s.busy, last: s.lastScene, wanted: s.wanted(), status: document.getElementById('status').textContent };
      });
      if (Date.now() - t0 > 300000) throw new Error(`the page did not settle in 300 s: ${JSON.stringify(st)}`);
      console.log(`  waiting for the page: ${JSON.stringify(st)}`);
      continue;
    }
    const frames = await page.evaluate(() => window.__nam.frames);
    await sleep(400);
    if (await page.evaluate((f) => !window.__nam.busy && window.__nam.frames === f, frames)) return;
  }
}

// The canvas against the server's frame for the scene the page last showed: level differences.
async function compareWithServer(page) {
  return page.evaluate(async () => {
    const s = window.__nam.lastScene;
    const t = new URLSearchParams(location.search).get('t');
    const q = new URLSearchParams({
      t, light: s.light.join(','), view: s.view.join(','), intensity: s.intensity,
      directional: +s.directional, ortho: +s.ortho, falloff: +s.falloff, fmt: 'rgb8',
    });
    const res = await fetch(`/api/frame?${q}`);
    const want = new Uint8Array(await res.arrayBuffer());
    const c = document.getElementById('frame');
    const got = c.getContext('2d', { willReadFrequently: true }).getImageData(0, 0, c.width, c.height).data;
    const diffs = [];
    for (let p = 0; p < want.length / 3; p++) {
      for (let k = 0; k < 3; k++) diffs.push(Math.abs(got[4 * p + k] - want[3 * p + k]));
    }
    diffs.sort((a, b) => a - b);
    const mean = diffs.reduce((a, b) => a + b, 0) / diffs.length;
    return { mean, p99: diffs[Math.floor(0.99 * (diffs.length - 1))], max: diffs[diffs.length - 1], n: diffs.length };
  });
}

const canvasHash = (page) => page.evaluate(() => {
  const c = document.getElementById('frame');
  const d = c.getContext('2d', { willReadFrequently: true }).getImageData(0, 0, c.width, c.height).data;
  let h = 2166136261;
  for (let i = 0; i < d.length; i++) h = Math.imul(h ^ d[i], 16777619);
  return h >>> 0;
});

// Drags from (ax, ay) to (bx, by) in material coordinates ([-1, 1]², y up); returns fps.
async function drag(page, [ax, ay], [bx, by]) {
  await page.evaluate(() => window.scrollTo(0, 0));
  const box = await page.locator('#frame').boundingBox();
  const at = (x, y) => [box.x + (x + 1) / 2 * box.width, box.y + (1 - y) / 2 * box.height];
  const [before, previews0] = await page.evaluate(() => [window.__nam.frames, window.__nam.previews]);
  const t0 = Date.now();
  await page.mouse.move(...at(ax, ay));
  await page.mouse.down();
  for (let k = 1; k <= DRAG_EVENTS; k++) {
    const u = k / DRAG_EVENTS;
    await page.mouse.move(...at(ax + u * (bx - ax), ay + u * (by - ay)));
    const next = t0 + k * INPUT_MS;
    if (next > Date.now()) await sleep(next - Date.now());
  }
  const seconds = (Date.now() - t0) / 1000;
  const frames = (await page.evaluate(() => window.__nam.frames)) - before;
  const previews = (await page.evaluate(() => window.__nam.previews)) - previews0;
  // Rest on the end point before letting go, as a hand does (Chromium may merge the last moves).
  await sleep(150);
  await page.mouse.move(...at(bx, by));
  await sleep(150);
  await page.mouse.up();
  return { fps: frames / seconds, frames, seconds, previews };
}

async function main() {
  const opt = args();
  const { child, url } = await startViewer(opt.bin, opt.photo, opt.maxSide);
  const browser = await chromium.launch({
    executablePath: opt.chromium,
    headless: true,
    args: ['--no-sandbox', '--disable-gpu-sandbox', '--no-first-run', '--disable-background-networking',
      '--disable-component-update', '--disable-sync', '--disable-quic', '--enable-unsafe-webgpu',
      '--enable-features=Vulkan'],
  });
  const rows = [];
  try {
    const page = await browser.newPage({ viewport: { width: 1440, height: 900 } });
    const consoleErrors = [];
    page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
    page.on('pageerror', (e) => consoleErrors.push(String(e)));
    await page.goto(opt.noPreview ? `${url}&preview=0` : url);
    await settle(page);
    const webgpu = await page.evaluate(() => !document.querySelector('#renderer option[value=webgpu]').disabled);
    const adapter = await page.evaluate(() => document.querySelector('#renderer option[value=webgpu]').textContent);
    console.log(`page loaded; ${adapter}`);
    const renderers = opt.renderers.filter((r) => r === 'server' || webgpu);
    for (const renderer of renderers) {
      for (const kind of ['point', 'directional']) {
        await page.selectOption('#renderer', renderer);
        await page.setChecked('#directional', kind === 'directional');
        await page.setChecked('#ortho', kind === 'directional');
        await settle(page);
        const hashBefore = await canvasHash(page);
        const [start, end] = DRAGS[`${renderer}/${kind}`];
        console.log(`dragging: ${renderer}, ${kind} light`);
        const d = await drag(page, start, end);
        await settle(page);
        const s = await page.evaluate(() => window.__nam);
        const label = `${renderer}/${kind}`;
        if (Math.abs(s.lastScene.light[0] - end[0]) > 0.02 || Math.abs(s.lastScene.light[1] - end[1]) > 0.02) {
          fail(`${label}: the light ended at ${s.lastScene.light} instead of above ${end}`);
        }
        if (s.renderer !== renderer) fail(`${label}: the page rendered with ${s.renderer}`);
        if ((await canvasHash(page)) === hashBefore) fail(`${label}: the canvas did not change during the drag`);
        const cmp = await compareWithServer(page);
        const exact = renderer === 'server';
        if (exact ? cmp.max !== 0 : (cmp.mean > WEBGPU_MEAN_LEVELS || cmp.p99 > WEBGPU_P99_LEVELS)) {
          fail(`${label}: canvas vs server frame: mean ${cmp.mean.toFixed(3)}, p99 ${cmp.p99}, max ${cmp.max} levels`);
        }
        rows.push({ label, path: s.path, fps: d.fps, frames: d.frames, ms: s.lastMs, cmp, previews: d.previews });
        if (opt.screenshots && renderer === 'server' && kind === 'point') {
          mkdirSync(opt.screenshots, { recursive: true });
          await page.screenshot({ path: `${opt.screenshots}/viewer.png` });
        }
      }
    }
    if (consoleErrors.length) fail(`console errors: ${consoleErrors.join(' | ')}`);
  } finally {
    await browser.close();
    child.kill();
  }
  console.log(`\n| renderer / light | path | frames/s during the drag | last frame (ms) | canvas vs server frame (mean / p99 / max levels) |`);
  console.log('|---|---|---:|---:|---|');
  for (const r of rows) {
    const kind = r.previews ? ', half-resolution previews' : '';
    console.log(`| ${r.label} | ${r.path} | ${r.fps.toFixed(1)} (${r.frames} frames${kind}) | ${r.ms.toFixed(1)} | ${r.cmp.mean.toFixed(3)} / ${r.cmp.p99} / ${r.cmp.max} |`);
  }
  const best = Math.max(...rows.map((r) => r.fps));
  if (opt.minFps && !(best >= opt.minFps)) fail(`best frame rate ${best.toFixed(1)} < --min-fps ${opt.minFps}`);
  if (!process.exitCode) console.log(`\nbrowser test passed (${rows.length} drags)`);
}

main().catch((e) => { console.error(e); process.exit(1); });
