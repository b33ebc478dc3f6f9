//! Specialised relighting (DESIGN §9): a material prepared once
//! ([`PreparedMaterial`]: `W_p·p` per texel), scenes described by where the
//! light and viewer are ([`Source`]), and evaluation of only what is asked
//! for: a rectangle of pixels ([`Roi`]) or a batch of (texel, ωi, ωo) queries.

use crate::Source;
use crate::encoding::direction_triple;
use crate::error::{ModelError, Result, check_finite, check_len};
use crate::geometry::{Directions, pixel_position};
use crate::maps::{ParamMap, Rgb};
use crate::render::{Base, Dirs, NoDirs, RenderNet};
use crate::sgemm::{Mat, sgemm};
use nam_ggx::Vec3;

/// A param map with the material part of the first render layer precomputed:
/// `rows[t·hidden + o] = Σ_k W_p[o, k] · p_t[k]` for every texel `t` (the
/// layer has no bias). Made by [`RenderNet::prepare`]; usable only with the
/// network that made it (checked).
///
/// Per pixel it saves `64 · 128 = 8,192` multiply-adds of every later render:
/// about 1.3% of a point-light relight, but ~15% of a directional one, where
/// the rest of the first layer is shared by all pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct PreparedMaterial {
    height: usize,
    width: usize,
    hidden: usize,
    net: u64,
    rows: Vec<f32>,
}

impl PreparedMaterial {
    /// Rows of the material.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Columns of the material.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Texels (`height · width`): valid query indices are `0..texels()`, row-major.
    pub fn texels(&self) -> usize {
        self.height * self.width
    }

    /// `W_p·p` per texel (`texels × hidden`), before the first activation.
    pub fn rows(&self) -> &[f32] {
        &self.rows
    }
}

/// A light or viewer the networks can render: finite coordinates, above the surface (z > 0).
fn check_source(source: &Source, what: &'static str) -> Result<()> {
    let v = source.coordinates();
    check_finite(what, &v)?;
    if v[2] <= 0.0 {
        return Err(ModelError::BelowSurface);
    }
    Ok(())
}

/// A rectangle of pixels: rows `row..row + height`, columns `col..col + width`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roi {
    /// First row.
    pub row: usize,
    /// First column.
    pub col: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
}

impl Roi {
    /// The whole `height × width` image.
    pub fn full(height: usize, width: usize) -> Self {
        Self {
            row: 0,
            col: 0,
            height,
            width,
        }
    }

    fn check(&self, height: usize, width: usize) -> Result<()> {
        let fits = self.height > 0
            && self.width > 0
            && self
                .row
                .checked_add(self.height)
                .is_some_and(|e| e <= height)
            && self.col.checked_add(self.width).is_some_and(|e| e <= width);
        if fits {
            Ok(())
        } else {
            Err(ModelError::ImageSize {
                height: self.height,
                width: self.width,
                reason: "region of interest empty or outside the material",
            })
        }
    }
}

impl RenderNet {
    /// Precomputes `W_p·p` for every texel of `map` (one GEMM, k = 64, in
    /// parallel tiles): estimate once, prepare once, relight many times
    /// ([`Self::relight_prepared`], [`Self::render_log_prepared`]).
    pub fn prepare(&self, map: &ParamMap) -> Result<PreparedMaterial> {
        let n = self.check_map(map)?;
        let (p, h1) = (self.params, self.hidden_len());
        let mut rows = vec![0.0f32; n * h1];
        let first = &self.render[0];
        self.tiles(&mut rows, h1, |_, q0, dst| {
            let m = dst.len() / h1;
            let src = Mat {
                data: &map.data[q0 * p..(q0 + m) * p],
                ld: p,
            };
            sgemm(m, h1, p, src, first.rows_from(0), dst, h1, false, 1);
        });
        Ok(PreparedMaterial {
            height: map.height,
            width: map.width,
            hidden: h1,
            net: self.first_id,
            rows,
        })
    }

    fn check_prepared(&self, prep: &PreparedMaterial) -> Result<()> {
        check_len("prepared material width", self.hidden_len(), prep.hidden)?;
        if prep.net != self.first_id {
            return Err(ModelError::ParamFile {
                file: "prepared material".into(),
                reason: "prepared by a network with other weights".into(),
            });
        }
        Ok(())
    }

