//! Routing and the API of the viewer. Every `/api/` request needs `t=<token>`.
//!
//! | request | answer |
//! |---|---|
//! | `GET /api/state` | JSON: the material (name, size, generation, photo or not), model, limits |
//! | `GET /api/photo` | the photo as the estimator saw it, 8-bit sRGB PNG |
//! | `GET /api/frame?light=x,y,z&view=x,y,z[&directional=1][&ortho=1][&intensity=I][&falloff=1][&preview=1][&fmt=rgb8\|f32\|png]` | the relit material (`preview`: at half resolution, [`Source::preview`]): `rgb8` raw 8-bit sRGB (H·W·3 bytes), `f32` raw linear radiance (H·W·3 little-endian), `png`; headers `X-Nam-Width`, `X-Nam-Height`, `X-Nam-Render-Ms`, `X-Nam-Path`, `X-Nam-Generation`, `X-Nam-Preview` |
//! | `GET /api/params` | the latent map, f32 little-endian `[H, W, param_channels]` (for WebGPU) |
//! | `GET /api/net`, `GET /api/weights` | `M_render`'s layers (JSON) and their weights, f32 little-endian, concatenated in that order (for WebGPU) |
//! | `POST /api/estimate[?fov=deg][&name=file]` | body: a PNG/JPEG/EXR photo; estimates it and makes it the current material; answers the new state |
//!
//! Errors are JSON `{"error": "…"}` with a 4xx status (5xx only if relighting itself fails).

use super::query::Query;
use super::{Current, MAX_UPLOAD_BYTES, Source, State, assets, fit};
use crate::args::parse_fov;
use crate::cmd::relight::{PhotoArgs, load_photo, make_scene};
use nam::geometry::{CAPTURE_DISTANCE, CAPTURE_FOV_DEG, capture_distance};
use nam::{BackendKind, Photo, RgbImage, Scene};
use nam_ggx::color::srgb_encode;
use nam_ggx::geometry::{Light, View};
use nam_ggx::imageio::{PngDepth, encode_png, quantize8};
use serde_json::json;
use std::io::Read;
use std::sync::Arc;
use std::time::Instant;
use tiny_http::{Header, Method, Request, Response};

/// An answer before it is sent.
#[derive(Debug)]
struct Reply {
    status: u16,
    content_type: &'static str,
    body: Vec<u8>,
    headers: Vec<(&'static str, String)>,
}

impl Reply {
    fn ok(content_type: &'static str, body: Vec<u8>) -> Self {
        Self {
            status: 200,
            content_type,
            body,
            headers: Vec::new(),
        }
    }

    fn json(value: &serde_json::Value) -> Self {
        Self::ok("application/json", value.to_string().into_bytes())
    }

    fn error(status: u16, message: impl Into<String>) -> Self {
        Self {
            status,
            ..Self::json(&json!({ "error": message.into() }))
        }
    }

