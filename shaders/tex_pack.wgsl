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
    // 1: 4-pixel vector loads (w and in_base multiples of 4).
    vec4_ok: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: PackParams;
@group(0) @binding(1) var<storage, read> src: array<vec4<st>>;
@group(0) @binding(2) var<storage, read> norm: array<f32>;
@group(0) @binding(3) var dst: texture_storage_2d<rgba32float, write>;

// Channel `c` at pixels x0 .. x0 + 3 of row `y` (0 past the channels), normalised when asked.
fn channel(c: u32, y: u32, x0: u32) -> vec4<f32> {
    if c >= p.channels {
        return vec4<f32>(0.0);
    }
    let e = p.in_base + c * p.h * p.w + y * p.w + x0;
    var v: vec4<f32>;
    if p.vec4_ok == 1u {
        v = vec4<f32>(src[e / 4u]);
    } else {
        // Pixels past the row repeat its last one (their texels are not stored).
        let last = e + (p.w - 1u - x0);
        let e1 = min(e + 1u, last);
        let e2 = min(e + 2u, last);
        let e3 = min(e + 3u, last);
        v = vec4<f32>(f32(src[e / 4u][e % 4u]), f32(src[e1 / 4u][e1 % 4u]), f32(src[e2 / 4u][e2 % 4u]), f32(src[e3 / 4u][e3 % 4u]));
    }
    if p.use_norm == 1u {
        v = v * norm[2u * c] + norm[2u * c + 1u];
    }
    return v;
}

@compute @workgroup_size(8, 8, 1)
fn pack_tex(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x0 = 4u * gid.x;
    let r = gid.y;
    let blocks = (p.channels + 3u) / 4u;
    if x0 >= p.w || r >= p.h * blocks {
        return;
    }
    let l = r / p.h;
    let y = r % p.h;
    // c_j: channel 4 l + j at the 4 pixels; texel i gathers component i of each.
    let c0 = vec4<st>(channel(4u * l, y, x0));
    let c1 = vec4<st>(channel(4u * l + 1u, y, x0));
    let c2 = vec4<st>(channel(4u * l + 2u, y, x0));
    let c3 = vec4<st>(channel(4u * l + 3u, y, x0));
    textureStore(dst, vec2<u32>(x0, r), vec4<f32>(vec4<st>(c0.x, c1.x, c2.x, c3.x)));
    if x0 + 1u < p.w {
        textureStore(dst, vec2<u32>(x0 + 1u, r), vec4<f32>(vec4<st>(c0.y, c1.y, c2.y, c3.y)));
    }
    if x0 + 2u < p.w {
        textureStore(dst, vec2<u32>(x0 + 2u, r), vec4<f32>(vec4<st>(c0.z, c1.z, c2.z, c3.z)));
    }
    if x0 + 3u < p.w {
        textureStore(dst, vec2<u32>(x0 + 3u, r), vec4<f32>(vec4<st>(c0.w, c1.w, c2.w, c3.w)));
    }
}
