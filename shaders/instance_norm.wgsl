// InstanceNorm (non-affine, biased variance) for one image, NCHW.
//
// `instance_norm_stats`: one workgroup per channel reduces over H*W in two passes (mean, then
// the centred sum of squares, which avoids the cancellation of E[x^2] - E[x]^2) and writes
// norm[2c] = 1 / sqrt(var + eps), norm[2c + 1] = -mean / sqrt(var + eps), so that the
// normalised value is x * norm[2c] + norm[2c + 1] (applied by conv2d as it reads its input).
// Dispatch: (channels, 1, 1).
alias st = f32;

struct NormParams {
    channels: u32,
    hw: u32,
    in_base: u32,
    eps: f32,
}

@group(0) @binding(0) var<uniform> p: NormParams;
@group(0) @binding(1) var<storage, read> src: array<st>;
@group(0) @binding(2) var<storage, read_write> norm: array<f32>;

const WG: u32 = 256u;
var<workgroup> partial: array<f32, WG>;

fn workgroup_sum(lid: u32, v: f32) -> f32 {
    partial[lid] = v;
    workgroupBarrier();
    for (var s = WG / 2u; s > 0u; s >>= 1u) {
        if lid < s {
            partial[lid] += partial[lid + s];
        }
        workgroupBarrier();
    }
    let total = partial[0];
    workgroupBarrier();
    return total;
}

@compute @workgroup_size(256, 1, 1)
fn instance_norm_stats(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let c = wid.x;
    let base = p.in_base + c * p.hw;
    var s = 0.0;
    for (var i = lid; i < p.hw; i += WG) {
        s += f32(src[base + i]);
    }
    let mean = workgroup_sum(lid, s) / f32(p.hw);
    var q = 0.0;
    for (var i = lid; i < p.hw; i += WG) {
        let d = f32(src[base + i]) - mean;
        q = fma(d, d, q);
    }
    let variance = workgroup_sum(lid, q) / f32(p.hw);
    if lid == 0u && c < p.channels {
        let r = inverseSqrt(variance + p.eps);
        norm[2u * c] = r;
        norm[2u * c + 1u] = -mean * r;
    }
}
