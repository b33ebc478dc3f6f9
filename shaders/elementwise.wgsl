// Elementwise kernels over n elements of NCHW tensors (views at element offsets).
//   add_relu:    dst = relu(src + src2)                          (residual add)
//   atan_act:    dst = atan(src)                                 (U-Net bottleneck)
// Dispatch: 256-wide workgroups over n, split over x and y (index = x + y * groups_x * 256).
alias st = f32;

struct EwParams {
    n: u32,
    in_base: u32,
    in2_base: u32,
    out_base: u32,
}

@group(0) @binding(0) var<uniform> p: EwParams;
@group(0) @binding(1) var<storage, read> src: array<st>;
@group(0) @binding(2) var<storage, read> src2: array<st>;
@group(0) @binding(3) var<storage, read_write> dst: array<st>;

fn index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 256u;
}

@compute @workgroup_size(256, 1, 1)
fn add_relu(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if i >= p.n {
        return;
    }
    dst[p.out_base + i] = st(max(f32(src[p.in_base + i]) + f32(src2[p.in2_base + i]), 0.0));
}

@compute @workgroup_size(256, 1, 1)
fn atan_act(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if i >= p.n {
        return;
    }
    dst[p.out_base + i] = st(atan(f32(src[p.in_base + i])));
}
