// Matrix multiply for CPU adapters (llvmpipe), with the operands in rgba textures:
//   Y[m, n] = act(sum_k X[m, k] * W[n, k])     (m < rows, n < cols, k < 4 * inner4)
// X is a texture with texel (k / 4, m) holding channels 4 (k / 4) .. + 3 of row m; W the same
// with rows n (PyTorch Linear [cols, inner] layout, zero-padded to whole texels).
// Why textures and subgroups: llvmpipe runs 8 invocations in the lanes of one AVX2 register.
// Its storage-buffer and workgroup-memory loads with a non-uniform address become a per-lane
// loop with a bounds-check branch per element, which costs far more than the FMAs; a texel
// fetch is a branch-free 8-lane gather of 16-byte texels. Each workgroup (8 invocations, one
// subgroup) computes a 16 x 16 block of Y: invocation i owns rows i and i + 8 (X fetched per
// lane) and loads W rows n0 + i and n0 + 8 + i; `subgroupBroadcast` then hands every lane each
// W texel as a uniform value, so one fetch feeds 16 FMAs per row. The 32 accumulators are
// named vec4s (8 x 4 columns) so they stay in registers.
// Output: `out_buf == 0`: texture `yt`, texel (y_texel_base + n / 4, m), channels of n >= cols
// written as 0 so the next layer can read whole texels; `out_buf == 1`: buffer `ybuf`,
// element m * y_stride + n. Needs a subgroup size >= 8 (checked by the host).
// Dispatch: (ceil(cols / 16), ceil(rows / 16), 1) workgroups of 8.
// This file is generated (R = 2 rows, C = 16 columns per lane); edit with care.
alias st = f32;

struct TexMatmulParams {
    rows: u32,
    cols: u32,
    inner4: u32,
    y_texel_base: u32,
    out_buf: u32,
    y_stride: u32,
    // 0 none, 2 leaky relu(slope).
    act: u32,
    slope: f32,
}

@group(0) @binding(0) var<uniform> p: TexMatmulParams;
@group(0) @binding(1) var xt: texture_2d<f32>;
@group(0) @binding(2) var wt: texture_2d<f32>;
@group(0) @binding(3) var yt: texture_storage_2d<rgba32float, write>;
@group(0) @binding(4) var<storage, read_write> ybuf: array<st>;

// Activation, with channels n0 .. n0 + 3 at or past `cols` zeroed, rounded to the storage
// type here (round to nearest) so that texture stores, whose f32 -> f16 conversion may
// truncate on some drivers, see exactly representable values.
fn epilogue(v: vec4<f32>, n0: u32) -> vec4<f32> {
    var a = v;
    if p.act == 2u {
        a = select(v * p.slope, v, v >= vec4<f32>(0.0));
    }
    let n = vec4<u32>(n0, n0 + 1u, n0 + 2u, n0 + 3u);
    return vec4<f32>(vec4<st>(select(vec4<f32>(0.0), a, n < vec4<u32>(p.cols))));
}

fn store4(m: u32, n0: u32, v: vec4<f32>) {
    if m >= p.rows || n0 >= p.cols {
        return;
    }
    let a = epilogue(v, n0);
    if p.out_buf == 0u {
        textureStore(yt, vec2<u32>(p.y_texel_base + n0 / 4u, m), a);
        return;
    }
    let row = m * p.y_stride + n0;
    ybuf[row] = st(a.x);
    if n0 + 1u < p.cols { ybuf[row + 1u] = st(a.y); }
    if n0 + 2u < p.cols { ybuf[row + 2u] = st(a.z); }
    if n0 + 3u < p.cols { ybuf[row + 3u] = st(a.w); }
}

