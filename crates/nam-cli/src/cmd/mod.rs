//! One module per subcommand: each has an `Args` (clap derive) and a `run(&Args)`.

pub mod bench;
#[cfg(feature = "gpu")]
mod bench_gpu;
pub mod estimate;
pub mod info;
pub mod relight;
pub mod render_ggx;
pub mod report;
mod timing;
pub mod view;