    /// Relights the pixels of `roi` of a prepared material (radiance, `roi.height
    /// × roi.width` RGB, row-major) for a light and a viewer, evaluating
    /// nothing outside the rectangle. With both sources [`Source::Distant`]
    /// the encoding and ND_enc run once and per pixel only the render layers
    /// after the first; otherwise directions are computed per pixel. The
    /// output equals the same pixels of [`Self::relight`] (point light,
    /// perspective view) or [`Self::relight_directional`] (both distant) up to
    /// f32 summation order.
    pub fn relight_prepared(
        &self,
        prep: &PreparedMaterial,
        light: Source,
        view: Source,
        roi: Roi,
    ) -> Result<Rgb> {
        self.check_prepared(prep)?;
        let base = Base::Prepared(&prep.rows);
        self.relight_region(base, prep.height, prep.width, light, view, roi)
    }

    /// Relights the pixels of `roi` of a param map for a light and a viewer,
    /// like [`Self::relight_prepared`] but streaming: `W_p·p` is computed per
    /// tile, so no `texels × hidden` buffer is allocated (the choice for a
    /// single relight; prepare once for many). Both sources distant: encoding
    /// and ND_enc run once for the region.
    pub fn relight_sources(
        &self,
        map: &ParamMap,
        light: Source,
        view: Source,
        roi: Roi,
    ) -> Result<Rgb> {
        self.check_map(map)?;
        let base = Base::Params(&map.data);
        self.relight_region(base, map.height, map.width, light, view, roi)
    }

    /// The region relight behind [`Self::relight_prepared`] and
    /// [`Self::relight_sources`] for an `h × w` material.
    fn relight_region(
        &self,
        base: Base<'_>,
        h: usize,
        w: usize,
        light: Source,
        view: Source,
        roi: Roi,
    ) -> Result<Rgb> {
        check_source(&light, "light")?;
        check_source(&view, "view")?;
        roi.check(h, w)?;
        let texel = |g: usize| (roi.row + g / roi.width) * w + roi.col + g % roi.width;
        let mut data = vec![0.0f32; roi.height * roi.width * 3];
        if matches!((light, view), (Source::Distant(_), Source::Distant(_))) {
            // Distant sources: the same directions at every surface point.
            let origin = Vec3::zero();
            let c = self.constant_direction_part(
                light.direction_from(origin).to_array(),
                view.direction_from(origin).to_array(),
            );
            self.run(&mut data, true, &texel, base, &Dirs::<NoDirs>::Constant(&c));
        } else {
            let dirs = Dirs::Each(|g: usize| {
                let t = texel(g);
                Directions::at(&light, &view, pixel_position(t / w, t % w, h, w)).to_array9()
            });
            self.run(&mut data, true, &texel, base, &dirs);
        }
        Ok(Rgb {
            height: roi.height,
            width: roi.width,
            data,
        })
    }

    /// Log-space output `ln(R + 1)` (`n × 3`) for `n` queries of a prepared
    /// material: query `q` is texel `texels[q]` (row-major index) seen with
    /// directions `wi[q]`, `wo[q]` (surface frame, unit vectors). Only the
    /// queried texels are evaluated, in any order and with repeats. Radiance
    /// is [`radiance_from_log`](crate::radiance_from_log) of each value.
    pub fn render_log_prepared(
        &self,
        prep: &PreparedMaterial,
        texels: &[usize],
        wi: &[[f32; 3]],
        wo: &[[f32; 3]],
        out_log: &mut [f32],
    ) -> Result<()> {
        self.check_prepared(prep)?;
        let n = texels.len();
        check_len("wi", n, wi.len())?;
        check_len("wo", n, wo.len())?;
        check_len("log out", n * 3, out_log.len())?;
        check_finite("wi", wi.as_flattened())?;
        check_finite("wo", wo.as_flattened())?;
        if let Some(&t) = texels.iter().find(|&&t| t >= prep.texels()) {
            return Err(ModelError::Size {
                what: "query texel index (must be < height·width)",
                expected: prep.texels(),
                found: t,
            });
        }
        let dirs = Dirs::Each(|g: usize| direction_triple(wi[g], wo[g]));
        self.run(
            out_log,
            false,
            &|g| texels[g],
            Base::Prepared(&prep.rows),
            &dirs,
        );
        Ok(())
    }
}
