//! `nam-eval` — the evaluation of nam (DESIGN.md §8): error against run time.
//!
//! - [`metrics`]: log-L1, log-RMSE and SSIM with `train_py/evaluate.py`'s definitions.
//! - [`flip`]: LDR-FLIP, a Rust port of the published pipeline.
//! - [`heldout`]: the held-out procedural set (4-panel PNGs), flash photos, protocol pairs.
//! - [`methods`]: printout and diffuse-fit baselines, the GGX ground truth, and the neural model
//!   per backend (CPU reference, CPU fast, GPU), precision and scene specialisation.
//! - [`runner`]: every method on every material and pair, timed.
//! - [`report`]: the Markdown tables and the PNG scatter plot ([`plot`]).
//!
//! `nam-cli report` is the command line; `benches/report.rs` times one configuration.

#![forbid(unsafe_code)]

mod error;
pub mod flip;
pub mod heldout;
pub mod methods;
pub mod metrics;
mod pair;
pub mod plot;
pub mod report;
pub mod runner;

pub use error::{EvalError, Result};
pub use heldout::Material;
pub use methods::{Backend, MethodSpec, NeuralConfig, Precision, Specialisation};
pub use metrics::Scores;
pub use report::{ReportMeta, ReportOptions};
pub use runner::{Entry, EntryResult, PairCounts, RunResults};

/// Threads of rayon's current pool: what the CPU rows run on.
pub fn cpu_threads() -> usize {
    rayon::current_num_threads()
}
