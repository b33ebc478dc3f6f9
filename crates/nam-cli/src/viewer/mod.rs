//! The browser viewer behind `nam-cli view`: a small HTTP server on 127.0.0.1 (tiny_http:
//! synchronous, a handful of small dependencies, no async runtime for a server that answers one
//! person's requests) serving the embedded page (`web/`, [`assets`]) and its API ([`api`]).
//!
//! Security: the socket is bound to the loopback address only; every API request must carry
//! the random token printed in the URL (`?t=…`); requests whose `Host` is not the loopback
//! address are refused (no DNS rebinding); static paths come from a fixed table of embedded
//! files, never from the file system; uploads are capped in bytes and pixels
//! ([`MAX_UPLOAD_BYTES`], [`MAX_UPLOAD_PIXELS`]).

mod api;
mod assets;
mod query;

use anyhow::{Context, Result, anyhow};
use nam::{NeuralMaterial, NeuralModel, Photo};
use nam_model::ParamMap;
use rand::Rng;
use std::sync::{Arc, OnceLock, RwLock};

/// Default for `--max-side`: photos are resampled to at most 256² (interactive frame rates on
/// a laptop CPU).
pub const DEFAULT_MAX_SIDE: usize = 256;
/// Smallest accepted `--max-side` (the U-Net pads to a multiple of 16; below 16 px there is
/// nothing to look at).
pub const MIN_SIDE: usize = 16;
/// Largest upload body accepted (bytes): a 48-megapixel JPEG is ~15 MB.
pub const MAX_UPLOAD_BYTES: usize = 32 << 20;
/// Worker threads answering requests (a frame may render while the page loads assets).
const WORKERS: usize = 4;

/// Options of the server.
#[derive(Debug, Clone)]
pub struct ViewerConfig {
    /// Port on 127.0.0.1 (0: any free one).
    pub port: u16,
    /// Photos larger than this are resampled to `max_side`².
    pub max_side: usize,
    /// Uploaded photos keep the network's own params where they clipped (`--keep-clipped`).
    pub keep_clipped: bool,
}

/// What is being viewed: a material, with the photo it was estimated from when there is one.
#[derive(Debug)]
pub struct Source {
    /// File name shown in the page.
    pub name: String,
    /// The estimated (or loaded) material.
    pub material: NeuralMaterial,
    /// The photo as the estimator saw it (after crop and resampling); `None` for a `.nam`.
    pub photo: Option<Photo>,
    /// Field of view of the capture camera, degrees (places the default viewer).
    pub fov: f64,
    /// The material at half resolution, built on first use ([`Source::preview`]).
    preview: OnceLock<NeuralMaterial>,
}

impl Source {
    /// A source; its preview is built when first asked for.
    pub fn new(name: String, material: NeuralMaterial, photo: Option<Photo>, fov: f64) -> Self {
        Self {
            name,
            material,
            photo,
            fov,
            preview: OnceLock::new(),
        }
    }

    /// The material at half resolution (each latent vector the mean of a 2×2 block; an odd
    /// last row or column averages what it has) for frames while the light is being dragged:
    /// a quarter of the pixels, so about 4× the frame rate of the general path. An
    /// approximation (the render MLP is not linear in its latents): the page labels it and
    /// renders the full frame when the drag ends.
    pub fn preview(&self) -> Result<&NeuralMaterial> {
        if let Some(p) = self.preview.get() {
            return Ok(p);
        }
        let half = half_resolution(&self.material)?;
        Ok(self.preview.get_or_init(|| half))
    }
}

/// 2×2 block means of a material's latent map.
fn half_resolution(material: &NeuralMaterial) -> Result<NeuralMaterial> {
    let p = material.params();
    let (h, w, c) = (p.height, p.width, p.channels);
    let (h2, w2) = (h.div_ceil(2), w.div_ceil(2));
    let mut data = vec![0.0f32; h2 * w2 * c];
    for i in 0..h2 {
        for j in 0..w2 {
            let rows = (2 * i)..(2 * i + 2).min(h);
            let cols = (2 * j)..(2 * j + 2).min(w);
            let n = (rows.len() * cols.len()) as f32;
            let out = &mut data[(i * w2 + j) * c..(i * w2 + j + 1) * c];
            for y in rows {
                for x in cols.clone() {
                    let src = &p.data[(y * w + x) * c..(y * w + x + 1) * c];
                    out.iter_mut().zip(src).for_each(|(o, v)| *o += v / n);
                }
            }
        }
    }
    let map = ParamMap {
        height: h2,
        width: w2,
        channels: c,
        data,
    };
    Ok(NeuralMaterial::new(
        map,
        material.model_fingerprint().to_string(),
    )?)
}

