//! The networks' layout, derived from the config: every tensor's name and shape
//! (docs/FORMAT.md, "Tensor names"), the pixel grid each U-Net convolution runs on, and from
//! them the multiply-add counts that the CPU and GPU paths and the benchmarks report.
//! Loaders validate files against [`expected_tensors`]; nothing else spells the layout out.

use crate::config::ModelConfig;

/// The U-Net pads each image side to a multiple of this many pixels: its three stride-2
/// encoder stages halve the grid three times and the decoder doubles it back.
pub const UNET_MULTIPLE: usize = 8;

/// One tensor of the layout.
struct Entry {
    name: String,
    shape: Vec<usize>,
    /// For a U-Net convolution weight, the grid its multiply-adds run on, as the power of two
    /// the padded input's side is divided by (0: full resolution): the output grid of a
    /// convolution, the input grid of a transposed one. `None` for everything else.
    grid: Option<u32>,
}

/// The complete `name → shape` list of a model file, derived from its config
/// (docs/FORMAT.md, "Tensor names"), in network order.
pub fn expected_tensors(cfg: &ModelConfig) -> Vec<(String, Vec<usize>)> {
    layout(cfg).into_iter().map(|e| (e.name, e.shape)).collect()
}

/// Which multiply-adds of `M_render` a render path spends per output (pixel or query).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RenderWork {
    /// `render.l0` and `render.l1` multiplied into one `[r2, r0]` layer at load (there is no
    /// activation between them) instead of `[r1, r0]` then `[r2, r1]` as stored.
    pub folded: bool,
    /// The material's part of the first layer, `W_p·p`, computed once per texel (a prepared
    /// material) instead of per output.
    pub prepared: bool,
    /// How much of the direction branch runs per output.
    pub directions: DirectionWork,
}

/// The direction branch's share of the per-output work.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DirectionWork {
    /// Positional encoding, ND_enc and the first layer's direction columns `W_d·f` per output
    /// (the general path).
    PerOutput,
    /// ND_enc once per frame; its features still go through `W_d` per output (the GPU's
    /// directional plan writes them into every row).
    FeaturesShared,
    /// ND_enc and `W_d·f` once per frame (the CPU's directional and orthographic path).
    Shared,
}

impl ModelConfig {
    /// Multiply-adds of one `M_est` on a `height × width` photo padded to multiples of
    /// [`UNET_MULTIPLE`]: every convolution weight `[a, b, k, k]` costs `a·b·k²` per pixel of
    /// the grid it runs on (every tap counted, as the CPU, the GPU and torch compute them).
    pub fn estimate_macs(&self, height: usize, width: usize) -> u64 {
        let hw =
            (height.next_multiple_of(UNET_MULTIPLE) * width.next_multiple_of(UNET_MULTIPLE)) as u64;
        layout(self)
            .iter()
            .filter_map(|e| {
                let grid = e.grid?;
                Some(e.shape.iter().product::<usize>() as u64 * (hw >> (2 * grid)))
            })
            .sum()
    }

    /// Multiply-adds of `M_render` per output (pixel or query) of the path `work` describes.
    /// The general path unfolded is DESIGN §4's count (634,470 for the standard widths).
    pub fn render_macs(&self, work: RenderWork) -> u64 {
        let r = &self.render;
        let dense = |w: &[usize]| w.windows(2).map(|p| p[0] * p[1]).sum::<usize>();
        // The first layer (folded or not) and the layers after it.
        let (first_out, tail) = if work.folded {
            (r[2], dense(&r[2..]))
        } else {
            (r[1], dense(&r[1..]))
        };
        let nd_out = self.nd_enc[self.nd_enc.len() - 1];
        let material = if work.prepared {
            0
        } else {
            self.param_channels * first_out
        };
        let directions = match work.directions {
            DirectionWork::PerOutput => dense(&self.nd_enc) + nd_out * first_out,
            DirectionWork::FeaturesShared => nd_out * first_out,
            DirectionWork::Shared => 0,
        };
        (material + directions + tail) as u64
    }
}

/// The layout in network order: the U-Net (`est.*`) with the grid of each convolution, then
/// ND_enc and the render MLP.
fn layout(cfg: &ModelConfig) -> Vec<Entry> {
    let mut out = Layout(Vec::new());
    let c = cfg.width;
    out.conv("est.stem.weight", vec![c, cfg.in_channels, 7, 7], 0);
    let widths = [c, 2 * c, 4 * c, 8 * c];
    let mut prev = c;
    for (k, &w) in (0u32..).zip(&widths) {
        let stride = if k == 0 { 1 } else { 2 };
        out.basic_block(&format!("est.enc{}.0", k + 1), prev, w, stride, k);
        out.basic_block(&format!("est.enc{}.1", k + 1), w, w, 1, k);
        prev = w;
    }
    out.reverse_block("est.dec1.0", 8 * c, 8 * c, 3);
    out.basic_block("est.dec1.1", 8 * c, 8 * c, 1, 2);
    out.reverse_block("est.dec2.0", 12 * c, 4 * c, 2);
    out.basic_block("est.dec2.1", 4 * c, 4 * c, 1, 1);
    out.reverse_block("est.dec3.0", 6 * c, 2 * c, 1);
    out.basic_block("est.dec3.1", 2 * c, 2 * c, 1, 0);
    out.basic_block("est.dec4.0", 3 * c, c, 1, 0);
    out.basic_block("est.dec4.1", c, c, 1, 0);
    out.conv(
        "est.head.weight",
        vec![cfg.param_channels, cfg.head_in_channels(), 7, 7],
        0,
    );
    for (i, pair) in cfg.nd_enc.windows(2).enumerate() {
        out.other(format!("nd_enc.l{i}.weight"), vec![pair[1], pair[0]]);
    }
    for (i, pair) in cfg.render.windows(2).enumerate() {
        out.other(format!("render.l{i}.weight"), vec![pair[1], pair[0]]);
    }
    out.0
}

