// Transposed 2-D convolution (PyTorch ConvTranspose2d, no output padding), NCHW batch 1,
// optional bias, fused activation. Used as k4 s2 p1 and k2 s2 p0 (both double H and W).
//
// Weights: [cin, cout, K, K] row-major (PyTorch ConvTranspose2d layout).
// out[co, oy, ox] = bias[co] + sum_{ci,ky,kx} x[ci, iy, ix] * w[ci, co, ky, kx]
// where oy = iy * S - pad + ky (taps whose iy is not an integer in range contribute nothing).
// Dispatch: (ceil(wo / 8), ceil(ho / 8), cout).
alias st = f32;

override K: u32 = 4u;
override S: u32 = 2u;

struct ConvTParams {
    cin: u32,
    h: u32,
    w: u32,
    cout: u32,
    ho: u32,
    wo: u32,
    pad: u32,
    in_base: u32,
    out_base: u32,
    // bit 0: add bias[co].
    flags: u32,
    // 0 none, 1 relu.
    act: u32,
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: ConvTParams;
@group(0) @binding(1) var<storage, read> src: array<st>;
@group(0) @binding(2) var<storage, read> wt: array<st>;
@group(0) @binding(3) var<storage, read> bias: array<st>;
@group(0) @binding(4) var<storage, read_write> dst: array<st>;

@compute @workgroup_size(8, 8, 1)
fn conv_transpose2d(@builtin(global_invocation_id) gid: vec3<u32>) {
    let ox = gid.x;
    let oy = gid.y;
    let co = gid.z;
    if ox >= p.wo || oy >= p.ho || co >= p.cout {
        return;
    }
    let kk = K * K;
    let hw = p.h * p.w;
    var acc = 0.0;
    for (var ky = 0u; ky < K; ky++) {
        let ny = i32(oy + p.pad) - i32(ky);
        if ny < 0 || (u32(ny) % S) != 0u {
            continue;
        }
        let iy = u32(ny) / S;
        if iy >= p.h {
            continue;
        }
        for (var kx = 0u; kx < K; kx++) {
            let nx = i32(ox + p.pad) - i32(kx);
            if nx < 0 || (u32(nx) % S) != 0u {
                continue;
            }
            let ix = u32(nx) / S;
            if ix >= p.w {
                continue;
            }
            let src_px = p.in_base + iy * p.w + ix;
            let w_tap = co * kk + ky * K + kx;
            for (var ci = 0u; ci < p.cin; ci++) {
                acc = fma(f32(src[src_px + ci * hw]), f32(wt[w_tap + ci * p.cout * kk]), acc);
            }
        }
    }
    if (p.flags & 1u) != 0u {
        acc += f32(bias[co]);
    }
    if p.act == 1u {
        acc = max(acc, 0.0);
    }
    dst[p.out_base + co * p.ho * p.wo + oy * p.wo + ox] = st(acc);
}
