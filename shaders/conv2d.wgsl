// 2-D convolution, NCHW (batch 1), replicate padding, optional bias, optional per-input-channel
// affine on load (used to fuse InstanceNorm into the following conv), fused activation.
//
// Weights: [cout, cin, K, K] row-major (PyTorch Conv2d layout).
// Each invocation computes one output pixel for CO_BLOCK consecutive output channels, so every
// input load is reused CO_BLOCK times.
// Dispatch: (ceil(wo / 8), ceil(ho / 8), ceil(cout / CO_BLOCK)).
//
// `st` is the storage type: the f16 variant replaces this alias (accumulation stays f32).
alias st = f32;

// Kernel size, a pipeline constant so the tap loops have constant bounds.
override K: u32 = 3u;

struct ConvParams {
    cin: u32,
    h: u32,
    w: u32,
    cout: u32,
    ho: u32,
    wo: u32,
    stride: u32,
    pad: u32,
    // Element offset of the input tensor inside `src` (views into concat buffers).
    in_base: u32,
    // Element offset of the output tensor inside `dst`.
    out_base: u32,
    // bit 0: add bias[co]; bit 1: x * norm[2ci] + norm[2ci + 1] on load.
    flags: u32,
    // 0 none, 2 leaky relu(slope) (the codes of matmul.wgsl).
    act: u32,
    slope: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: ConvParams;
@group(0) @binding(1) var<storage, read> src: array<st>;
@group(0) @binding(2) var<storage, read> wt: array<st>;
@group(0) @binding(3) var<storage, read> bias: array<st>;
@group(0) @binding(4) var<storage, read> norm: array<f32>;
@group(0) @binding(5) var<storage, read_write> dst: array<st>;

const CO_BLOCK: u32 = 4u;

fn activate(v: f32, act: u32, slope: f32) -> f32 {
    if act == 2u {
        return select(v * slope, v, v >= 0.0);
    }
    return v;
}

@compute @workgroup_size(8, 8, 1)
fn conv2d(@builtin(global_invocation_id) gid: vec3<u32>) {
    let ox = gid.x;
    let oy = gid.y;
    let co0 = gid.z * CO_BLOCK;
    if ox >= p.wo || oy >= p.ho || co0 >= p.cout {
        return;
    }
    let kk = K * K;
    let w_co_stride = p.cin * kk;
    // Clamp the channel index of the block tail; those lanes are computed and discarded.
    let last_co = p.cout - 1u;
    let wb0 = min(co0, last_co) * w_co_stride;
    let wb1 = min(co0 + 1u, last_co) * w_co_stride;
    let wb2 = min(co0 + 2u, last_co) * w_co_stride;
    let wb3 = min(co0 + 3u, last_co) * w_co_stride;
    let hw = p.h * p.w;
    let iy0 = i32(oy * p.stride) - i32(p.pad);
    let ix0 = i32(ox * p.stride) - i32(p.pad);
    let hmax = i32(p.h) - 1;
    let wmax = i32(p.w) - 1;
    let use_norm = (p.flags & 2u) != 0u;
    var acc = vec4<f32>(0.0);
    for (var ci = 0u; ci < p.cin; ci++) {
        var sc = 1.0;
        var sh = 0.0;
        if use_norm {
            sc = norm[2u * ci];
            sh = norm[2u * ci + 1u];
        }
        let base = p.in_base + ci * hw;
        let wci = ci * kk;
        for (var ky = 0u; ky < K; ky++) {
            let iy = u32(clamp(iy0 + i32(ky), 0, hmax));
            let row = base + iy * p.w;
            for (var kx = 0u; kx < K; kx++) {
                let ix = u32(clamp(ix0 + i32(kx), 0, wmax));
                let v = f32(src[row + ix]) * sc + sh;
                let t = wci + ky * K + kx;
                let wv = vec4<f32>(f32(wt[wb0 + t]), f32(wt[wb1 + t]), f32(wt[wb2 + t]), f32(wt[wb3 + t]));
                acc = fma(vec4<f32>(v), wv, acc);
            }
        }
    }
    let plane = p.ho * p.wo;
    let pix = oy * p.wo + ox;
    for (var j = 0u; j < CO_BLOCK; j++) {
        let co = co0 + j;
        if co < p.cout {
            var v = acc[j];
            if (p.flags & 1u) != 0u {
                v += f32(bias[co]);
            }
            dst[p.out_base + co * plane + pix] = st(activate(v, p.act, p.slope));
        }
    }
}