@compute @workgroup_size(8, 1, 1)
fn matmul_tex(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(subgroup_invocation_id) sid: u32,
) {
    let n0 = wid.x * 16u;
    let m0 = wid.y * 16u + lid.x + 0u;
    let xm0 = min(m0, p.rows - 1u);
    let m1 = wid.y * 16u + lid.x + 8u;
    let xm1 = min(m1, p.rows - 1u);
    // Lane `sid` fetches W rows n0 + sid and n0 + 8 + sid; broadcast from lane j is row n0 + j.
    let wn0 = min(n0 + 0u + sid, p.cols - 1u);
    let wn1 = min(n0 + 8u + sid, p.cols - 1u);
    var a0_0 = vec4<f32>(0.0);
    var a0_1 = vec4<f32>(0.0);
    var a0_2 = vec4<f32>(0.0);
    var a0_3 = vec4<f32>(0.0);
    var a1_0 = vec4<f32>(0.0);
    var a1_1 = vec4<f32>(0.0);
    var a1_2 = vec4<f32>(0.0);
    var a1_3 = vec4<f32>(0.0);
    for (var k = 0u; k < p.inner4; k++) {
        let x0 = textureLoad(xt, vec2<u32>(k, xm0), 0);
        let x1 = textureLoad(xt, vec2<u32>(k, xm1), 0);
        let wl0 = textureLoad(wt, vec2<u32>(k, wn0), 0);
        let wl1 = textureLoad(wt, vec2<u32>(k, wn1), 0);
        let w0 = subgroupBroadcast(wl0, 0u);
        let w1 = subgroupBroadcast(wl0, 1u);
        let w2 = subgroupBroadcast(wl0, 2u);
        let w3 = subgroupBroadcast(wl0, 3u);
        let w4 = subgroupBroadcast(wl0, 4u);
        let w5 = subgroupBroadcast(wl0, 5u);
        let w6 = subgroupBroadcast(wl0, 6u);
        let w7 = subgroupBroadcast(wl0, 7u);
        let w8 = subgroupBroadcast(wl1, 0u);
        let w9 = subgroupBroadcast(wl1, 1u);
        let w10 = subgroupBroadcast(wl1, 2u);
        let w11 = subgroupBroadcast(wl1, 3u);
        let w12 = subgroupBroadcast(wl1, 4u);
        let w13 = subgroupBroadcast(wl1, 5u);
        let w14 = subgroupBroadcast(wl1, 6u);
        let w15 = subgroupBroadcast(wl1, 7u);
        a0_0 = fma(vec4<f32>(x0.x), vec4<f32>(w0.x, w1.x, w2.x, w3.x), a0_0);
        a0_0 = fma(vec4<f32>(x0.y), vec4<f32>(w0.y, w1.y, w2.y, w3.y), a0_0);
        a0_0 = fma(vec4<f32>(x0.z), vec4<f32>(w0.z, w1.z, w2.z, w3.z), a0_0);
        a0_0 = fma(vec4<f32>(x0.w), vec4<f32>(w0.w, w1.w, w2.w, w3.w), a0_0);
        a0_1 = fma(vec4<f32>(x0.x), vec4<f32>(w4.x, w5.x, w6.x, w7.x), a0_1);
        a0_1 = fma(vec4<f32>(x0.y), vec4<f32>(w4.y, w5.y, w6.y, w7.y), a0_1);
        a0_1 = fma(vec4<f32>(x0.z), vec4<f32>(w4.z, w5.z, w6.z, w7.z), a0_1);
        a0_1 = fma(vec4<f32>(x0.w), vec4<f32>(w4.w, w5.w, w6.w, w7.w), a0_1);
        a0_2 = fma(vec4<f32>(x0.x), vec4<f32>(w8.x, w9.x, w10.x, w11.x), a0_2);
        a0_2 = fma(vec4<f32>(x0.y), vec4<f32>(w8.y, w9.y, w10.y, w11.y), a0_2);
        a0_2 = fma(vec4<f32>(x0.z), vec4<f32>(w8.z, w9.z, w10.z, w11.z), a0_2);
        a0_2 = fma(vec4<f32>(x0.w), vec4<f32>(w8.w, w9.w, w10.w, w11.w), a0_2);
        a0_3 = fma(vec4<f32>(x0.x), vec4<f32>(w12.x, w13.x, w14.x, w15.x), a0_3);
        a0_3 = fma(vec4<f32>(x0.y), vec4<f32>(w12.y, w13.y, w14.y, w15.y), a0_3);
        a0_3 = fma(vec4<f32>(x0.z), vec4<f32>(w12.z, w13.z, w14.z, w15.z), a0_3);
        a0_3 = fma(vec4<f32>(x0.w), vec4<f32>(w12.w, w13.w, w14.w, w15.w), a0_3);
        a1_0 = fma(vec4<f32>(x1.x), vec4<f32>(w0.x, w1.x, w2.x, w3.x), a1_0);
        a1_0 = fma(vec4<f32>(x1.y), vec4<f32>(w0.y, w1.y, w2.y, w3.y), a1_0);
        a1_0 = fma(vec4<f32>(x1.z), vec4<f32>(w0.z, w1.z, w2.z, w3.z), a1_0);
        a1_0 = fma(vec4<f32>(x1.w), vec4<f32>(w0.w, w1.w, w2.w, w3.w), a1_0);
        a1_1 = fma(vec4<f32>(x1.x), vec4<f32>(w4.x, w5.x, w6.x, w7.x), a1_1);
        a1_1 = fma(vec4<f32>(x1.y), vec4<f32>(w4.y, w5.y, w6.y, w7.y), a1_1);
        a1_1 = fma(vec4<f32>(x1.z), vec4<f32>(w4.z, w5.z, w6.z, w7.z), a1_1);
        a1_1 = fma(vec4<f32>(x1.w), vec4<f32>(w4.w, w5.w, w6.w, w7.w), a1_1);
        a1_2 = fma(vec4<f32>(x1.x), vec4<f32>(w8.x, w9.x, w10.x, w11.x), a1_2);
        a1_2 = fma(vec4<f32>(x1.y), vec4<f32>(w8.y, w9.y, w10.y, w11.y), a1_2);
        a1_2 = fma(vec4<f32>(x1.z), vec4<f32>(w8.z, w9.z, w10.z, w11.z), a1_2);
        a1_2 = fma(vec4<f32>(x1.w), vec4<f32>(w8.w, w9.w, w10.w, w11.w), a1_2);
        a1_3 = fma(vec4<f32>(x1.x), vec4<f32>(w12.x, w13.x, w14.x, w15.x), a1_3);
        a1_3 = fma(vec4<f32>(x1.y), vec4<f32>(w12.y, w13.y, w14.y, w15.y), a1_3);
        a1_3 = fma(vec4<f32>(x1.z), vec4<f32>(w12.z, w13.z, w14.z, w15.z), a1_3);
        a1_3 = fma(vec4<f32>(x1.w), vec4<f32>(w12.w, w13.w, w14.w, w15.w), a1_3);
    }
    store4(m0, n0 + 0u, a0_0);
    store4(m0, n0 + 4u, a0_1);
    store4(m0, n0 + 8u, a0_2);
    store4(m0, n0 + 12u, a0_3);
    store4(m1, n0 + 0u, a1_0);
    store4(m1, n0 + 4u, a1_1);
    store4(m1, n0 + 8u, a1_2);
    store4(m1, n0 + 12u, a1_3);
}
