// The register-blocked multiply-add shared by `matmul_tex.wgsl` and `conv_tex.wgsl` (the host
// appends this file to both): each lane of an 8-lane subgroup holds 2 rows (pixels) x 16 columns
// (output channels) of accumulators; per 4-wide inner step it brings its 2 input texels and
// fetches 2 weight texels, which `subgroupBroadcast` hands to every lane (16 broadcasts, 32
// vec4 FMAs). Generated (R = 2, C = 16); edit with care.

// Accumulators of one lane: row r, columns n0 + 4 j .. + 3. Named members (no
// dynamically indexed array) so they stay in registers.
struct Acc {
    a0_0: vec4<f32>,
    a0_1: vec4<f32>,
    a0_2: vec4<f32>,
    a0_3: vec4<f32>,
    a1_0: vec4<f32>,
    a1_1: vec4<f32>,
    a1_2: vec4<f32>,
    a1_3: vec4<f32>,
}

// acc += x_r (4 inner values of row r) times the 16 broadcast weight texels; `wl0` holds
// column n0 + lane, `wl1` column n0 + 8 + lane.
fn mac(acc: ptr<function, Acc>, x0: vec4<f32>, x1: vec4<f32>, wl0: vec4<f32>, wl1: vec4<f32>) {
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
    (*acc).a0_0 = fma(vec4<f32>(x0.x), vec4<f32>(w0.x, w1.x, w2.x, w3.x), (*acc).a0_0);
    (*acc).a0_0 = fma(vec4<f32>(x0.y), vec4<f32>(w0.y, w1.y, w2.y, w3.y), (*acc).a0_0);
    (*acc).a0_0 = fma(vec4<f32>(x0.z), vec4<f32>(w0.z, w1.z, w2.z, w3.z), (*acc).a0_0);
    (*acc).a0_0 = fma(vec4<f32>(x0.w), vec4<f32>(w0.w, w1.w, w2.w, w3.w), (*acc).a0_0);
    (*acc).a0_1 = fma(vec4<f32>(x0.x), vec4<f32>(w4.x, w5.x, w6.x, w7.x), (*acc).a0_1);
    (*acc).a0_1 = fma(vec4<f32>(x0.y), vec4<f32>(w4.y, w5.y, w6.y, w7.y), (*acc).a0_1);
    (*acc).a0_1 = fma(vec4<f32>(x0.z), vec4<f32>(w4.z, w5.z, w6.z, w7.z), (*acc).a0_1);
    (*acc).a0_1 = fma(vec4<f32>(x0.w), vec4<f32>(w4.w, w5.w, w6.w, w7.w), (*acc).a0_1);
    (*acc).a0_2 = fma(vec4<f32>(x0.x), vec4<f32>(w8.x, w9.x, w10.x, w11.x), (*acc).a0_2);
    (*acc).a0_2 = fma(vec4<f32>(x0.y), vec4<f32>(w8.y, w9.y, w10.y, w11.y), (*acc).a0_2);
    (*acc).a0_2 = fma(vec4<f32>(x0.z), vec4<f32>(w8.z, w9.z, w10.z, w11.z), (*acc).a0_2);
    (*acc).a0_2 = fma(vec4<f32>(x0.w), vec4<f32>(w8.w, w9.w, w10.w, w11.w), (*acc).a0_2);
    (*acc).a0_3 = fma(vec4<f32>(x0.x), vec4<f32>(w12.x, w13.x, w14.x, w15.x), (*acc).a0_3);
    (*acc).a0_3 = fma(vec4<f32>(x0.y), vec4<f32>(w12.y, w13.y, w14.y, w15.y), (*acc).a0_3);
    (*acc).a0_3 = fma(vec4<f32>(x0.z), vec4<f32>(w12.z, w13.z, w14.z, w15.z), (*acc).a0_3);
    (*acc).a0_3 = fma(vec4<f32>(x0.w), vec4<f32>(w12.w, w13.w, w14.w, w15.w), (*acc).a0_3);
    (*acc).a1_0 = fma(vec4<f32>(x1.x), vec4<f32>(w0.x, w1.x, w2.x, w3.x), (*acc).a1_0);
    (*acc).a1_0 = fma(vec4<f32>(x1.y), vec4<f32>(w0.y, w1.y, w2.y, w3.y), (*acc).a1_0);
    (*acc).a1_0 = fma(vec4<f32>(x1.z), vec4<f32>(w0.z, w1.z, w2.z, w3.z), (*acc).a1_0);
    (*acc).a1_0 = fma(vec4<f32>(x1.w), vec4<f32>(w0.w, w1.w, w2.w, w3.w), (*acc).a1_0);
    (*acc).a1_1 = fma(vec4<f32>(x1.x), vec4<f32>(w4.x, w5.x, w6.x, w7.x), (*acc).a1_1);
    (*acc).a1_1 = fma(vec4<f32>(x1.y), vec4<f32>(w4.y, w5.y, w6.y, w7.y), (*acc).a1_1);
    (*acc).a1_1 = fma(vec4<f32>(x1.z), vec4<f32>(w4.z, w5.z, w6.z, w7.z), (*acc).a1_1);
    (*acc).a1_1 = fma(vec4<f32>(x1.w), vec4<f32>(w4.w, w5.w, w6.w, w7.w), (*acc).a1_1);
    (*acc).a1_2 = fma(vec4<f32>(x1.x), vec4<f32>(w8.x, w9.x, w10.x, w11.x), (*acc).a1_2);
    (*acc).a1_2 = fma(vec4<f32>(x1.y), vec4<f32>(w8.y, w9.y, w10.y, w11.y), (*acc).a1_2);
    (*acc).a1_2 = fma(vec4<f32>(x1.z), vec4<f32>(w8.z, w9.z, w10.z, w11.z), (*acc).a1_2);
    (*acc).a1_2 = fma(vec4<f32>(x1.w), vec4<f32>(w8.w, w9.w, w10.w, w11.w), (*acc).a1_2);
    (*acc).a1_3 = fma(vec4<f32>(x1.x), vec4<f32>(w12.x, w13.x, w14.x, w15.x), (*acc).a1_3);
    (*acc).a1_3 = fma(vec4<f32>(x1.y), vec4<f32>(w12.y, w13.y, w14.y, w15.y), (*acc).a1_3);
    (*acc).a1_3 = fma(vec4<f32>(x1.z), vec4<f32>(w12.z, w13.z, w14.z, w15.z), (*acc).a1_3);
    (*acc).a1_3 = fma(vec4<f32>(x1.w), vec4<f32>(w12.w, w13.w, w14.w, w15.w), (*acc).a1_3);
}