    fn header(mut self, name: &'static str, value: impl ToString) -> Self {
        self.headers.push((name, value.to_string()));
        self
    }
}

/// Answers one request (on a worker thread); a failed send (the page went away) is ignored.
pub(super) fn answer(state: &State, port: u16, mut request: Request) {
    let reply = route(state, port, &mut request);
    // Always a Content-Length (tiny_http switches to chunked bodies above 32 KiB otherwise).
    let mut response = Response::from_data(reply.body)
        .with_status_code(reply.status)
        .with_chunked_threshold(usize::MAX);
    let fixed = [
        ("Content-Type", reply.content_type.to_string()),
        ("Cache-Control", "no-store".into()),
        ("X-Content-Type-Options", "nosniff".into()),
        ("Referrer-Policy", "no-referrer".into()),
        (
            "Content-Security-Policy",
            "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; \
             frame-ancestors 'none'"
                .into(),
        ),
    ];
    for (name, value) in fixed.into_iter().chain(reply.headers) {
        if let Ok(h) = Header::from_bytes(name.as_bytes(), value.as_bytes()) {
            response.add_header(h);
        }
    }
    let _ = request.respond(response);
}

fn route(state: &State, port: u16, request: &mut Request) -> Reply {
    if !host_is_loopback(request, port) {
        return Reply::error(
            403,
            "this viewer answers only http://127.0.0.1 on its own port",
        );
    }
    let url = request.url().to_string();
    let q = Query::parse(&url);
    let method = request.method().clone();
    if !q.path.starts_with("/api/") {
        return match (method, assets::find(q.path)) {
            (Method::Get | Method::Head, Some(a)) => {
                Reply::ok(a.content_type, a.body.as_bytes().to_vec())
            }
            (_, Some(_)) => Reply::error(405, "static files answer GET only"),
            (_, None) => Reply::error(404, format!("no such page: {}", shorten(q.path))),
        };
    }
    if q.get("t") != Some(state.token.as_str()) {
        return Reply::error(403, "missing or wrong token: open the URL nam-cli printed");
    }
    let result = match (method, q.path) {
        (Method::Get, "/api/state") => Ok(Reply::json(&state_json(state))),
        (Method::Get, "/api/photo") => photo(state),
        (Method::Get, "/api/frame") => frame(state, &q),
        (Method::Get, "/api/params") => params(state),
        (Method::Get, "/api/net") => net(state),
        (Method::Get, "/api/weights") => weights(state),
        (Method::Post, "/api/estimate") => estimate(state, &q, request),
        (_, "/api/state" | "/api/photo" | "/api/frame" | "/api/params" | "/api/net")
        | (_, "/api/weights" | "/api/estimate") => Err(Reply::error(405, "wrong method")),
        (_, path) => Err(Reply::error(404, format!("no such API: {}", shorten(path)))),
    };
    result.unwrap_or_else(|e| e)
}

/// Whether the `Host` header names the loopback address on our port (a page on another
/// origin that rebinds its DNS name to 127.0.0.1 sends its own name and is refused).
fn host_is_loopback(request: &Request, port: u16) -> bool {
    let allowed = [format!("127.0.0.1:{port}"), format!("localhost:{port}")];
    request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Host"))
        .is_some_and(|h| {
            allowed
                .iter()
                .any(|a| h.value.as_str().eq_ignore_ascii_case(a))
        })
}

/// At most 60 characters of a path, for messages.
fn shorten(path: &str) -> String {
    path.chars().take(60).collect()
}

fn current(state: &State) -> Current {
    state
        .current
        .read()
        .map_or_else(|p| p.into_inner().clone(), |c| c.clone())
}

fn source(state: &State) -> Result<(u64, Arc<Source>), Reply> {
    let c = current(state);
    c.source.map(|s| (c.generation, s)).ok_or_else(|| {
        Reply::error(
            409,
            "no material yet: drop a photo on the page (or start nam-cli view with one)",
        )
    })
}

fn state_json(state: &State) -> serde_json::Value {
    let c = current(state);
    let model = &state.model;
    let material = c.source.as_ref().map(|s| {
        let (h, w) = s.material.size();
        json!({
            "name": s.name,
            "width": w,
            "height": h,
            "has_photo": s.photo.is_some(),
            "fov": s.fov,
            "capture_distance": capture_distance(s.fov),
        })
    });
    json!({
        "generation": c.generation,
        "material": material,
        "model": {
            "fingerprint": model.fingerprint(),
            "width": model.config().width,
            "param_channels": model.config().param_channels,
            "backend": match model.backend() { BackendKind::Cpu => "cpu", BackendKind::Gpu => "gpu" },
        },
        "default_fov": CAPTURE_FOV_DEG,
        // Where a point light gives radiance 1 (the `falloff` reference, DESIGN §3).
        "unit_light_distance": CAPTURE_DISTANCE,
        "max_side": state.max_side,
        "max_upload_bytes": MAX_UPLOAD_BYTES,
    })
}

fn photo(state: &State) -> Result<Reply, Reply> {
    let (_, s) = source(state)?;
    let photo = s
        .photo
        .as_ref()
        .ok_or_else(|| Reply::error(404, "this material was loaded from a .nam file: no photo"))?;
    let side = photo.side();
    let img = RgbImage::from_vec(side, side, photo.rgb().to_vec())
        .map_err(|e| Reply::error(500, e.to_string()))?;
    let png = encode_png(&img.map(srgb_encode), PngDepth::Eight)
        .map_err(|e| Reply::error(500, e.to_string()))?;
    Ok(Reply::ok("image/png", png))
}

/// Which pipeline renders `scene` (DESIGN §9: a directional light with an orthographic view
/// runs ND_enc once per frame).
fn path_label(state: &State, scene: &Scene) -> String {
    let device = match state.model.backend() {
        BackendKind::Cpu => "server CPU",
        BackendKind::Gpu => "server GPU",
    };
    let fast = matches!(
        (scene.light, scene.view),
        (Light::Directional(_), View::Orthographic(_))
    );
    if fast {
        format!("{device}, directional fast path (ND_enc once per frame)")
    } else {
        format!("{device}, general path (ND_enc per pixel)")
    }
}

fn frame(state: &State, q: &Query<'_>) -> Result<Reply, Reply> {
    let bad = |e: String| Reply::error(400, e);
    let light = q.vec3("light").map_err(bad)?;
    let view = q.vec3("view").map_err(bad)?;
    let directional = q.flag("directional").map_err(bad)?;
    let ortho = q.flag("ortho").map_err(bad)?;
    let intensity = q.non_negative("intensity", 1.0).map_err(bad)?;
    let falloff = q.flag("falloff").map_err(bad)?;
    let fmt = q.choice("fmt", &["rgb8", "f32", "png"]).map_err(bad)?;
    let preview = q.flag("preview").map_err(bad)?;
    let scene = make_scene((light, directional), (view, ortho), (intensity, falloff))
        .map_err(|e| Reply::error(400, format!("{e:#}")))?;
    let (generation, s) = source(state)?;
    let started = Instant::now();
    let material = if preview {
        s.preview()
            .map_err(|e| Reply::error(500, format!("{e:#}")))?
    } else {
        &s.material
    };
    let img = nam::relight(&state.model, material, &scene)
        .map_err(|e| Reply::error(500, format!("relighting failed: {e}")))?;
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let body = match fmt {
        "f32" => img.data().iter().flat_map(|v| v.to_le_bytes()).collect(),
        "png" => encode_png(&img.map(srgb_encode), PngDepth::Eight)
            .map_err(|e| Reply::error(500, e.to_string()))?,
        _ => img
            .data()
            .iter()
            .map(|&v| quantize8(srgb_encode(v)))
            .collect(),
    };
    let content_type = if fmt == "png" {
        "image/png"
    } else {
        "application/octet-stream"
    };
    Ok(Reply::ok(content_type, body)
        .header("X-Nam-Width", img.width())
        .header("X-Nam-Height", img.height())
        .header("X-Nam-Render-Ms", format!("{ms:.2}"))
        .header("X-Nam-Path", path_label(state, &scene))
        .header("X-Nam-Generation", generation)
        .header("X-Nam-Preview", u8::from(preview)))
}

fn params(state: &State) -> Result<Reply, Reply> {
    let (generation, s) = source(state)?;
    let p = s.material.params();
    let body = p.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    Ok(Reply::ok("application/octet-stream", body)
        .header("X-Nam-Generation", generation)
        .header(
            "X-Nam-Shape",
            format!("{},{},{}", p.height, p.width, p.channels),
        ))
}

fn render_layers(state: &State) -> Result<nam::RenderLayers, Reply> {
    state
        .model
        .weights()
        .render_layers(true)
        .map_err(|e| Reply::error(500, e.to_string()))
}

fn net(state: &State) -> Result<Reply, Reply> {
    let layers = render_layers(state)?;
    let cfg = state.model.config();
    let describe = |ls: &[nam::LinearLayer]| -> Vec<serde_json::Value> {
        ls.iter()
            .map(|l| json!({ "name": l.name, "out": l.out, "inp": l.inp, "slope": l.slope }))
            .collect()
    };
    Ok(Reply::json(&json!({
        "param_channels": cfg.param_channels,
        "octaves": cfg.pe_octaves,
        "encoding": cfg.encoding_len(),
        "nd_enc": describe(&layers.nd_enc),
        "mlp": describe(&layers.mlp),
    })))
}

fn weights(state: &State) -> Result<Reply, Reply> {
    let layers = render_layers(state)?;
    let body = layers
        .nd_enc
        .iter()
        .chain(&layers.mlp)
        .flat_map(|l| l.weight.iter().flat_map(|v| v.to_le_bytes()))
        .collect();
    Ok(Reply::ok("application/octet-stream", body))
}

/// The image kind of an upload, from its first bytes: the file-name extension the loader needs.
fn sniff(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("png")
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("jpg")
    } else if bytes.starts_with(&[0x76, 0x2F, 0x31, 0x01]) {
        Some("exr")
    } else {
        None
    }
}