struct Layout(Vec<Entry>);

impl Layout {
    fn conv(&mut self, name: &str, shape: Vec<usize>, grid: u32) {
        self.0.push(Entry {
            name: name.to_string(),
            shape,
            grid: Some(grid),
        });
    }

    fn other(&mut self, name: String, shape: Vec<usize>) {
        self.0.push(Entry {
            name,
            shape,
            grid: None,
        });
    }

    /// An HA-Conv from grid `grid_in` to `grid_out`: `inc1a` runs at the input grid, the
    /// stride (if any) is in `gate`, `feat`, `inc1b` and `inc2`.
    fn ha(&mut self, p: &str, cin: usize, cout: usize, grid_in: u32, grid_out: u32) {
        self.conv(&format!("{p}.gate.weight"), vec![cout, cin, 3, 3], grid_out);
        self.conv(&format!("{p}.feat.weight"), vec![cout, cin, 3, 3], grid_out);
        self.conv(&format!("{p}.inc1a.weight"), vec![cout, cin, 3, 3], grid_in);
        self.conv(
            &format!("{p}.inc1b.weight"),
            vec![cout / 2, cout, 3, 3],
            grid_out,
        );
        self.conv(
            &format!("{p}.inc2.weight"),
            vec![cout / 2, cin, 3, 3],
            grid_out,
        );
    }

    /// A basic block whose output is on grid `grid` (its input on `grid - 1` when strided).
    fn basic_block(&mut self, p: &str, cin: usize, cout: usize, stride: usize, grid: u32) {
        let grid_in = if stride == 1 { grid } else { grid - 1 };
        self.ha(&format!("{p}.ha1"), cin, cout, grid_in, grid);
        self.other(format!("{p}.bn1.scale"), vec![cout]);
        self.other(format!("{p}.bn1.shift"), vec![cout]);
        self.ha(&format!("{p}.ha2"), cout, cout, grid, grid);
        self.other(format!("{p}.bn2.scale"), vec![cout]);
        self.other(format!("{p}.bn2.shift"), vec![cout]);
        if cin != cout || stride != 1 {
            self.conv(&format!("{p}.down.weight"), vec![cout, cin, 1, 1], grid);
            self.other(format!("{p}.down.bias"), vec![cout]);
        }
    }

    /// A reverse (upsampling) block from grid `grid_in` to `grid_in - 1`: the transposed
    /// convolutions count per input pixel, the 3×3 convolution per output pixel.
    fn reverse_block(&mut self, p: &str, cin: usize, cout: usize, grid_in: u32) {
        self.conv(&format!("{p}.up4.weight"), vec![cin, cout, 4, 4], grid_in);
        self.other(format!("{p}.up4.bias"), vec![cout]);
        self.conv(
            &format!("{p}.conv.weight"),
            vec![cout, cout, 3, 3],
            grid_in - 1,
        );
        self.other(format!("{p}.conv.bias"), vec![cout]);
        self.conv(&format!("{p}.up2.weight"), vec![cin, cout, 2, 2], grid_in);
        self.other(format!("{p}.up2.bias"), vec![cout]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn render_macs_follow_design_section_4() {
        let cfg = ModelConfig::standard(8);
        let work = |folded, prepared, directions| RenderWork {
            folded,
            prepared,
            directions,
        };
        use DirectionWork::*;
        assert_eq!(cfg.render_macs(work(false, false, PerOutput)), 634_470);
        assert_eq!(
            cfg.render_macs(work(true, false, PerOutput)),
            634_470 - 128 * 128
        );
        let tail = 3 * 128 * 128 + 128 * 64 + 64 * 3;
        assert_eq!(cfg.render_macs(work(true, true, Shared)), tail);
        assert_eq!(
            cfg.render_macs(work(true, false, FeaturesShared)),
            96 * 128 + tail
        );
    }

    #[test]
    fn estimate_macs_pad_to_the_unet_multiple() {
        let cfg = ModelConfig::standard(8);
        assert_eq!(cfg.estimate_macs(250, 251), cfg.estimate_macs(256, 256));
        assert!(cfg.estimate_macs(256, 256) > cfg.estimate_macs(248, 256));
        // Every term scales with the pixel count.
        assert_eq!(4 * cfg.estimate_macs(64, 64), cfg.estimate_macs(128, 128));
    }
}
