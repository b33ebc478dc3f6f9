// Convolutions for CPU adapters (llvmpipe) as implicit GEMMs on texture operands, the recipe of
// `matmul_tex.wgsl` (see there for why textures and subgroup broadcasts): the GEMM rows are
// output pixels, its columns output channels, its inner dimension (tap, input channel).
// Input: the channel-block texture of `tex_pack.wgsl` (texel (x, l * h + y) = channels 4 l .. + 3
// of input pixel (x, y)); taps read it at clamped coordinates, so no im2col buffer exists.
// Weights: a matrix texture, row = output channel, texel (ky * K + kx) * cin4 + l = input
// channels 4 l .. + 3 of that tap (zero-padded; PyTorch's [cout, cin, K, K] for `conv_tex`,
// [cin, cout, K, K] for `conv_t_tex`, rearranged on upload).
// Each workgroup (8 invocations, one subgroup) computes 16 output pixels x 16 output channels:
// invocation i owns pixels 16 b + i and 16 b + 8 + i of the output plane and fetches weight
// rows n0 + i and n0 + 8 + i, which `subgroupBroadcast` hands to every lane (32 FMAs per pair
// of input texels). The epilogue adds the bias, applies the activation and stores NCHW into
// `dst` from element `out_base`, so the gating, norm and residual kernels read buffers as before.
// Dispatch: x + y * groups_x = pixel block b (16 pixels; for `conv_t_tex` 4 phases of
// `phase_blocks` blocks), z = output-channel block of 16.
// The multiply-add body `mac` and its accumulators `Acc` are `subgroup_mac.wgsl`, appended by
// the host (shared with `matmul_tex.wgsl`).
alias st = f32;

// Kernel size, a pipeline constant so the tap loops have constant bounds.
override K: u32 = 3u;

