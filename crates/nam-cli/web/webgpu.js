// M_render on WebGPU in the browser, with the project's own shaders (shaders/pos_enc.wgsl and
// shaders/matmul.wgsl, served by nam-cli from the copies embedded in it) and the dispatch
// sequence of nam-gpu's buffer path: per row the positional encoding, ND_enc, then the render
// MLP on [params | ND_enc] (DESIGN §4, §9). The weights are `/api/net` + `/api/weights`
// (render.l0·l1 folded, as every backend runs them); the latent map is `/api/params`.
//
// Directions are computed here in f32 exactly as nam-ggx's `Directions::at` does for the
// networks (every operation rounded with Math.fround), so this path sees the same inputs as the
// server's. A directional light with an orthographic view runs ND_enc on one row and
// broadcasts its features to every row with the same matmul kernel (a [N, 1] column of ones
// times the [32, 1] features), as nam-gpu's ConstantDirections plan does.

const f = Math.fround;
const CHUNK = 16384;              // rows per submission: 16384 x 594 f32 = 39 MB per buffer
const DIRECTION_GUARD = f(1e-12); // nam-ggx DIRECTION_GUARD: |v|^2 below it is degenerate
const LN_F32_MAX = 88.72283;      // nam-weights radiance_from_log: expm1 stays finite

export async function createWebGpu() {
  if (!navigator.gpu) return null;
  const adapter = await navigator.gpu.requestAdapter();
  if (!adapter) return null;
  const info = adapter.info || {};
  const device = await adapter.requestDevice({
    requiredLimits: {
      maxStorageBufferBindingSize: adapter.limits.maxStorageBufferBindingSize,
      maxBufferSize: adapter.limits.maxBufferSize,
    },
  });
  return new WebGpuRenderer(device, [info.vendor, info.architecture, info.description].filter(Boolean).join(' ') || 'adapter');
}

function unit(x, y, z) {
  const n2 = f(f(f(x * x) + f(y * y)) + f(z * z));
  if (!(n2 >= DIRECTION_GUARD && Number.isFinite(n2))) return [0, 0, 1];
  const n = f(Math.sqrt(n2));
  return [f(x / n), f(y / n), f(z / n)];
}

// [wi, wo, wh] at surface point p for a source {point: bool, v: [x, y, z]} (f32 throughout).
function towards(src, px, py) {
  const [x, y, z] = src.v;
  return src.point ? unit(f(x - px), f(y - py), z) : unit(x, y, z);
}

function triple(light, view, px, py, out, o) {
  const wi = towards(light, px, py);
  const wo = towards(view, px, py);
  const wh = unit(f(wi[0] + wo[0]), f(wi[1] + wo[1]), f(wi[2] + wo[2]));
  out.set(wi, o); out.set(wo, o + 3); out.set(wh, o + 6);
}

const srgb = (v) => {
  const c = Math.min(Math.max(v, 0), 1);
  return c <= 0.0031308 ? 12.92 * c : 1.055 * Math.pow(c, 1 / 2.4) - 0.055;
};

class WebGpuRenderer {
  constructor(device, label) {
    this.device = device;
    this.label = label;
    this.ready = false;
  }

  describe() { return this.label; }

