// HA-Conv gating with the folded BatchNorm after it and the block's tail, fused:
//   y = (sigmoid(a) * leaky(b, slope) + c) * affine[2ch] + affine[2ch + 1]
//   mode 1: relu(y);  mode 2: relu(y + res)   (BasicBlock residual)
// a, b are the pre-activation gate/feature convolutions, c the inception concat.
// All tensors are [channels, hw]; a, b, c start at element 0 of their buffers.
// Dispatch: 256-wide workgroups over channels * hw, split over x and y.
alias st = f32;

struct GateParams {
    channels: u32,
    hw: u32,
    mode: u32,
    res_base: u32,
    out_base: u32,
    slope: f32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: GateParams;
@group(0) @binding(1) var<storage, read> a: array<st>;
@group(0) @binding(2) var<storage, read> b: array<st>;
@group(0) @binding(3) var<storage, read> c: array<st>;
@group(0) @binding(4) var<storage, read> affine: array<st>;
@group(0) @binding(5) var<storage, read> res: array<st>;
@group(0) @binding(6) var<storage, read_write> dst: array<st>;

@compute @workgroup_size(256, 1, 1)
fn ha_gate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if i >= p.channels * p.hw {
        return;
    }
    let ch = i / p.hw;
    let gate = 1.0 / (1.0 + exp(-f32(a[i])));
    let fb = f32(b[i]);
    let feat = select(fb * p.slope, fb, fb >= 0.0);
    var y = fma(gate, feat, f32(c[i]));
    y = fma(y, f32(affine[2u * ch]), f32(affine[2u * ch + 1u]));
    if p.mode == 2u {
        y += f32(res[p.res_base + i]);
    }
    dst[p.out_base + i] = st(max(y, 0.0));
}
