//! One module per subcommand: each has an `Args` (clap derive) and a `run(&Args)`.

pub mod relight;
pub mod render_ggx;
