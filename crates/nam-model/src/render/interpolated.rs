//! Interpolated ND_enc (between the general path and the directional one): for a
//! point light and a perspective viewer far from the surface relative to a pixel,
//! ωi and ωo turn slowly across the image, so ND_enc (86% of the multiply-adds per
//! pixel) runs only on a coarser grid of nodes and its 32 features are bilinearly
//! interpolated to every pixel inside each tile; the render MLP still runs per pixel
//! on the pixel's own params. The grid spacing keeps the turn of ωi and ωo between
//! neighbouring nodes below a caller-given angle ([`interpolation_step`]).

use super::RenderNet;
use super::tile::{Base, Dirs, NoDirs};
use crate::Source;
use crate::error::{ModelError, Result, check_finite};
use crate::geometry::{Directions, pixel_position};
use crate::maps::{ParamMap, Rgb};

/// Grid step in pixels at which ωi and ωo turn by at most `max_angle` radians
/// between neighbouring nodes, for a light and a viewer at heights `light_z`,
/// `view_z` over the surface (surface units, the image spans [-1, 1]²).
///
/// For a point at height z the direction towards it turns at most 1/z radians per
/// unit moved on the surface, so nodes `max_angle · min(z_l, z_v)` units apart
/// (pixels are `2 / side` units) stay within the bound. 1 means the general path.
pub fn interpolation_step(
    light_z: f32,
    view_z: f32,
    height: usize,
    width: usize,
    max_angle: f32,
) -> usize {
    let units = max_angle * light_z.min(view_z);
    let pixel = 2.0 / height.min(width).max(1) as f32;
    let step = (units / pixel).floor();
    if step.is_finite() && step >= 1.0 {
        (step as usize).min(height.max(width).max(1))
    } else {
        1
    }
}

/// ND_enc features on grid nodes and the bilinear weights that carry them to pixels.
pub(crate) struct FeatureGrid {
    width: usize,
    d: usize,
    gw: usize,
    /// Node features, `gh × gw × d`.
    feats: Vec<f32>,
    /// Per image row: the node row above and the weight of the one below.
    rows: Vec<(usize, f32)>,
    /// Per image column: the node column left and the weight of the one right.
    cols: Vec<(usize, f32)>,
}

/// Node lines of one axis (0, step, 2·step, …, and always `len − 1`) and, per
/// pixel, the segment it lies in with its weight towards the segment's end.
fn axis(len: usize, step: usize) -> (Vec<usize>, Vec<(usize, f32)>) {
    let mut lines: Vec<usize> = (0..len).step_by(step).collect();
    if lines.last() != Some(&(len - 1)) {
        lines.push(len - 1);
    }
    let mut seg = 0;
    let per_pixel = (0..len)
        .map(|i| {
            while seg + 2 < lines.len() && i >= lines[seg + 1] {
                seg += 1;
            }
            if lines.len() == 1 {
                return (0, 0.0);
            }
            let (a, b) = (lines[seg], lines[seg + 1]);
            (seg, (i - a) as f32 / (b - a) as f32)
        })
        .collect();
    (lines, per_pixel)
}

impl FeatureGrid {
    /// Writes the interpolated features of pixels `q0..q0 + n` into `out` (`n × d`).
    pub(crate) fn fill(&self, q0: usize, n: usize, out: &mut [f32]) {
        let d = self.d;
        for (q, o) in out[..n * d].chunks_exact_mut(d).enumerate() {
            let g = q0 + q;
            let (r, ty) = self.rows[g / self.width];
            let (c, tx) = self.cols[g % self.width];
            let node = |i: usize, j: usize| {
                let k = (i * self.gw + j) * d;
                &self.feats[k..k + d]
            };
            let (r1, c1) = ((r + 1).min(self.rows_len() - 1), (c + 1).min(self.gw - 1));
            let (f00, f01, f10, f11) = (node(r, c), node(r, c1), node(r1, c), node(r1, c1));
            let w = [
                (1.0 - ty) * (1.0 - tx),
                (1.0 - ty) * tx,
                ty * (1.0 - tx),
                ty * tx,
            ];
            for k in 0..d {
                o[k] = w[0] * f00[k] + w[1] * f01[k] + w[2] * f10[k] + w[3] * f11[k];
            }
        }
    }

