// HA-Conv gating with the folded BatchNorm after it and the block's tail, fused:
//   y = (sigmoid(a) * leaky(b, slope) + c) * affine[2ch] + affine[2ch + 1]
//   mode 1: relu(y);  mode 2: relu(y + res)   (BasicBlock residual)
// a, b are the pre-activation gate/feature convolutions, c the inception concat.
// All tensors are [channels, hw]; a, b, c start at element 0 of their buffers.
// Each invocation handles 4 consecutive elements: with `vec4_ok` (hw and both bases multiples
// of 4, so the 4 share a channel) as one vec4 load per tensor (llvmpipe turns every storage
// load with a per-lane address into a loop over the lanes: 4 elements per trip instead of 1),
// else element by element.
// Dispatch: 256-wide workgroups over ceil(channels * hw / 4), split over x and y.
alias st = f32;

struct GateParams {
    channels: u32,
    hw: u32,
    mode: u32,
    res_base: u32,
    out_base: u32,
    slope: f32,
    vec4_ok: u32,
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: GateParams;
@group(0) @binding(1) var<storage, read> a: array<vec4<st>>;
@group(0) @binding(2) var<storage, read> b: array<vec4<st>>;
@group(0) @binding(3) var<storage, read> c: array<vec4<st>>;
@group(0) @binding(4) var<storage, read> affine: array<st>;
@group(0) @binding(5) var<storage, read> res: array<vec4<st>>;
@group(0) @binding(6) var<storage, read_write> dst: array<vec4<st>>;

fn gate(av: vec4<f32>, bv: vec4<f32>, cv: vec4<f32>, ch: u32) -> vec4<f32> {
    let g = 1.0 / (1.0 + exp(-av));
    let feat = select(bv * p.slope, bv, bv >= vec4<f32>(0.0));
    let y = fma(g, feat, cv);
    return fma(y, vec4<f32>(f32(affine[2u * ch])), vec4<f32>(f32(affine[2u * ch + 1u])));
}

@compute @workgroup_size(256, 1, 1)
fn ha_gate(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let q = gid.x + gid.y * nwg.x * 256u;
    let n = p.channels * p.hw;
    let i0 = 4u * q;
    if i0 >= n {
        return;
    }
    if p.vec4_ok == 1u {
        var y = gate(vec4<f32>(a[q]), vec4<f32>(b[q]), vec4<f32>(c[q]), i0 / p.hw);
        if p.mode == 2u {
            y += vec4<f32>(res[(p.res_base + i0) / 4u]);
        }
        dst[(p.out_base + i0) / 4u] = vec4<st>(max(y, vec4<f32>(0.0)));
        return;
    }
    for (var j = 0u; j < 4u; j++) {
        let i = i0 + j;
        if i < n {
            var y = gate(vec4<f32>(f32(a[i / 4u][i % 4u])), vec4<f32>(f32(b[i / 4u][i % 4u])), vec4<f32>(f32(c[i / 4u][i % 4u])), i / p.hw).x;
            if p.mode == 2u {
                let r = p.res_base + i;
                y += f32(res[r / 4u][r % 4u]);
            }
            let o = p.out_base + i;
            dst[o / 4u][o % 4u] = st(max(y, 0.0));
        }
    }
}
