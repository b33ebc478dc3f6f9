//! Which products run fastest on this CPU, measured rather than guessed: [`RenderNet::fastest`]
//! times one fused tile of the general path (encoding, ND_enc, render MLP) with every precision
//! the CPU supports and keeps the fastest.

use std::time::Instant;

use super::{Base, Dirs, Precision, RenderNet};
use crate::bf16::bf16_supported;
use crate::encoding::direction_triple;
use crate::error::Result;
use crate::geometry::unit_direction;
use crate::int8::int8_supported;

/// Timed repetitions of the probe tile per precision (the best is kept); one more warms up.
const PROBE_RUNS: usize = 5;

/// One precision's probe time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeTime {
    pub precision: Precision,
    /// Best time of one tile ([`crate::DEFAULT_TILE`]-sized unless set otherwise), in ms.
    pub ms: f64,
}

impl RenderNet {
    /// The precisions this CPU can run the fused paths in: f32 always, bf16 with AVX-512 BF16,
    /// int8 with AVX-512 VNNI.
    pub fn supported_precisions() -> Vec<Precision> {
        let mut v = vec![Precision::F32];
        if bf16_supported() {
            v.push(Precision::Bf16);
        }
        if int8_supported() {
            v.push(Precision::Int8);
        }
        v
    }

    /// This network switched to `precision` (f32: the reduced twins dropped).
    pub fn with_precision(self, precision: Precision) -> Result<Self> {
        match precision {
            Precision::F32 => Ok(Self {
                reduced: None,
                ..self
            }),
            Precision::Bf16 => self.with_bf16(),
            Precision::Int8 => self.with_int8(),
        }
    }

    /// The fastest of [`Self::supported_precisions`] on this CPU, single-threaded on one tile of
    /// the general path (a few ms in all), and every probe time. The result computes in that
    /// precision; see the report for each one's error.
    pub fn fastest(self) -> Result<(Self, Vec<ProbeTime>)> {
        let mut best: Option<(f64, Self)> = None;
        let mut times = Vec::new();
        for precision in Self::supported_precisions() {
            let net = self.clone().with_precision(precision)?;
            let ms = net.probe_tile_ms();
            times.push(ProbeTime { precision, ms });
            if best.as_ref().is_none_or(|(b, _)| ms < *b) {
                best = Some((ms, net));
            }
        }
        Ok((best.map_or(self, |(_, net)| net), times))
    }

    /// Best of [`PROBE_RUNS`] timings of one tile of random-looking params under a point light.
    fn probe_tile_ms(&self) -> f64 {
        let n = self.tile;
        let p = self.params;
        let params: Vec<f32> = (0..n * p)
            .map(|i| ((i * 7919 % 1000) as f32 / 500.0 - 1.0) * 0.5)
            .collect();
        let dirs = Dirs::Each(|g: usize| {
            let x = (g % 16) as f32 / 16.0 - 0.5;
            direction_triple(unit_direction([x, 0.3, 1.0]), unit_direction([0.2, x, 1.0]))
        });
        let mut s = self.scratch(n);
        let mut best = f64::INFINITY;
        for run in 0..=PROBE_RUNS {
            let t0 = Instant::now();
            self.run_tile(&mut s, (0, n), &|g| g, Base::Params(&params), &dirs);
            if run > 0 {
                best = best.min(t0.elapsed().as_secs_f64() * 1e3);
            }
        }
        best
    }
}