    fn rows_len(&self) -> usize {
        self.feats.len() / (self.gw * self.d)
    }
}

impl RenderNet {
    /// Relights like [`Self::relight`] (point light at `light`, viewer at `view`,
    /// surface units) with ND_enc evaluated only on a grid whose spacing keeps the
    /// turn of ωi and ωo between neighbouring nodes at most `max_angle` radians
    /// ([`interpolation_step`]); its features are bilinearly interpolated per pixel.
    /// Where that spacing is below 2 pixels this is the general path, unchanged.
    /// An approximation: its error against the general path is measured in the
    /// error-vs-time report (`nam-cli report`) for several bounds.
    pub fn relight_interpolated(
        &self,
        map: &ParamMap,
        light: [f32; 3],
        view: [f32; 3],
        max_angle: f32,
    ) -> Result<Rgb> {
        check_finite("max angle", &[max_angle])?;
        if max_angle <= 0.0 {
            return Err(ModelError::Unsupported(
                "the interpolation bound must be a positive angle",
            ));
        }
        let (h, w) = (map.height, map.width);
        let step = interpolation_step(light[2], view[2], h, w, max_angle);
        if step < 2 {
            return self.relight(map, light, view);
        }
        let n = self.check_map(map)?;
        check_finite("light", &light)?;
        check_finite("view", &view)?;
        if light[2] <= 0.0 || view[2] <= 0.0 {
            return Err(ModelError::BelowSurface);
        }
        let (row_lines, rows) = axis(h, step);
        let (col_lines, cols) = axis(w, step);
        let (gh, gw, d) = (row_lines.len(), col_lines.len(), self.nd_len());
        let (light, view) = (Source::Point(light), Source::Point(view));
        let mut feats = vec![0.0f32; gh * gw * d];
        self.tiles(&mut feats, d, |s, q0, dst| {
            let m = dst.len() / d;
            self.features_into(s, m, |q| {
                let g = q0 + q;
                let p = pixel_position(row_lines[g / gw], col_lines[g % gw], h, w);
                Directions::at(&light, &view, p).to_array9()
            });
            dst.copy_from_slice(&s.nd[..m * d]);
        });
        let grid = FeatureGrid {
            width: w,
            d,
            gw,
            feats,
            rows,
            cols,
        };
        let mut data = vec![0.0f32; n * 3];
        self.run(
            &mut data,
            true,
            &|g| g,
            Base::Params(&map.data),
            &Dirs::<NoDirs>::Grid(&grid),
        );
        Ok(Rgb {
            height: h,
            width: w,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_covers_every_pixel_with_weights_in_unit_range() {
        for (len, step) in [(1, 4), (7, 2), (8, 4), (9, 4), (256, 8), (13, 5)] {
            let (lines, px) = axis(len, step);
            assert_eq!((lines[0], *lines.last().unwrap()), (0, len - 1));
            for (i, &(seg, t)) in px.iter().enumerate() {
                assert!((0.0..=1.0).contains(&t));
                if lines.len() > 1 {
                    let (a, b) = (lines[seg], lines[seg + 1]);
                    let pos = a as f32 + t * (b - a) as f32;
                    assert!(
                        (pos - i as f32).abs() < 1e-4,
                        "len {len} step {step} pixel {i}"
                    );
                }
            }
        }
    }

    #[test]
    fn step_follows_the_angle_and_the_height() {
        // Capture distance 4.01 at 256²: 1° → 0.07 units → 8 pixels of 2/256.
        assert_eq!(
            interpolation_step(4.01, 4.01, 256, 256, 1f32.to_radians()),
            8
        );
        assert_eq!(
            interpolation_step(1.0, 4.01, 256, 256, 1f32.to_radians()),
            2
        );
        assert_eq!(
            interpolation_step(0.1, 4.01, 256, 256, 1f32.to_radians()),
            1
        );
        assert_eq!(interpolation_step(4.01, 4.01, 64, 64, 1f32.to_radians()), 2);
    }
}
