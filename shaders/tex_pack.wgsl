// Packs an NCHW activation (batch 1) from a storage buffer into the channel-block texture that
// `conv_tex.wgsl` reads: texel (x, l * h + y) holds channels 4 l .. 4 l + 3 of pixel (x, y)
// (channel blocks stacked vertically, one h-row band each), channels past `channels` are 0.
// Optionally applies the per-channel affine `x * norm[2c] + norm[2c + 1]` on the way (the
// InstanceNorm that HA-Conv's feature convolution reads). Values are rounded to the storage type
// here, as `matmul_tex.wgsl` does, so that f16 texture stores see representable values.
// Dispatch: (ceil(w / 8), ceil(h * ceil(channels / 4) / 8), 1).
alias st = f32;

struct PackParams {
    channels: u32,
    h: u32,
    w: u32,
    // Element offset of the tensor inside `src`.
    in_base: u32,
    // 1: apply the norm affine.
    use_norm: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: PackParams;
@group(0) @binding(1) var<storage, read> src: array<st>;
@group(0) @binding(2) var<storage, read> norm: array<f32>;
@group(0) @binding(3) var dst: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(8, 8, 1)
fn pack_tex(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let r = gid.y;
    let blocks = (p.channels + 3u) / 4u;
    if x >= p.w || r >= p.h * blocks {
        return;
    }
    let l = r / p.h;
    let y = r % p.h;
    let hw = p.h * p.w;
    var v = vec4<f32>(0.0);
    for (var j = 0u; j < 4u; j++) {
        let c = 4u * l + j;
        if c < p.channels {
            var e = f32(src[p.in_base + c * hw + y * p.w + x]);
            if p.use_norm == 1u {
                e = e * norm[2u * c] + norm[2u * c + 1u];
            }
            v[j] = e;
        }
    }
    textureStore(dst, vec2<u32>(x, r), vec4<f32>(vec4<st>(v)));
}
