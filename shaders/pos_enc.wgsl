// Positional encoding of the 9 direction values c = [wi, wo, wh] per query (DESIGN §4):
//   enc[0..9] = c;  enc[9 + 18k + 2j] = sin(2^k pi c_j), enc[9 + 18k + 2j + 1] = cos(2^k pi c_j)
// for octaves k in 0..OCTAVES. Arguments reach 2^15 pi, far outside the range where WGSL's
// sin/cos are accurate, so the argument is reduced exactly: 2^k pi c = 2 pi t with
// t = fract(2^(k-1) c) (a power-of-two scaling and fract are exact in binary floating point),
// t folded to [-1/2, 1/2), then sin/cos(2 pi t) come from quadrant reduction and Taylor
// polynomials on [-pi/4, pi/4] (error < 1e-7, independent of the platform's sin/cos).
//
// Input `dirs`: [n, 9] rows, f32. Output `dst`: row r starts at out_base + r * out_stride.
// One invocation per (row, j). Dispatch: 64-wide workgroups over n * 9, split over x and y.
// `pos_enc_tex` writes the same channels into the rgba texture `dst_tex` instead (texel (c / 4,
// row) holds channels c .. c + 3; channels past the encoding are 0), one invocation per
// (row, texel) with out_stride = texels per row; `dst` is unused there, as is `dst_tex` in
// `pos_enc`.
alias st = f32;

override OCTAVES: u32 = 16u;

struct PeParams {
    n: u32,
    out_stride: u32,
    out_base: u32,
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: PeParams;
// Directions stay f32 in both variants: an f16 c would move 2^15·π·c by up to ~25 rad.
@group(0) @binding(1) var<storage, read> dirs: array<f32>;
@group(0) @binding(2) var<storage, read_write> dst: array<st>;
@group(0) @binding(3) var dst_tex: texture_storage_2d<rgba32float, write>;

const HALF_PI: f32 = 1.5707963267948966;

// (sin(2 pi t), cos(2 pi t)) for t in [-1/2, 1/2].
fn sincos_2pi(t: f32) -> vec2<f32> {
    let u = 4.0 * t;             // exact
    let q = round(u);            // quadrant in -2..2
    let r = (u - q) * HALF_PI;   // u - q is exact; r in [-pi/4, pi/4]
    let r2 = r * r;
    // Taylor series to r^11 / r^12: truncation error below 2e-10 on [-pi/4, pi/4].
    let s = r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0
        + r2 * (1.0 / 362880.0 + r2 * (-1.0 / 39916800.0))))));
    let c = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40320.0
        + r2 * (-1.0 / 3628800.0 + r2 * (1.0 / 479001600.0))))));
    // sin/cos(q pi/2 + r) by quadrant.
    switch u32(i32(q) & 3) {
        case 1u: { return vec2<f32>(c, -s); }
        case 2u: { return vec2<f32>(-s, -c); }
        case 3u: { return vec2<f32>(-c, s); }
        default: { return vec2<f32>(s, c); }
    }
}

@compute @workgroup_size(64, 1, 1)
fn pos_enc(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = gid.x + gid.y * nwg.x * 64u;
    if idx >= p.n * 9u {
        return;
    }
    let row = idx / 9u;
    let j = idx % 9u;
    let x = dirs[idx];
    let base = p.out_base + row * p.out_stride;
    dst[base + j] = st(x);
    var scale = 0.5;
    for (var k = 0u; k < OCTAVES; k++) {
        var t = fract(scale * x);
        t = select(t, t - 1.0, t >= 0.5);
        let sc = sincos_2pi(t);
        let o = base + 9u + 18u * k + 2u * j;
        dst[o] = st(sc.x);
        dst[o + 1u] = st(sc.y);
        scale *= 2.0;
    }
}

// Channel `c` of the encoding of `row` (0 past the last channel).
fn channel(row: u32, c: u32) -> f32 {
    if c < 9u {
        return dirs[row * 9u + c];
    }
    let cc = c - 9u;
    let k = cc / 18u;
    if k >= OCTAVES {
        return 0.0;
    }
    let j = (cc % 18u) / 2u;
    let x = dirs[row * 9u + j];
    // 2^(k-1), exact, as the repeated doubling in `pos_enc`.
    var t = fract(ldexp(0.5, i32(k)) * x);
    t = select(t, t - 1.0, t >= 0.5);
    let sc = sincos_2pi(t);
    return select(sc.y, sc.x, cc % 2u == 0u);
}

@compute @workgroup_size(64, 1, 1)
fn pos_enc_tex(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = gid.x + gid.y * nwg.x * 64u;
    if idx >= p.n * p.out_stride {
        return;
    }
    let row = idx / p.out_stride;
    let t = idx % p.out_stride;
    let c = 4u * t;
    let v = vec4<f32>(channel(row, c), channel(row, c + 1u), channel(row, c + 2u), channel(row, c + 3u));
    // Rounded to the storage type first (see `epilogue` in matmul_tex.wgsl).
    textureStore(dst_tex, vec2<u32>(t, row), vec4<f32>(vec4<st>(v)));
}
