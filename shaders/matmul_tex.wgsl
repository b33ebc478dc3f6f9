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
// named vec4 members of `Acc` (8 x 4 columns) so they stay in registers.
// Output: `out_buf == 0`: texture `yt`, texel (y_texel_base + n / 4, m), channels of n >= cols
// written as 0 so the next layer can read whole texels; `out_buf == 1`: buffer `ybuf`,
// element m * y_stride + n. Needs a subgroup size >= 8 (checked by the host).
// Dispatch: (ceil(cols / 16), ceil(rows / 16), 1) workgroups of 8.
// The multiply-add body `mac` and its accumulators `Acc` are `subgroup_mac.wgsl`, appended by
// the host (shared with `conv_tex.wgsl`).
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
    var acc: Acc;
    for (var k = 0u; k < p.inner4; k++) {
        let x0 = textureLoad(xt, vec2<u32>(k, xm0), 0);
        let x1 = textureLoad(xt, vec2<u32>(k, xm1), 0);
        let wl0 = textureLoad(wt, vec2<u32>(k, wn0), 0);
        let wl1 = textureLoad(wt, vec2<u32>(k, wn1), 0);
        mac(&acc, x0, x1, wl0, wl1);
    }
    store4(m0, n0 + 0u, acc.a0_0);
    store4(m0, n0 + 4u, acc.a0_1);
    store4(m0, n0 + 8u, acc.a0_2);
    store4(m0, n0 + 12u, acc.a0_3);
    store4(m1, n0 + 0u, acc.a1_0);
    store4(m1, n0 + 4u, acc.a1_1);
    store4(m1, n0 + 8u, acc.a1_2);
    store4(m1, n0 + 12u, acc.a1_3);
}
