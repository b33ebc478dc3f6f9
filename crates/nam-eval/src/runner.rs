//! The protocol runner: every method on every held-out material and light/view pair, with
//! per-call timings and per-protocol mean scores.

use crate::error::Result;
use crate::flip::FlipImage;
use crate::heldout::{Material, PROTOCOLS};
use crate::methods::{Estimate, GpuDevice, MethodSpec, Prepared};
use crate::metrics::{Scores, score_with};
use nam::geometry::{Light, View};
use nam_ggx::{Protocol, RenderSettings, render};
use rayon::prelude::*;
use std::time::Instant;

/// Light/view pairs per material for each protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PairCounts {
    /// Reflect pairs.
    pub reflect: usize,
    /// Identity pairs (all identical; 1 is enough).
    pub identity: usize,
    /// Hemisphere pairs.
    pub hemisphere: usize,
}

impl PairCounts {
    /// `evaluate.py`'s defaults: Reflect 8, Identity 1, Hemisphere 128.
    pub const PAPER: PairCounts = PairCounts {
        reflect: 8,
        identity: 1,
        hemisphere: 128,
    };

    /// The count of `protocol`.
    pub fn get(&self, protocol: Protocol) -> usize {
        match protocol {
            Protocol::Reflect => self.reflect,
            Protocol::Identity => self.identity,
            Protocol::Hemisphere => self.hemisphere,
        }
    }

    /// Pairs over all protocols.
    pub fn total(&self) -> usize {
        self.reflect + self.identity + self.hemisphere
    }

    /// Field-wise minimum.
    pub fn min(self, o: PairCounts) -> PairCounts {
        PairCounts {
            reflect: self.reflect.min(o.reflect),
            identity: self.identity.min(o.identity),
            hemisphere: self.hemisphere.min(o.hemisphere),
        }
    }
}

/// One row of the report: a method and the part of the set it runs on.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    /// What runs.
    pub spec: MethodSpec,
    /// Row label.
    pub label: String,
    /// Evaluated on the first `materials` materials.
    pub materials: usize,
    /// … and the first `pairs` of each protocol's pairs (slow backends use a prefix).
    pub pairs: PairCounts,
}

/// The measured outcome of one [`Entry`].
#[derive(Debug, Clone, PartialEq)]
pub struct EntryResult {
    /// The entry.
    pub entry: Entry,
    /// U-Net width `C` (0 for non-neural rows).
    pub width: usize,
    /// Mean scores per protocol, in [`PROTOCOLS`] order (over all evaluated images).
    pub scores: [Scores; 3],
    /// Median wall time of one estimate (ms); `None` without an estimate step.
    pub ms_per_estimate: Option<f64>,
    /// Median wall time of one relight divided by the image's megapixels (ms per MP).
    pub ms_per_megapixel: f64,
    /// Median wall time of one relight (ms).
    pub ms_per_relight: f64,
    /// Images evaluated.
    pub images: usize,
}

/// A configuration that could not run here, with the reason.
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    /// The entry.
    pub entry: Entry,
    /// Why.
    pub reason: String,
}

/// Everything a run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct RunResults {
    /// Rows that ran.
    pub results: Vec<EntryResult>,
    /// Rows that could not run.
    pub skipped: Vec<Skipped>,
    /// Image side (pixels).
    pub side: usize,
    /// Materials in the set.
    pub materials: usize,
    /// Pairs per material of the full rows.
    pub pairs: PairCounts,
    /// Wall time of the whole run (s).
    pub seconds: f64,
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Number of relights a run performs (the unit of `progress`).
pub fn total_steps(materials: &[Material], entries: &[Entry]) -> u64 {
    let n = materials.len();
    entries
        .iter()
        .map(|e| (e.materials.min(n) * e.pairs.total()) as u64)
        .sum()
}

struct Running {
    prepared: Prepared,
    index: usize,
    est_ms: Vec<f64>,
    relight_ms: Vec<f64>,
    sums: [Scores; 3],
    counts: [usize; 3],
}