fn estimate(state: &State, q: &Query<'_>, request: &mut Request) -> Result<Reply, Reply> {
    let too_large = || {
        Reply::error(
            413,
            format!(
                "the photo is larger than {} MB; resize or recompress it",
                MAX_UPLOAD_BYTES >> 20
            ),
        )
    };
    if request.body_length().is_some_and(|n| n > MAX_UPLOAD_BYTES) {
        return Err(too_large());
    }
    let mut bytes = Vec::new();
    request
        .as_reader()
        .take(MAX_UPLOAD_BYTES as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Reply::error(400, format!("reading the upload: {e}")))?;
    if bytes.len() > MAX_UPLOAD_BYTES {
        return Err(too_large());
    }
    let fov = match q.get("fov") {
        None => CAPTURE_FOV_DEG,
        Some(v) => parse_fov(v).map_err(|e| Reply::error(400, format!("fov: {e}")))?,
    };
    let name: String = q
        .get("name")
        .filter(|n| {
            n.chars()
                .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c))
        })
        .unwrap_or("upload")
        .chars()
        .take(80)
        .collect();
    let ext = sniff(&bytes)
        .ok_or_else(|| Reply::error(415, format!("{name} is not a PNG, JPEG or EXR image")))?;
    let started = Instant::now();
    let (photo, how) = decode_upload(state, &bytes, ext, fov, &name)?;
    let material = how
        .estimate(&state.model, &photo)
        .map_err(|e| Reply::error(400, format!("{name}: {e:#}")))?;
    eprintln!(
        "viewer: estimated {name} ({0}×{0}) in {1:.1} s",
        photo.side(),
        started.elapsed().as_secs_f64()
    );
    let source = Source::new(name, material, Some(photo), fov);
    {
        let mut c = state
            .current
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        c.generation += 1;
        c.source = Some(Arc::new(source));
    }
    Ok(Reply::json(&state_json(state)))
}

