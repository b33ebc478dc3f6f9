// Smoke test: data[i] = 2 * data[i] + 1. Dispatch: (ceil(n / 64), 1, 1).
@group(0) @binding(0) var<storage, read_write> data: array<f32>;

@compute @workgroup_size(64, 1, 1)
fn smoke(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x < arrayLength(&data) { data[gid.x] = fma(data[gid.x], 2.0, 1.0); }
}