/// Shared state: the model, and the current source with a generation counter that the page
/// uses to notice a new material.
#[derive(Debug)]
struct State {
    model: NeuralModel,
    token: String,
    max_side: usize,
    keep_clipped: bool,
    current: RwLock<Current>,
}

#[derive(Debug, Clone)]
struct Current {
    generation: u64,
    source: Option<Arc<Source>>,
}

/// A bound server; [`Server::serve`] answers requests until the process ends.
pub struct Server {
    http: Arc<tiny_http::Server>,
    state: Arc<State>,
    port: u16,
}

impl std::fmt::Debug for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Server")
            .field("port", &self.port)
            .finish_non_exhaustive()
    }
}

impl Server {
    /// Binds 127.0.0.1:`config.port` and prepares the state; nothing is served yet.
    pub fn bind(model: NeuralModel, source: Option<Source>, config: &ViewerConfig) -> Result<Self> {
        let http = tiny_http::Server::http(("127.0.0.1", config.port))
            .map_err(|e| anyhow!("cannot listen on 127.0.0.1:{}: {e}", config.port))?;
        let port = http
            .server_addr()
            .to_ip()
            .map(|a| a.port())
            .context("the server has no IP address")?;
        let token: String = format!("{:032x}", rand::rng().random::<u128>());
        let state = State {
            model,
            token,
            max_side: config.max_side,
            keep_clipped: config.keep_clipped,
            current: RwLock::new(Current {
                generation: 1,
                source: source.map(Arc::new),
            }),
        };
        Ok(Self {
            http: Arc::new(http),
            state: Arc::new(state),
            port,
        })
    }

    /// The page's URL, token included.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}/?t={}", self.port, self.state.token)
    }

    /// Answers requests on [`WORKERS`] threads; returns only if the listener fails.
    pub fn serve(self) -> Result<()> {
        let workers: Vec<_> = (0..WORKERS)
            .map(|_| {
                let (http, state, port) =
                    (Arc::clone(&self.http), Arc::clone(&self.state), self.port);
                std::thread::spawn(move || {
                    for request in http.incoming_requests() {
                        api::answer(&state, port, request);
                    }
                })
            })
            .collect();
        for w in workers {
            w.join()
                .map_err(|_| anyhow!("a viewer worker thread panicked"))?;
        }
        Ok(())
    }
}

/// The photo resampled to `max_side`² when it is larger (the viewer's frames stay
/// interactive); otherwise unchanged.
pub fn fit(photo: Photo, max_side: usize) -> Result<Photo> {
    Ok(if photo.side() > max_side {
        photo.resized(max_side)?
    } else {
        photo
    })
}

#[cfg(test)]
mod tests {
    use super::half_resolution;
    use nam::NeuralMaterial;
    use nam_model::ParamMap;

    #[test]
    fn the_preview_averages_two_by_two_blocks_and_keeps_odd_edges() {
        // 3×3 pixels, 2 channels: value = 10·row + col in channel 0, 1 in channel 1.
        let data: Vec<f32> = (0..9)
            .flat_map(|k| [(10 * (k / 3) + k % 3) as f32, 1.0])
            .collect();
        let map = ParamMap {
            height: 3,
            width: 3,
            channels: 2,
            data,
        };
        let m = NeuralMaterial::new(map, "f".into()).unwrap_or_else(|e| panic!("{e}"));
        let half = half_resolution(&m).unwrap_or_else(|e| panic!("{e}"));
        let p = half.params();
        assert_eq!((p.height, p.width, p.channels), (2, 2, 2));
        // Blocks: {0,1,10,11} -> 5.5, {2,12} -> 7, {20,21} -> 20.5, {22} -> 22.
        let ch0: Vec<f32> = p.data.iter().step_by(2).copied().collect();
        assert_eq!(ch0, [5.5, 7.0, 20.5, 22.0]);
        assert!(
            p.data
                .iter()
                .skip(1)
                .step_by(2)
                .all(|&v| (v - 1.0).abs() < 1e-6)
        );
        assert_eq!(half.model_fingerprint(), "f");
    }
}
