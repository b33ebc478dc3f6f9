//! `nam-cli info`: what a model or material file holds.

use anyhow::{Context, Result};
use nam::{NeuralMaterial, NeuralModel};
use std::path::PathBuf;

/// Describe a model (.safetensors; default: the embedded one) or a material (.nam).
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  nam-cli info
  nam-cli info models/default.safetensors
  nam-cli info photo.nam")]
pub struct Args {
    /// Model (.safetensors) or material (.nam) file; default: the embedded model.
    pub file: Option<PathBuf>,
}

/// Runs the subcommand.
pub fn run(args: &Args) -> Result<()> {
    let Some(path) = &args.file else {
        print_model("embedded default model", &NeuralModel::embedded()?);
        return Ok(());
    };
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("nam"))
    {
        let m = NeuralMaterial::load(path)?;
        let (h, w) = m.size();
        println!("material      {}", path.display());
        println!(
            "size          {h}×{w} pixels × {} params",
            m.params().channels
        );
        println!("estimated by  model sha256 {}", m.model_fingerprint());
        if let Ok(model) = NeuralModel::embedded() {
            let same = model.fingerprint() == m.model_fingerprint();
            println!(
                "embedded      {}",
                if same {
                    "this material belongs to the embedded model"
                } else {
                    "not the embedded model: relight it with --model <that model>"
                }
            );
        }
        return Ok(());
    }
    let model = NeuralModel::from_file(path)
        .with_context(|| format!("reading the model {}", path.display()))?;
    let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    print_model(&format!("{} ({size} bytes)", path.display()), &model);
    Ok(())
}

fn print_model(label: &str, model: &NeuralModel) {
    let c = model.config();
    println!("model         {label}");
    println!("sha256        {}", model.fingerprint());
    println!("format        {} v{}", c.format, c.version);
    println!("stored dtype  {}", c.dtype);
    println!("parameters    {}", model.parameter_count());
    println!(
        "U-Net width   C = {} (input {} channels{})",
        c.width,
        c.in_channels,
        if c.input_skip {
            "; head also sees the input"
        } else {
            ""
        }
    );
    println!("latent        {} params per pixel", c.param_channels);
    println!(
        "log mode      {:?}; positional encoding {} octaves ({} values)",
        c.log_mode,
        c.pe_octaves,
        c.encoding_len()
    );
    println!("ND_enc        {}", widths(&c.nd_enc));
    println!("render MLP    {}", widths(&c.render));
    println!("BN folded     {}", c.bn_folded);
}

/// Layer widths, input first, as `297 → 594 → …`.
fn widths(layers: &[usize]) -> String {
    layers
        .iter()
        .map(|n| n.to_string())
        .collect::<Vec<_>>()
        .join(" → ")
}
