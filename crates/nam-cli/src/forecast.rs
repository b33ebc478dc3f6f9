//! The note printed before a large estimate: its forecast time and memory
//! ([`nam::NeuralModel::estimate_cost`]), and a warning when the memory is not available.

use anyhow::Result;
use nam::NeuralModel;

/// Photos with fewer pixels than this are estimated without a forecast (a 512² estimate takes
/// about a second on 2 cores, less than the note would be worth).
const FORECAST_FROM_PIXELS: usize = 512 * 512;

/// A forecast above either bound is printed.
const NOTE_ABOVE_SECONDS: f64 = 3.0;
const NOTE_ABOVE_BYTES: u64 = 1 << 30;

/// Prints the forecast for estimating a `side × side` photo when it is long or large.
pub fn note_estimate_cost(model: &NeuralModel, side: usize) -> Result<()> {
    if side * side < FORECAST_FROM_PIXELS {
        return Ok(());
    }
    let cost = model.estimate_cost(side)?;
    let long = cost.seconds.is_some_and(|s| s > NOTE_ABOVE_SECONDS);
    if !long && cost.peak_bytes <= NOTE_ABOVE_BYTES {
        return Ok(());
    }
    let time = cost
        .seconds
        .map(|s| format!("about {s:.0} s and "))
        .unwrap_or_default();
    eprintln!(
        "note: estimating {side}×{side} takes {time}{} of memory (forecast: a {}² estimate timed \
         here, scaled; --resize N makes it smaller and faster)",
        gib(cost.peak_bytes),
        nam::COST_PROBE_SIDE
    );
    if let Some(free) = available_bytes()
        && cost.peak_bytes > free
    {
        eprintln!(
            "warning: only {} of memory is available now; the estimate may swap or be stopped",
            gib(free)
        );
    }
    Ok(())
}

fn gib(bytes: u64) -> String {
    format!("{:.1} GB", bytes as f64 / 1e9)
}

/// `MemAvailable` of /proc/meminfo (Linux), in bytes; `None` elsewhere.
fn available_bytes() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}