struct ConvTexParams {
    // Input texels per pixel: ceil(cin / 4).
    cin4: u32,
    h: u32,
    w: u32,
    cout: u32,
    ho: u32,
    wo: u32,
    stride: u32,
    pad: u32,
    // Element offset of the output tensor inside `dst`.
    out_base: u32,
    // bit 0: add bias[co].
    flags: u32,
    // 0 none, 2 leaky relu(slope).
    act: u32,
    slope: f32,
    // `conv_t_tex`: pixel blocks of one output phase, ceil(h * w / 16).
    phase_blocks: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: ConvTexParams;
@group(0) @binding(1) var xt: texture_2d<f32>;
@group(0) @binding(2) var wt: texture_2d<f32>;
@group(0) @binding(3) var<storage, read> bias: array<st>;
@group(0) @binding(4) var<storage, read_write> dst: array<st>;

// ReLU is LeakyReLU(0) (its -0 for negative inputs compares equal to 0).
fn activate(v: vec4<f32>) -> vec4<f32> {
    if p.act == 2u {
        return select(v * p.slope, v, v >= vec4<f32>(0.0));
    }
    return v;
}

// Writes channels n0 .. n0 + 3 of output pixel `pix` (element offset in the plane), within
// bounds; `valid` is false for the tail lanes of the last pixel block.
fn store4(valid: bool, pix: u32, n0: u32, v: vec4<f32>) {
    if !valid || n0 >= p.cout {
        return;
    }
    var b = vec4<f32>(0.0);
    if (p.flags & 1u) != 0u {
        let last = p.cout - 1u;
        b = vec4<f32>(f32(bias[n0]), f32(bias[min(n0 + 1u, last)]), f32(bias[min(n0 + 2u, last)]), f32(bias[min(n0 + 3u, last)]));
    }
    let a = activate(v + b);
    let plane = p.ho * p.wo;
    let o = p.out_base + n0 * plane + pix;
    dst[o] = st(a.x);
    if n0 + 1u < p.cout { dst[o + plane] = st(a.y); }
    if n0 + 2u < p.cout { dst[o + 2u * plane] = st(a.z); }
    if n0 + 3u < p.cout { dst[o + 3u * plane] = st(a.w); }
}

fn store_all(acc: Acc, v0: bool, pix0: u32, v1: bool, pix1: u32, n0: u32) {
    store4(v0, pix0, n0, acc.a0_0);
    store4(v0, pix0, n0 + 4u, acc.a0_1);
    store4(v0, pix0, n0 + 8u, acc.a0_2);
    store4(v0, pix0, n0 + 12u, acc.a0_3);
    store4(v1, pix1, n0, acc.a1_0);
    store4(v1, pix1, n0 + 4u, acc.a1_1);
    store4(v1, pix1, n0 + 8u, acc.a1_2);
    store4(v1, pix1, n0 + 12u, acc.a1_3);
}

// Convolution with replicate padding (stride `stride`, padding `pad`).
@compute @workgroup_size(8, 1, 1)
fn conv_tex(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(subgroup_invocation_id) sid: u32,
) {
    let plane = p.ho * p.wo;
    let blk = wid.x + wid.y * nwg.x;
    if blk * 16u >= plane {
        return;
    }
    let n0 = wid.z * 16u;
    let m0 = blk * 16u + lid.x;
    let m1 = m0 + 8u;
    let q0 = min(m0, plane - 1u);
    let q1 = min(m1, plane - 1u);
    let iy0 = i32((q0 / p.wo) * p.stride) - i32(p.pad);
    let ix0 = i32((q0 % p.wo) * p.stride) - i32(p.pad);
    let iy1 = i32((q1 / p.wo) * p.stride) - i32(p.pad);
    let ix1 = i32((q1 % p.wo) * p.stride) - i32(p.pad);
    let hmax = i32(p.h) - 1;
    let wmax = i32(p.w) - 1;
    let wn0 = min(n0 + sid, p.cout - 1u);
    let wn1 = min(n0 + 8u + sid, p.cout - 1u);
    var acc: Acc;
    for (var ky = 0u; ky < K; ky++) {
        let y0 = u32(clamp(iy0 + i32(ky), 0, hmax));
        let y1 = u32(clamp(iy1 + i32(ky), 0, hmax));
        for (var kx = 0u; kx < K; kx++) {
            let x0 = u32(clamp(ix0 + i32(kx), 0, wmax));
            let x1 = u32(clamp(ix1 + i32(kx), 0, wmax));
            let wcol = (ky * K + kx) * p.cin4;
            for (var l = 0u; l < p.cin4; l++) {
                let band = l * p.h;
                let xa = textureLoad(xt, vec2<u32>(x0, band + y0), 0);
                let xb = textureLoad(xt, vec2<u32>(x1, band + y1), 0);
                let wa = textureLoad(wt, vec2<u32>(wcol + l, wn0), 0);
                let wb = textureLoad(wt, vec2<u32>(wcol + l, wn1), 0);
                mac(&acc, xa, xb, wa, wb);
            }
        }
    }
    store_all(acc, m0 < plane, q0, m1 < plane, q1, n0);
}

// Transposed convolution, stride 2 (PyTorch ConvTranspose2d: output 2 h x 2 w for K = 4, pad 1
// and K = 2, pad 0). Output pixel (2 qy + py, 2 qx + px) only receives taps with
// ky = py + pad (mod 2), from input row qy + (py + pad - ky) / 2 (zero outside the input);
// each workgroup stays in one phase (py, px), so the tap loop is uniform.
@compute @workgroup_size(8, 1, 1)
fn conv_t_tex(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(subgroup_invocation_id) sid: u32,
) {
    let hw = p.h * p.w;
    let blk = wid.x + wid.y * nwg.x;
    let phase = blk / p.phase_blocks;
    let pb = blk % p.phase_blocks;
    if phase >= 4u || pb * 16u >= hw {
        return;
    }
    let py = phase / 2u;
    let px = phase % 2u;
    let n0 = wid.z * 16u;
    let m0 = pb * 16u + lid.x;
    let m1 = m0 + 8u;
    let q0 = min(m0, hw - 1u);
    let q1 = min(m1, hw - 1u);
    let qy0 = i32(q0 / p.w);
    let qx0 = i32(q0 % p.w);
    let qy1 = i32(q1 / p.w);
    let qx1 = i32(q1 % p.w);
    let hmax = i32(p.h) - 1;
    let wmax = i32(p.w) - 1;
    let wn0 = min(n0 + sid, p.cout - 1u);
    let wn1 = min(n0 + 8u + sid, p.cout - 1u);
    var acc: Acc;
    for (var ky = (py + p.pad) % 2u; ky < K; ky += 2u) {
        let dy = (i32(py + p.pad) - i32(ky)) / 2;
        let y0 = qy0 + dy;
        let y1 = qy1 + dy;
        for (var kx = (px + p.pad) % 2u; kx < K; kx += 2u) {
            let dx = (i32(px + p.pad) - i32(kx)) / 2;
            let x0 = qx0 + dx;
            let x1 = qx1 + dx;
            let in0 = y0 >= 0 && y0 <= hmax && x0 >= 0 && x0 <= wmax;
            let in1 = y1 >= 0 && y1 <= hmax && x1 >= 0 && x1 <= wmax;
            let cy0 = u32(clamp(y0, 0, hmax));
            let cx0 = u32(clamp(x0, 0, wmax));
            let cy1 = u32(clamp(y1, 0, hmax));
            let cx1 = u32(clamp(x1, 0, wmax));
            let wcol = (ky * K + kx) * p.cin4;
            for (var l = 0u; l < p.cin4; l++) {
                let band = l * p.h;
                let xa = select(vec4<f32>(0.0), textureLoad(xt, vec2<u32>(cx0, band + cy0), 0), in0);
                let xb = select(vec4<f32>(0.0), textureLoad(xt, vec2<u32>(cx1, band + cy1), 0), in1);
                let wa = textureLoad(wt, vec2<u32>(wcol + l, wn0), 0);
                let wb = textureLoad(wt, vec2<u32>(wcol + l, wn1), 0);
                mac(&acc, xa, xb, wa, wb);
            }
        }
    }
    let pix0 = u32(2 * qy0 + i32(py)) * p.wo + u32(2 * qx0 + i32(px));
    let pix1 = u32(2 * qy1 + i32(py)) * p.wo + u32(2 * qx1 + i32(px));
    store_all(acc, m0 < hw, pix0, m1 < hw, pix1, n0);
}
