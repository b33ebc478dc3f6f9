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
    var acc: array<vec4<f32>, 4>;
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
            acc[0] = fma(vec4<f32>(xs[xo]), bv, acc[0]);
            acc[1] = fma(vec4<f32>(xs[xo + 16u]), bv, acc[1]);
            acc[2] = fma(vec4<f32>(xs[xo + 32u]), bv, acc[2]);
            acc[3] = fma(vec4<f32>(xs[xo + 48u]), bv, acc[3]);
        }
        workgroupBarrier();
    }
    for (var i = 0u; i < 4u; i++) {
        let m = m0 + lid.y + 16u * i;
        if m >= p.rows {
            continue;
        }
        for (var j = 0u; j < 4u; j++) {
            let n = n0 + lid.x + 16u * j;
            if n < p.cols {
                var v = acc[i][j];
                if p.act == 2u {
                    v = select(v * p.slope, v, v >= 0.0);
                }
                y[m * p.y_stride + p.y_base + n] = st(v);
            }
        }
    }
}