  // Fetches the shaders, the layers and the current material; builds buffers and pipelines.
  async load(api, state) {
    const dev = this.device;
    const get = async (url, kind) => {
      const r = await fetch(url);
      if (!r.ok) throw new Error(`${url.split('?')[0]}: ${r.status}`);
      return kind === 'json' ? r.json() : kind === 'text' ? r.text() : r.arrayBuffer();
    };
    if (!this.pipelines) {
      const [pe, mm, net, weights] = await Promise.all([
        get('/shaders/pos_enc.wgsl', 'text'), get('/shaders/matmul.wgsl', 'text'),
        get(api('net'), 'json'), get(api('weights'), 'bin'),
      ]);
      this.net = net;
      const all = new Float32Array(weights);
      let off = 0;
      const upload = (l) => {
        const n = l.out * l.inp;
        const buf = this.storage(n, GPUBufferUsage.COPY_DST);
        dev.queue.writeBuffer(buf, 0, all, off, n);
        off += n;
        return { ...l, buf };
      };
      this.nd = net.nd_enc.map(upload);
      this.mlp = net.mlp.map(upload);
      if (off !== all.length) throw new Error(`weights: ${all.length} floats, layers need ${off}`);
      const module = (code) => dev.createShaderModule({ code });
      this.pipelines = {
        pe: dev.createComputePipeline({ layout: 'auto', compute: { module: module(pe), entryPoint: 'pos_enc', constants: { OCTAVES: net.octaves } } }),
        mm: dev.createComputePipeline({ layout: 'auto', compute: { module: module(mm), entryPoint: 'matmul' } }),
      };
    }
    const m = state.material;
    const params = new Float32Array(await get(api('params', { g: state.generation }), 'bin'));
    const pc = this.net.param_channels;
    const ndOut = this.nd[this.nd.length - 1].out;
    const n = m.width * m.height;
    if (params.length !== n * pc) throw new Error(`params: ${params.length} floats for ${n} pixels`);
    this.width = m.width;
    this.height = m.height;
    this.unitDistance = state.unit_light_distance;
    this.catW = pc + ndOut;
    // [params | ND_enc features] per pixel; the params are written once per material.
    const cat = new Float32Array(n * this.catW);
    for (let p = 0; p < n; p++) cat.set(params.subarray(p * pc, (p + 1) * pc), p * this.catW);
    this.destroyFrameBuffers();
    const rows = Math.min(CHUNK, n);
    const widest = Math.max(...[...this.nd, ...this.mlp].map((l) => Math.max(l.out, l.inp)));
    this.bufs = {
      cat: this.storage(n * this.catW, GPUBufferUsage.COPY_DST),
      dirs: this.storage(rows * 9, GPUBufferUsage.COPY_DST),
      enc: this.storage(rows * this.net.encoding),
      ping: [this.storage(rows * widest), this.storage(rows * widest)],
      feat: this.storage(ndOut),
      ones: this.storage(n, GPUBufferUsage.COPY_DST),
      out: this.storage(n * 3, GPUBufferUsage.COPY_SRC),
      read: dev.createBuffer({ size: n * 3 * 4, usage: GPUBufferUsage.MAP_READ | GPUBufferUsage.COPY_DST }),
    };
    dev.queue.writeBuffer(this.bufs.cat, 0, cat);
    dev.queue.writeBuffer(this.bufs.ones, 0, new Float32Array(n).fill(1));
    this.dirs = new Float32Array(rows * 9);
    this.ready = true;
  }

  storage(floats, extra = 0) {
    return this.device.createBuffer({ size: Math.max(16, floats * 4), usage: GPUBufferUsage.STORAGE | extra });
  }

  destroyFrameBuffers() {
    if (!this.bufs) return;
    for (const b of Object.values(this.bufs).flat()) b.destroy();
    this.bufs = null;
  }

  // A matmul dispatch: Y[m, yBase + n] = act(sum_k X[m, xBase + k] W[n, k]) (matmul.wgsl).
  matmul(pass, uniforms, { x, xStride, xBase, w, y, yStride, yBase, rows, cols, inner, slope }) {
    const u = new ArrayBuffer(48);
    new Uint32Array(u, 0, 8).set([rows, cols, inner, xStride, xBase, yStride, yBase, slope == null ? 0 : 2]);
    new Float32Array(u, 32, 1)[0] = slope ?? 0;
    const ub = this.device.createBuffer({ size: 48, usage: GPUBufferUsage.UNIFORM | GPUBufferUsage.COPY_DST });
    this.device.queue.writeBuffer(ub, 0, u);
    uniforms.push(ub);
    const p = this.pipelines.mm;
    pass.setPipeline(p);
    pass.setBindGroup(0, this.device.createBindGroup({
      layout: p.getBindGroupLayout(0),
      entries: [ub, x, w, y].map((buffer, binding) => ({ binding, resource: { buffer } })),
    }));
    pass.dispatchWorkgroups(Math.ceil(cols / 64), Math.ceil(rows / 64));
  }

  posEnc(pass, uniforms, rows) {
    const ub = this.device.createBuffer({ size: 16, usage: GPUBufferUsage.UNIFORM | GPUBufferUsage.COPY_DST });
    this.device.queue.writeBuffer(ub, 0, new Uint32Array([rows, this.net.encoding, 0, 0]));
    uniforms.push(ub);
    const p = this.pipelines.pe;
    pass.setPipeline(p);
    pass.setBindGroup(0, this.device.createBindGroup({
      layout: p.getBindGroupLayout(0),
      entries: [ub, this.bufs.dirs, this.bufs.enc].map((buffer, binding) => ({ binding, resource: { buffer } })),
    }));
    const groups = Math.ceil(rows * 9 / 64);
    const gx = Math.min(groups, 65535);
    pass.dispatchWorkgroups(gx, Math.ceil(groups / gx));
  }

  // ND_enc on `rows` encoded rows into Y (the last layer's output at yBase, stride yStride).
  ndChain(pass, uniforms, rows, y, yStride, yBase) {
    const b = this.bufs;
    let x = b.enc; let xStride = this.net.encoding;
    this.nd.forEach((l, i) => {
      const last = i === this.nd.length - 1;
      const dst = last ? y : b.ping[i % 2];
      this.matmul(pass, uniforms, {
        x, xStride, xBase: 0, w: l.buf, y: dst, yStride: last ? yStride : l.out, yBase: last ? yBase : 0,
        rows, cols: l.out, inner: l.inp, slope: l.slope,
      });
      x = dst; xStride = l.out;
    });
  }

