//! Dense layers of `M_render` as the tile chain runs them: f32 ([`Dense`], `y = x·Wᵀ` on the
//! transposed weights) or reduced precision ([`Reduced`]: bf16 or int8 products), each with its
//! optional LeakyReLU, and [`chain`], which runs a stack of them on one tile.

use crate::bf16::Bf16Dense;
use crate::int8::Int8Dense;
use crate::sgemm::{Mat, sgemm};
use crate::simd::Line;

/// One dense layer `y = x · Wᵀ` stored transposed (`wt[i·out + o] = W[o, i]`),
/// followed by an optional LeakyReLU.
#[derive(Debug, Clone)]
pub(crate) struct Dense {
    pub inp: usize,
    pub out: usize,
    pub wt: Vec<f32>,
    pub slope: Option<f32>,
}

impl Dense {
    /// From `W` stored `[out, inp]` row-major (a torch `Linear` weight).
    pub(crate) fn from_w(w: &[f32], out: usize, inp: usize, slope: Option<f32>) -> Self {
        let mut wt = vec![0.0f32; inp * out];
        for o in 0..out {
            for i in 0..inp {
                wt[i * out + o] = w[o * inp + i];
            }
        }
        Self {
            inp,
            out,
            wt,
            slope,
        }
    }

    /// `Wᵀ` from input row `k0` on, as a GEMM operand: the part of the layer
    /// that sees inputs `k0..`.
    pub(crate) fn rows_from(&self, k0: usize) -> Mat<'_> {
        Mat {
            data: &self.wt[k0 * self.out..],
            ld: self.out,
        }
    }

    /// The activation, in place, on `n` rows of `y` (leading dimension `ldy`).
    pub(crate) fn activate(&self, n: usize, y: &mut [f32], ldy: usize) {
        if let Some(s) = self.slope {
            for r in 0..n {
                for v in &mut y[r * ldy..r * ldy + self.out] {
                    *v = if *v >= 0.0 { *v } else { *v * s };
                }
            }
        }
    }
}

/// A layer the tile chain can run: f32 ([`Dense`]) or [`Reduced`].
pub(crate) trait Layer {
    fn width(&self) -> usize;
    /// `y[n×out] (ld ldy) = act(x[n×inp] (ld ldx) · Wᵀ)`, single-threaded; `packed` is scratch
    /// for the reduced-precision operands.
    fn run(
        &self,
        n: usize,
        x: &[f32],
        ldx: usize,
        y: &mut [f32],
        ldy: usize,
        packed: &mut Vec<Line>,
    );
}

impl Layer for Dense {
    fn width(&self) -> usize {
        self.out
    }

    fn run(&self, n: usize, x: &[f32], ldx: usize, y: &mut [f32], ldy: usize, _: &mut Vec<Line>) {
        sgemm(
            n,
            self.out,
            self.inp,
            Mat { data: x, ld: ldx },
            self.rows_from(0),
            y,
            ldy,
            false,
            1,
        );
        self.activate(n, y, ldy);
    }
}

/// A reduced-precision layer: bf16 ([`Bf16Dense`]) or int8 ([`Int8Dense`]) products, f32
/// accumulation and activation.
#[derive(Debug, Clone)]
pub(crate) enum Reduced {
    Bf16(Bf16Dense),
    Int8(Int8Dense),
}

impl Layer for Reduced {
    fn width(&self) -> usize {
        match self {
            Self::Bf16(l) => l.out(),
            Self::Int8(l) => l.out(),
        }
    }

    fn run(
        &self,
        n: usize,
        x: &[f32],
        ldx: usize,
        y: &mut [f32],
        ldy: usize,
        packed: &mut Vec<Line>,
    ) {
        match self {
            Self::Bf16(l) => l.forward(n, x, ldx, y, ldy, packed),
            Self::Int8(l) => l.forward(n, x, ldx, y, ldy, packed),
        }
    }
}

/// Runs `layers` on `n` rows of `input`, ping-ponging through `a` and `b`;
/// the last layer writes `last` (leading dimension `ldlast`). With no
/// layers the input is copied.
#[allow(clippy::too_many_arguments)]
pub(crate) fn chain<L: Layer>(
    layers: &[L],
    n: usize,
    input: &[f32],
    ldin: usize,
    a: &mut [f32],
    b: &mut [f32],
    last: &mut [f32],
    ldlast: usize,
    packed: &mut Vec<Line>,
) {
    let Some((tail, body)) = layers.split_last() else {
        for r in 0..n {
            last[r * ldlast..r * ldlast + ldin].copy_from_slice(&input[r * ldin..(r + 1) * ldin]);
        }
        return;
    };
    // Where the current activations are: `input`, `a` or `b`.
    let mut in_a: Option<bool> = None;
    let mut ld = ldin;
    for l in body {
        let (src, dst): (&[f32], &mut [f32]) = match in_a {
            None => (input, &mut *a),
            Some(true) => (&*a, &mut *b),
            Some(false) => (&*b, &mut *a),
        };
        l.run(n, src, ld, dst, l.width(), packed);
        ld = l.width();
        in_a = Some(in_a != Some(true));
    }
    let src: &[f32] = match in_a {
        None => input,
        Some(true) => a,
        Some(false) => b,
    };
    tail.run(n, src, ld, last, ldlast, packed);
}
