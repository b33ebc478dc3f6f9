//! The typed model config stored in `__metadata__["config"]` (docs/FORMAT.md).

use serde::{Deserialize, Serialize};

/// How the input photo is log-compressed into network input channels 0..3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogMode {
    /// `ln(1 + clamp(rgb_linear, 0, 0.999999))` (sRGB decoded first).
    Ldr,
    /// `ln(1 + max(rgb, 0))`.
    Hdr,
}

/// Leaky-ReLU negative slopes of the networks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Slopes {
    /// HA-Conv feature branch (0.1).
    pub ha: f32,
    /// ND_enc hidden layers (0.01).
    pub nd_enc: f32,
    /// Render MLP hidden layers after the first (0.01).
    pub render_hidden: f32,
    /// Render MLP output (0.001).
    pub render_out: f32,
}

/// Architecture description of a model file. Unknown keys are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    /// Must be `"nam-model"`.
    pub format: String,
    /// Format version; this reader supports 1.
    pub version: u32,
    /// U-Net base width C (stages C, 2C, 4C, 8C). Must be even.
    pub width: usize,
    /// Network input channels (4: log RGB + half-vector z).
    pub in_channels: usize,
    /// The U-Net head convolves `[decoder output, network input]` (`width + in_channels`
    /// channels) instead of the decoder output alone: a direct path for the photo's
    /// per-pixel colour (not in the paper; docs/FORMAT.md). Absent = `false`.
    #[serde(default)]
    pub input_skip: bool,
    /// Latent parameters per pixel (64).
    pub param_channels: usize,
    /// Input log compression.
    pub log_mode: LogMode,
    /// Positional-encoding octaves (16); ND_enc input is `9 + 18·pe_octaves`.
    pub pe_octaves: usize,
    /// ND_enc layer widths, input first (`[297, 594, 594, 32]`).
    pub nd_enc: Vec<usize>,
    /// Render MLP widths, input first (`[96, 128, 128, 128, 128, 128, 64, 3]`).
    pub render: Vec<usize>,
    /// Leaky-ReLU slopes.
    pub slopes: Slopes,
    /// InstanceNorm epsilon (1e-5).
    pub norm_eps: f32,
    /// BatchNorm folded into convs at export; this reader requires `true`.
    pub bn_folded: bool,
    /// Storage dtype the exporter used (informational: "f32", "f16", "bf16").
    #[serde(default = "default_dtype")]
    pub dtype: String,
}

fn default_dtype() -> String {
    "f32".into()
}

/// Largest accepted layer width / U-Net base width (guards shape arithmetic).
pub const MAX_WIDTH: usize = 1 << 16;

impl ModelConfig {
    /// The standard architecture of DESIGN §4 with U-Net base width `width` (LDR, f32).
    pub fn standard(width: usize) -> Self {
        Self {
            format: "nam-model".into(),
            version: 1,
            width,
            in_channels: 4,
            input_skip: false,
            param_channels: 64,
            log_mode: LogMode::Ldr,
            pe_octaves: 16,
            nd_enc: vec![297, 594, 594, 32],
            render: vec![96, 128, 128, 128, 128, 128, 64, 3],
            slopes: Slopes {
                ha: 0.1,
                nd_enc: 0.01,
                render_hidden: 0.01,
                render_out: 0.001,
            },
            norm_eps: 1e-5,
            bn_folded: true,
            dtype: "f32".into(),
        }
    }

    /// Parses the JSON string of `__metadata__["config"]` and checks it.
    pub fn from_json(json: &str) -> Result<Self, String> {
        let cfg: Self = serde_json::from_str(json).map_err(|e| e.to_string())?;
        cfg.check()?;
        Ok(cfg)
    }

    /// JSON form, as written to `__metadata__["config"]`.
    pub fn to_json(&self) -> String {
        // Serialising plain data to a String cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Input channels of the U-Net head: `width`, plus `in_channels` with [`Self::input_skip`].
    pub fn head_in_channels(&self) -> usize {
        self.width + if self.input_skip { self.in_channels } else { 0 }
    }

    /// Length of the positional encoding: `9 + 18·pe_octaves`.
    pub fn encoding_len(&self) -> usize {
        9 + 18 * self.pe_octaves
    }

    /// Checks internal consistency; the message says what is wrong.
    pub fn check(&self) -> Result<(), String> {
        if self.format != "nam-model" {
            return Err(format!(
                "format is {:?}, expected \"nam-model\"",
                self.format
            ));
        }
        if self.version != 1 {
            return Err(format!(
                "version {} unsupported (this reader knows 1)",
                self.version
            ));
        }
        if self.width < 2 || !self.width.is_multiple_of(2) || self.width > MAX_WIDTH / 16 {
            return Err(format!(
                "width {} must be even and in 2..={}",
                self.width,
                MAX_WIDTH / 16
            ));
        }
        for (what, v) in [
            ("in_channels", self.in_channels),
            ("param_channels", self.param_channels),
        ] {
            if v == 0 || v > MAX_WIDTH {
                return Err(format!("{what} {v} must be in 1..={MAX_WIDTH}"));
            }
        }
        if self.pe_octaves > 30 {
            return Err(format!("pe_octaves {} > 30", self.pe_octaves));
        }
        if self.nd_enc.len() < 2 || self.render.len() < 3 {
            return Err("nd_enc needs ≥ 2 widths and render ≥ 3".into());
        }
        if let Some(bad) = self
            .nd_enc
            .iter()
            .chain(&self.render)
            .find(|&&w| w == 0 || w > MAX_WIDTH)
        {
            return Err(format!("layer width {bad} must be in 1..={MAX_WIDTH}"));
        }
        if self.nd_enc[0] != self.encoding_len() {
            return Err(format!(
                "nd_enc input {} != 9 + 18·pe_octaves = {}",
                self.nd_enc[0],
                self.encoding_len()
            ));
        }
        let nd_out = self.nd_enc[self.nd_enc.len() - 1];
        if self.render[0] != self.param_channels + nd_out {
            return Err(format!(
                "render input {} != param_channels {} + nd_enc output {}",
                self.render[0], self.param_channels, nd_out
            ));
        }
        if self.render[self.render.len() - 1] != 3 {
            return Err("render output must be 3 (RGB)".into());
        }
        let slopes = [
            self.slopes.ha,
            self.slopes.nd_enc,
            self.slopes.render_hidden,
            self.slopes.render_out,
        ];
        if slopes.iter().any(|s| !s.is_finite()) {
            return Err("slopes must be finite".into());
        }
        if !(self.norm_eps.is_finite() && self.norm_eps > 0.0) {
            return Err(format!("norm_eps {} must be finite and > 0", self.norm_eps));
        }
        if !self.bn_folded {
            return Err("bn_folded is false; export with BatchNorm folded".into());
        }
        Ok(())
    }
}
