//! The U-Net's heap use: measured with a counting allocator against [`UNet::peak_bytes`], the
//! forecast `nam-cli estimate` prints before large estimates.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use nam_model::UNet;
use nam_weights::{ModelConfig, Weights};

/// Counts live heap bytes and their high-water mark.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator and only adds bookkeeping.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Ordering::SeqCst) + layout.size();
            PEAK.fetch_max(now, Ordering::SeqCst);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::SeqCst);
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// One test at a time: the counters are process-wide, so every test holds this throughout.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

/// Heap bytes the estimate allocates beyond what was live before it, at its peak, with the
/// returned param map included.
fn measured_peak(unet: &UNet, side: usize) -> usize {
    let input: Vec<f32> = (0..4 * side * side)
        .map(|i| ((i * 37 % 101) as f32) / 101.0)
        .collect();
    // Warm up: the first run allocates the thread pool and per-thread GEMM buffers once.
    unet.estimate(&input, side, side).unwrap();
    let before = LIVE.load(Ordering::SeqCst);
    PEAK.store(before, Ordering::SeqCst);
    let map = unet.estimate(&input, side, side).unwrap();
    let peak = PEAK.load(Ordering::SeqCst) - before;
    drop(map);
    peak
}

/// How far above the measured peak the forecast may lie (it leaves out nothing it should count
/// when below 1, and is useful as a forecast when near 1).
const FORECAST_ABOVE_MAX: f64 = 1.3;

#[test]
fn peak_bytes_forecasts_the_measured_peak_for_every_width() {
    let _serial = serial();
    for width in [4, 8, 16] {
        for input_skip in [false, true] {
            let cfg = ModelConfig {
                input_skip,
                ..ModelConfig::standard(width)
            };
            let unet = UNet::new(&Weights::random(cfg, 3).unwrap()).unwrap();
            // 250 is padded to 256 internally; 256 is not. Both are one band of each HA-Conv.
            for side in [250, 256] {
                let measured = measured_peak(&unet, side);
                let forecast = unet.peak_bytes(side, side);
                let ratio = forecast as f64 / measured as f64;
                println!(
                    "C={width} skip={input_skip} {side}²: measured {measured} B ({:.0} B/px), \
                     forecast {forecast} B ({ratio:.2}×)",
                    measured as f64 / (side * side) as f64
                );
                assert!(
                    (1.0..=FORECAST_ABOVE_MAX).contains(&ratio),
                    "C={width} skip={input_skip} {side}²: forecast {forecast} vs measured {measured}"
                );
            }
        }
    }
}

#[test]
fn a_large_estimate_holds_little_beyond_its_param_map() {
    let _serial = serial();
    // 512² runs each full-resolution HA-Conv in four bands. The param map alone is 64 floats
    // per pixel; the whole estimate peaks at 1.48× that (1024²: 1.28×; before the bands
    // 1.96×, and 3.3× when saving copied the map).
    let unet = UNet::new(&Weights::random(ModelConfig::standard(8), 3).unwrap()).unwrap();
    let side = 512;
    let map_bytes = side * side * 64 * 4;
    let measured = measured_peak(&unet, side);
    let forecast = unet.peak_bytes(side, side);
    println!(
        "C=8 512²: peak {:.2}× the param map, forecast {:.2}× the peak",
        measured as f64 / map_bytes as f64,
        forecast as f64 / measured as f64
    );
    assert!(measured < map_bytes * 8 / 5, "{measured} B");
    assert!((1.0..=FORECAST_ABOVE_MAX).contains(&(forecast as f64 / measured as f64)));
}