/// Decodes an upload through the same loader as files (centre-cropped, fitted to
/// `--max-side`), with how it is estimated; its messages name the upload, not the temporary
/// file.
fn decode_upload(
    state: &State,
    bytes: &[u8],
    ext: &str,
    fov: f64,
    name: &str,
) -> Result<(Photo, PhotoArgs), Reply> {
    let internal = |e: std::io::Error| Reply::error(500, format!("staging the upload: {e}"));
    let mut file = tempfile::Builder::new()
        .prefix("nam-view-")
        .suffix(&format!(".{ext}"))
        .tempfile()
        .map_err(internal)?;
    std::io::Write::write_all(&mut file, bytes).map_err(internal)?;
    let how = PhotoArgs {
        crop: true,
        resize: None,
        fov,
        keep_clipped: state.keep_clipped,
    };
    let tmp = file.path().display().to_string();
    let photo = load_photo(&state.model, file.path(), &how)
        .and_then(|p| fit(p, state.max_side))
        .map_err(|e| Reply::error(400, format!("{e:#}").replace(&tmp, name)))?;
    Ok((photo, how))
}

#[cfg(test)]
mod tests {
    use super::sniff;

    #[test]
    fn uploads_are_recognised_by_their_magic_bytes() {
        assert_eq!(sniff(b"\x89PNG\r\n\x1a\n...."), Some("png"));
        assert_eq!(sniff(&[0xFF, 0xD8, 0xFF, 0xE0]), Some("jpg"));
        assert_eq!(sniff(&[0x76, 0x2F, 0x31, 0x01, 2]), Some("exr"));
        assert_eq!(sniff(b"GIF89a"), None);
        assert_eq!(sniff(b""), None);
    }
}
