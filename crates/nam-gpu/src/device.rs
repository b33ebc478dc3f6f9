//! A convenience device for tools, tests and benchmarks. Engines create their own device and
//! pass it to [`crate::GpuNetwork::new`]; this helper is never used inside the library.

/// An adapter's device and queue plus a description of the adapter.
#[derive(Debug)]
pub struct DeviceHandles {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name, backend and type.
    pub info: wgpu::AdapterInfo,
}

/// Requests the default adapter (lavapipe on a machine with only Mesa's CPU Vulkan) and a
/// device with WebGPU's default limits, plus `SHADER_F16` when `want_f16` and the adapter
/// has it, and `SUBGROUP` when the adapter has it (the CPU matmul variant uses it). Returns `None` and prints the reason to stderr when no adapter or device exists.
pub fn request_device(want_f16: bool) -> Option<DeviceHandles> {
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle());
    let adapter =
        match pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
        {
            Ok(a) => a,
            Err(e) => {
                eprintln!(
                    "nam-gpu: no GPU adapter ({e}); install mesa-vulkan-drivers for lavapipe"
                );
                return None;
            }
        };
    let mut features = adapter.features() & wgpu::Features::SUBGROUP;
    if want_f16 && adapter.features().contains(wgpu::Features::SHADER_F16) {
        features |= wgpu::Features::SHADER_F16;
    }
    let desc = wgpu::DeviceDescriptor {
        label: Some("nam-gpu"),
        required_features: features,
        required_limits: wgpu::Limits::default(),
        ..Default::default()
    };
    match pollster::block_on(adapter.request_device(&desc)) {
        Ok((device, queue)) => Some(DeviceHandles {
            device,
            queue,
            info: adapter.get_info(),
        }),
        Err(e) => {
            eprintln!(
                "nam-gpu: adapter {:?} refused a device: {e}",
                adapter.get_info().name
            );
            None
        }
    }
}

/// The one decision of every GPU test that finds no adapter (or no usable device): on a
/// developer's machine it prints `SKIP: {reason}` and returns, so the test can pass; under
/// `CI=true`, where lavapipe is installed, it panics, because a skip there would hide a break.
pub fn skip_without_adapter(reason: &str) {
    skip_or_fail(reason, std::env::var("CI").ok().as_deref());
}

/// [`skip_without_adapter`] with the value of `CI` passed in.
fn skip_or_fail(reason: &str, ci: Option<&str>) {
    if ci == Some("true") {
        panic!(
            "CI=true and the GPU test cannot run: {reason} (CI runs GPU tests on lavapipe: \
             install mesa-vulkan-drivers)"
        );
    }
    eprintln!("SKIP: {reason}");
}

#[cfg(test)]
mod tests {
    use super::skip_or_fail;

    #[test]
    #[should_panic(expected = "CI=true and the GPU test cannot run: no adapter")]
    fn a_missing_adapter_fails_the_test_under_ci_true() {
        skip_or_fail("no adapter", Some("true"));
    }

    #[test]
    fn a_missing_adapter_is_a_skip_elsewhere() {
        skip_or_fail("no adapter", None);
        skip_or_fail("no adapter", Some("false"));
        skip_or_fail("no adapter", Some(""));
    }
}