/// Runs `entries` on `materials` with FLIP at `pixels_per_degree`. Methods that cannot be set
/// up here (no GPU, no bf16 CPU, ...) are reported as skipped, not as errors. GPU and CPU
/// fast-path methods get one untimed warm-up estimate and relight (pipeline compilation,
/// caches). `progress(k)` is called after every `k` relights.
pub fn run(
    materials: &[Material],
    entries: &[Entry],
    gpu: Option<&GpuDevice>,
    pixels_per_degree: f64,
    progress: &mut dyn FnMut(u64),
) -> Result<RunResults> {
    let t0 = Instant::now();
    let Some(first) = materials.first() else {
        return Err(crate::error::EvalError::Option("no materials".into()));
    };
    let side = first.side();
    let mut running = Vec::new();
    let mut skipped = Vec::new();
    for (index, e) in entries.iter().enumerate() {
        match Prepared::new(&e.spec, gpu) {
            Ok(prepared) => running.push(Running {
                prepared,
                index,
                est_ms: Vec::new(),
                relight_ms: Vec::new(),
                sums: [Scores::default(); 3],
                counts: [0; 3],
            }),
            Err(err) => skipped.push(Skipped {
                entry: e.clone(),
                reason: err.to_string(),
            }),
        }
    }
    for r in &running {
        let reference = matches!(
            r.prepared.spec(),
            MethodSpec::Neural(c) if c.backend == crate::methods::Backend::CpuReference
        );
        if !reference {
            let est = r.prepared.estimate(first)?;
            let lv = first.pairs(Protocol::Hemisphere, 1);
            if let Some(lv) = lv.first() {
                r.prepared.relight(&est, side, lv)?;
            }
        }
    }
    let max_pairs = entries.iter().fold(
        PairCounts {
            reflect: 0,
            identity: 0,
            hemisphere: 0,
        },
        |a, e| PairCounts {
            reflect: a.reflect.max(e.pairs.reflect),
            identity: a.identity.max(e.pairs.identity),
            hemisphere: a.hemisphere.max(e.pairs.hemisphere),
        },
    );
    for (mi, m) in materials.iter().enumerate() {
        let mut estimates: Vec<Option<Estimate>> = Vec::with_capacity(running.len());
        for r in running.iter_mut() {
            if mi >= entries[r.index].materials {
                estimates.push(None);
                continue;
            }
            let t = Instant::now();
            let est = r.prepared.estimate(m)?;
            r.est_ms.push(t.elapsed().as_secs_f64() * 1e3);
            estimates.push(Some(est));
        }
        for (pi, &protocol) in PROTOCOLS.iter().enumerate() {
            let pairs = m.pairs(protocol, max_pairs.get(protocol));
            for (k, lv) in pairs.iter().enumerate() {
                let scene = RenderSettings::new(Light::Point(lv.light), View::Point(lv.view));
                let gt = render::<f32>(&m.maps, &scene)?.into_vec();
                let mut preds = Vec::new();
                for (ri, r) in running.iter_mut().enumerate() {
                    let Some(est) = &estimates[ri] else { continue };
                    if k >= entries[r.index].pairs.get(protocol) {
                        continue;
                    }
                    let t = Instant::now();
                    let pred = r.prepared.relight(est, side, lv)?;
                    r.relight_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    preds.push((ri, pred));
                }
                if preds.is_empty() {
                    continue;
                }
                let gt_flip = FlipImage::new(&gt, side, side, pixels_per_degree)?;
                let scores: Result<Vec<(usize, Scores)>> = preds
                    .par_iter()
                    .map(|(ri, pred)| Ok((*ri, score_with(pred, &gt, side, side, &gt_flip)?)))
                    .collect();
                for (ri, s) in scores? {
                    running[ri].sums[pi].add_scaled(&s, 1.0);
                    running[ri].counts[pi] += 1;
                }
                progress(preds.len() as u64);
            }
        }
    }
    let mp = (side * side) as f64 / 1e6;
    let results = running
        .into_iter()
        .map(|mut r| {
            let scores: [Scores; 3] = std::array::from_fn(|p| {
                let mut mean = Scores::default();
                if r.counts[p] > 0 {
                    mean.add_scaled(&r.sums[p], 1.0 / r.counts[p] as f64);
                } else {
                    mean = Scores {
                        log_l1: f64::NAN,
                        log_rmse: f64::NAN,
                        flip: f64::NAN,
                        ssim: f64::NAN,
                    };
                }
                mean
            });
            let entry = entries[r.index].clone();
            let ms_relight = median(&mut r.relight_ms);
            EntryResult {
                width: r.prepared.width(),
                scores,
                ms_per_estimate: entry.spec.has_estimate().then(|| median(&mut r.est_ms)),
                ms_per_megapixel: ms_relight / mp,
                ms_per_relight: ms_relight,
                images: r.counts.iter().sum(),
                entry,
            }
        })
        .collect();
    Ok(RunResults {
        results,
        skipped,
        side,
        materials: materials.len(),
        pairs: max_pairs,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_lists() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&mut []).is_nan());
    }

    #[test]
    fn pair_counts_min_and_total() {
        let a = PairCounts::PAPER.min(PairCounts {
            reflect: 2,
            identity: 5,
            hemisphere: 4,
        });
        assert_eq!(
            a,
            PairCounts {
                reflect: 2,
                identity: 1,
                hemisphere: 4
            }
        );
        assert_eq!(a.total(), 7);
        assert_eq!(a.get(Protocol::Hemisphere), 4);
    }
}
