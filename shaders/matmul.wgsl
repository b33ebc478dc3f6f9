// Tiled matrix multiply for the bias-free MLP layers, with a fused activation:
//   Y[m, y_base + n] = act(sum_k X[m, x_base + k] * W[n, k])     (m < rows, n < cols, k < inner)
// X rows have stride x_stride, Y rows y_stride (elements), so layers can read and write column
// ranges of wider buffers (the [params | nd_enc] concat needs no copy). W is [cols, inner]
// row-major (PyTorch Linear layout).
// Each 16x16 workgroup computes a 64x64 tile of Y; each invocation a 4x4 sub-tile with rows
// ty + 16 i and cols tx + 16 j. K is staged through workgroup memory in 16-wide slices
// (2 x 4 KiB, f32 in workgroup memory for either storage type: accumulation is f32).
// Dispatch: (ceil(cols / 64), ceil(rows / 64), 1).
alias st = f32;

struct MatmulParams {
    rows: u32,
    cols: u32,
    inner: u32,
    x_stride: u32,
    x_base: u32,
    y_stride: u32,
    y_base: u32,
    // 0 none, 2 leaky relu(slope).
    act: u32,
    slope: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: MatmulParams;
@group(0) @binding(1) var<storage, read> x: array<st>;
@group(0) @binding(2) var<storage, read> w: array<st>;
@group(0) @binding(3) var<storage, read_write> y: array<st>;

const TILE: u32 = 64u;
const BK: u32 = 16u;
var<workgroup> xs: array<f32, 1024>; // [BK][TILE]
var<workgroup> ws: array<f32, 1024>; // [BK][TILE]

@compute @workgroup_size(16, 16, 1)
fn matmul(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let m0 = wid.y * TILE;
    let n0 = wid.x * TILE;
    // Named accumulators (no dynamically indexed array) stay in registers on every backend;
    // llvmpipe spills an indexed private array to memory.
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var k0 = 0u; k0 < p.inner; k0 += BK) {
        for (var e = li; e < TILE * BK; e += 256u) {
            let r = e / BK;
            let kk = e % BK;
            let k = k0 + kk;
            var xv = 0.0;
            if m0 + r < p.rows && k < p.inner {
                xv = f32(x[(m0 + r) * p.x_stride + p.x_base + k]);
            }
            xs[kk * TILE + r] = xv;
            var wv = 0.0;
            if n0 + r < p.cols && k < p.inner {
                wv = f32(w[(n0 + r) * p.inner + k]);
            }
            ws[kk * TILE + r] = wv;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < BK; kk++) {
            let xo = kk * TILE + lid.y;
            let wo = kk * TILE + lid.x;
            let bv = vec4<f32>(ws[wo], ws[wo + 16u], ws[wo + 32u], ws[wo + 48u]);
            acc0 = fma(vec4<f32>(xs[xo]), bv, acc0);
            acc1 = fma(vec4<f32>(xs[xo + 16u]), bv, acc1);
            acc2 = fma(vec4<f32>(xs[xo + 32u]), bv, acc2);
            acc3 = fma(vec4<f32>(xs[xo + 48u]), bv, acc3);
        }
        workgroupBarrier();
    }
    store_row(m0 + lid.y, n0 + lid.x, acc0);
    store_row(m0 + lid.y + 16u, n0 + lid.x, acc1);
    store_row(m0 + lid.y + 32u, n0 + lid.x, acc2);
    store_row(m0 + lid.y + 48u, n0 + lid.x, acc3);
}

// Writes y[m, n + 16 j] = act(v[j]) for j in 0..4, within bounds.
fn store_row(m: u32, n: u32, v: vec4<f32>) {
    if m >= p.rows {
        return;
    }
    var a = v;
    if p.act == 2u {
        a = select(v * p.slope, v, v >= vec4<f32>(0.0));
    }
    let row = m * p.y_stride + p.y_base;
    if n < p.cols { y[row + n] = st(a.x); }
    if n + 16u < p.cols { y[row + n + 16u] = st(a.y); }
    if n + 32u < p.cols { y[row + n + 32u] = st(a.z); }
    if n + 48u < p.cols { y[row + n + 48u] = st(a.w); }
}

// Barrier-free variant for CPU adapters (llvmpipe runs workgroup barriers as coroutine
// switches, which costs more than the reuse they buy; the CPU caches play the role of
// workgroup memory). Each invocation computes rows 4 gy .. 4 gy + 3 and columns
// gx + 16 j (j < 4) straight from storage. Dispatch: (ceil(cols / 64), ceil(rows / 4), 1)
// workgroups of 16.
@compute @workgroup_size(16, 1, 1)
fn matmul_direct(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let m0 = gid.y * 4u;
    let n0 = wid.x * TILE + lid.x;
    let last_m = p.rows - 1u;
    let last_n = p.cols - 1u;
    let xr0 = min(m0, last_m) * p.x_stride + p.x_base;
    let xr1 = min(m0 + 1u, last_m) * p.x_stride + p.x_base;
    let xr2 = min(m0 + 2u, last_m) * p.x_stride + p.x_base;
    let xr3 = min(m0 + 3u, last_m) * p.x_stride + p.x_base;
    let wr0 = min(n0, last_n) * p.inner;
    let wr1 = min(n0 + 16u, last_n) * p.inner;
    let wr2 = min(n0 + 32u, last_n) * p.inner;
    let wr3 = min(n0 + 48u, last_n) * p.inner;
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var k = 0u; k < p.inner; k++) {
        let bv = vec4<f32>(f32(w[wr0 + k]), f32(w[wr1 + k]), f32(w[wr2 + k]), f32(w[wr3 + k]));
        acc0 = fma(vec4<f32>(f32(x[xr0 + k])), bv, acc0);
        acc1 = fma(vec4<f32>(f32(x[xr1 + k])), bv, acc1);
        acc2 = fma(vec4<f32>(f32(x[xr2 + k])), bv, acc2);
        acc3 = fma(vec4<f32>(f32(x[xr3 + k])), bv, acc3);
    }
    store_row(m0, n0, acc0);
    store_row(m0 + 1u, n0, acc1);
    store_row(m0 + 2u, n0, acc2);
    store_row(m0 + 3u, n0, acc3);
}