  // The render MLP on rows r0 .. r0 + rows of [params | features] into the log output.
  mlpChain(pass, uniforms, r0, rows) {
    const b = this.bufs;
    let x = b.cat; let xStride = this.catW; let xBase = r0 * this.catW;
    this.mlp.forEach((l, i) => {
      const last = i === this.mlp.length - 1;
      const dst = last ? b.out : b.ping[i % 2];
      this.matmul(pass, uniforms, {
        x, xStride, xBase, w: l.buf, y: dst, yStride: last ? 3 : l.out, yBase: last ? r0 * 3 : 0,
        rows, cols: l.out, inner: l.inp, slope: l.slope,
      });
      x = dst; xStride = l.out; xBase = 0;
    });
  }

  // Renders scene {light, directional, view, ortho, intensity, falloff}: {rgb (8-bit sRGB), width, height}.
  async render(s) {
    if (!this.ready) throw new Error('WebGPU renderer has no material yet');
    const dev = this.device;
    const { width: w, height: h } = this;
    const n = w * h;
    const pc = this.net.param_channels;
    const light = { point: !s.directional, v: s.light.map(f) };
    const view = { point: !s.ortho, v: s.view.map(f) };
    const uniforms = [];
    const constant = !light.point && !view.point;
    if (constant) {
      // One row of directions; its features broadcast to every row.
      triple(light, view, 0, 0, this.dirs, 0);
      dev.queue.writeBuffer(this.bufs.dirs, 0, this.dirs, 0, 9);
      const enc = dev.createCommandEncoder();
      const pass = enc.beginComputePass();
      this.posEnc(pass, uniforms, 1);
      this.ndChain(pass, uniforms, 1, this.bufs.feat, this.nd[this.nd.length - 1].out, 0);
      this.matmul(pass, uniforms, {
        x: this.bufs.ones, xStride: 1, xBase: 0, w: this.bufs.feat, y: this.bufs.cat,
        yStride: this.catW, yBase: pc, rows: n, cols: this.catW - pc, inner: 1, slope: null,
      });
      for (let r0 = 0; r0 < n; r0 += CHUNK) this.mlpChain(pass, uniforms, r0, Math.min(CHUNK, n - r0));
      pass.end();
      dev.queue.submit([enc.finish()]);
    } else {
      for (let r0 = 0; r0 < n; r0 += CHUNK) {
        const rows = Math.min(CHUNK, n - r0);
        for (let k = 0; k < rows; k++) {
          const i = Math.floor((r0 + k) / w); const j = (r0 + k) % w;
          // nam-ggx pixel_position in f32: x = 2(j + 0.5)/W - 1, y = -2(i + 0.5)/H + 1.
          const px = f(f(f(2 * f(j + 0.5)) / f(w)) - 1);
          const py = f(f(f(-2 * f(i + 0.5)) / f(h)) + 1);
          triple(light, view, px, py, this.dirs, 9 * k);
        }
        dev.queue.writeBuffer(this.bufs.dirs, 0, this.dirs, 0, rows * 9);
        const enc = dev.createCommandEncoder();
        const pass = enc.beginComputePass();
        this.posEnc(pass, uniforms, rows);
        this.ndChain(pass, uniforms, rows, this.bufs.cat, this.catW, r0 * this.catW + pc);
        this.mlpChain(pass, uniforms, r0, rows);
        pass.end();
        dev.queue.submit([enc.finish()]);
      }
    }
    const enc = dev.createCommandEncoder();
    enc.copyBufferToBuffer(this.bufs.out, 0, this.bufs.read, 0, n * 3 * 4);
    dev.queue.submit([enc.finish()]);
    await this.bufs.read.mapAsync(GPUMapMode.READ);
    const y = new Float32Array(this.bufs.read.getMappedRange().slice(0));
    this.bufs.read.unmap();
    for (const u of uniforms) u.destroy();
    // Radiance = max(expm1(y), 0) x intensity (x d^2 / |light - p|^2 with falloff), as
    // nam::relight; then 8-bit sRGB as nam-cli writes PNGs.
    const rgb = new Uint8Array(n * 3);
    const d2 = this.unitDistance * this.unitDistance;
    for (let p = 0; p < n; p++) {
      let scale = s.intensity;
      if (s.falloff && light.point) {
        const px = 2 * ((p % w) + 0.5) / w - 1;
        const py = -2 * (Math.floor(p / w) + 0.5) / h + 1;
        const [lx, ly, lz] = s.light;
        const r2 = (lx - px) ** 2 + (ly - py) ** 2 + lz * lz;
        scale *= r2 > 0 ? d2 / r2 : 0;
      }
      for (let c = 0; c < 3; c++) {
        const r = Math.max(Math.expm1(Math.min(y[3 * p + c], LN_F32_MAX)), 0);
        rgb[3 * p + c] = Math.round(srgb(f(f(r) * f(scale))) * 255);
      }
    }
    return { rgb, width: w, height: h };
  }
}
