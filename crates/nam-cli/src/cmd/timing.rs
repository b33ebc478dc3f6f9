//! Interleaved timing of benchmark cases, shared by `bench` (CPU rows) and `bench_gpu`
//! (GPU rows): each case is a labelled closure, each result a [`Row`].

use anyhow::Result;
use std::time::Instant;

/// One measured row of the table.
pub struct Row {
    /// The case's label.
    pub name: String,
    /// Pixels or queries computed (0: not a per-pixel path).
    pub items: usize,
    /// Best run, in milliseconds.
    pub ms: f64,
    /// Floating-point operations of one run (0: not counted).
    pub flops: f64,
}

/// A path to time: its row label, items per run, flops per run and the work.
pub type Case<'a> = (String, usize, f64, Box<dyn FnMut() -> Result<()> + 'a>);

/// Times every case round-robin: one warm-up round, then `repeat` rounds of
/// one run per case; the best run of each is kept. Interleaving makes the
/// ratios fair on a shared machine, where load changes between seconds.
pub fn measure(cases: Vec<Case<'_>>, repeat: usize) -> Result<Vec<Row>> {
    let mut best = vec![f64::INFINITY; cases.len()];
    let mut cases = cases;
    for round in 0..=repeat {
        for (b, (_, _, _, f)) in best.iter_mut().zip(cases.iter_mut()) {
            let t = Instant::now();
            f()?;
            if round > 0 {
                *b = b.min(t.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    Ok(cases
        .into_iter()
        .zip(best)
        .map(|((name, items, flops, _), ms)| Row {
            name,
            items,
            ms,
            flops,
        })
        .collect())
}
