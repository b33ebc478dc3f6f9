//! Progress bars for work expected to take more than a second (indicatif, on stderr; hidden
//! automatically when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

/// Work below this expected duration gets no bar (seconds).
const MIN_SECONDS_FOR_BAR: f64 = 1.0;

/// A bar with `total` steps labelled `label`, or a hidden one when the caller expects the
/// work to finish within [`MIN_SECONDS_FOR_BAR`].
pub fn bar(total: u64, label: &str, expected_seconds: f64) -> ProgressBar {
    if expected_seconds < MIN_SECONDS_FOR_BAR {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total);
    let style = ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} ({eta})")
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    pb.set_style(style);
    pb.set_message(label.to_string());
    pb
}
