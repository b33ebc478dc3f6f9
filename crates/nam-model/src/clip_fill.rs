//! Latent params where the photo clipped, filled in from the pixels around them.
//!
//! A pixel the photo clipped (a channel at or above [`LDR_CLAMP`](crate::input::LDR_CLAMP),
//! pure white to an LDR model) shows only that the radiance there was at least 1; the U-Net's
//! params there are a guess that keeps the flash highlight baked in. [`fill_clipped`] replaces
//! them by a push-pull interpolation of the other pixels' params (Gortler et al. 1996, "The
//! Lumigraph", §3.4), O(pixels); `train_py/clip_fill.py` is the torch twin, with the measurement
//! that made it the default, and `golden.py` stores both ends for the parity test.

use rayon::prelude::*;

use crate::error::{Result, check_len};
use crate::maps::ParamMap;

/// Replaces the params of the pixels where `clipped` (row-major, one flag per pixel) is true by
/// a push-pull interpolation of the others; the others keep theirs bit for bit. A map with no
/// clipped pixel, or with every pixel clipped (nothing to fill from), is left as it is.
///
/// Push: halve the map (2×2 blocks; a last odd row or column alone) until every pixel of a level
/// has an unclipped pixel below it; a coarse pixel is the mean of its unclipped children. Pull:
/// from the coarsest level down, each clipped pixel takes the bilinear upsample of the filled
/// level above (child `i` at parent coordinate `(i + 0.5) / 2 − 0.5`, clamped to the edge).
pub fn fill_clipped(map: &mut ParamMap, clipped: &[bool]) -> Result<()> {
    check_len("clipped mask", map.height * map.width, clipped.len())?;
    check_len(
        "param map",
        map.height * map.width * map.channels,
        map.data.len(),
    )?;
    if !clipped.contains(&true) || !clipped.contains(&false) {
        return Ok(());
    }
    let keep: Vec<bool> = clipped.iter().map(|&c| !c).collect();
    push_pull(map, &keep);
    Ok(())
}

/// Fills `level`'s pixels where `keep` is false (the recursion of [`fill_clipped`]).
fn push_pull(level: &mut ParamMap, keep: &[bool]) {
    let (h, w) = (level.height, level.width);
    if keep.iter().all(|&k| k) || (h == 1 && w == 1) {
        return;
    }
    let (mut coarse, coarse_keep) = push(level, keep);
    push_pull(&mut coarse, &coarse_keep);
    pull(level, keep, &coarse);
}

/// The next coarser level: each pixel the mean of its kept children (0 and not kept when it has
/// none).
fn push(level: &ParamMap, keep: &[bool]) -> (ParamMap, Vec<bool>) {
    let (h, w, c) = (level.height, level.width, level.channels);
    let (ph, pw) = (h.div_ceil(2), w.div_ceil(2));
    let mut data = vec![0.0f32; ph * pw * c];
    let mut counts = vec![0u32; ph * pw];
    data.par_chunks_mut(pw * c)
        .zip(counts.par_chunks_mut(pw))
        .enumerate()
        .for_each(|(pr, (row, row_counts))| {
            for (pc, (out, count)) in row.chunks_mut(c).zip(row_counts.iter_mut()).enumerate() {
                for r in (2 * pr)..(2 * pr + 2).min(h) {
                    for col in (2 * pc)..(2 * pc + 2).min(w) {
                        let p = r * w + col;
                        if keep[p] {
                            *count += 1;
                            let src = &level.data[p * c..(p + 1) * c];
                            out.iter_mut().zip(src).for_each(|(o, s)| *o += s);
                        }
                    }
                }
                if *count > 0 {
                    let n = *count as f32;
                    out.iter_mut().for_each(|o| *o /= n);
                }
            }
        });
    let map = ParamMap {
        height: ph,
        width: pw,
        channels: c,
        data,
    };
    (map, counts.iter().map(|&n| n > 0).collect())
}

/// Bilinear taps of child index `i` in a parent axis of `parent` pixels: (low, high, weight of
/// high).
fn taps(i: usize, parent: usize) -> (usize, usize, f32) {
    let x = ((i as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (parent - 1) as f32);
    let lo = x.floor() as usize;
    (lo, (lo + 1).min(parent - 1), x - lo as f32)
}

/// Sets `level`'s pixels where `keep` is false to the bilinear upsample of `coarse` (filled).
fn pull(level: &mut ParamMap, keep: &[bool], coarse: &ParamMap) {
    let (w, c, pw) = (level.width, level.channels, coarse.width);
    let at = |r: usize, col: usize| &coarse.data[(r * pw + col) * c..(r * pw + col + 1) * c];
    level
        .data
        .par_chunks_mut(w * c)
        .zip(keep.par_chunks(w))
        .enumerate()
        .for_each(|(r, (row, row_keep))| {
            let (r0, r1, fr) = taps(r, coarse.height);
            for (col, (out, _)) in row
                .chunks_mut(c)
                .zip(row_keep)
                .enumerate()
                .filter(|(_, (_, k))| !**k)
            {
                let (c0, c1, fc) = taps(col, pw);
                let (a, b, d, e) = (at(r0, c0), at(r0, c1), at(r1, c0), at(r1, c1));
                for k in 0..c {
                    let left = a[k] * (1.0 - fr) + d[k] * fr;
                    let right = b[k] * (1.0 - fr) + e[k] * fr;
                    out[k] = left * (1.0 - fc) + right * fc;
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(h: usize, w: usize, c: usize) -> ParamMap {
        let data = (0..h * w * c)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) / 10.0)
            .collect();
        ParamMap {
            height: h,
            width: w,
            channels: c,
            data,
        }
    }

    #[test]
    fn unclipped_pixels_keep_their_params_and_clipped_ones_change() {
        let (h, w, c) = (7, 9, 3);
        let before = map(h, w, c);
        let clipped: Vec<bool> = (0..h * w)
            .map(|p| (2..5).contains(&(p / w)) && (3..8).contains(&(p % w)))
            .collect();
        let mut after = before.clone();
        fill_clipped(&mut after, &clipped).expect("fill");
        let pixels = after.data.chunks(c).zip(before.data.chunks(c));
        for (p, ((a, b), &is_clipped)) in pixels.zip(&clipped).enumerate() {
            assert_eq!(a == b, !is_clipped, "pixel {p}");
            assert!(a.iter().all(|v| v.is_finite()));
        }
    }

    #[test]
    fn a_constant_map_stays_constant_and_all_or_nothing_clipped_is_untouched() {
        let mut m = ParamMap {
            height: 11,
            width: 6,
            channels: 2,
            data: vec![2.5; 11 * 6 * 2],
        };
        let clipped: Vec<bool> = (0..66).map(|p| p % 3 != 0 || p < 30).collect();
        fill_clipped(&mut m, &clipped).expect("fill");
        assert!(m.data.iter().all(|&v| (v - 2.5).abs() < 1e-6));
        let before = map(4, 5, 3);
        for flag in [true, false] {
            let mut m = before.clone();
            fill_clipped(&mut m, &[flag; 20]).expect("fill");
            assert_eq!(m, before);
        }
    }

    #[test]
    fn a_mask_of_the_wrong_length_is_an_error() {
        let mut m = map(4, 5, 3);
        assert!(fill_clipped(&mut m, &[false; 19]).is_err());
    }
}
