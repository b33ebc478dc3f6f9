//! `nam-cli view`: the real binary serving on port 0, driven over HTTP. Frames must equal the
//! facade's `relight`; bad requests get a 4xx and the server keeps serving.

mod common;

use common::{ok, s, small_photo, tmp};
use nam::geometry::{Light, View};
use nam::{DVec3, NeuralMaterial, NeuralModel, Photo, Scene, relight};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};

/// A served frame (f32) and the facade's relight of the same material and scene run the same
/// code on the same machine: they agree to f32 round-off (the server's material is estimated
/// by the binary, the reference by this test, from the same file).
const FRAME_REL_TOL: f32 = 1e-5;

/// The server process, killed when the test ends (pass or fail).
struct Viewer {
    child: Child,
    /// Its stdout, kept open (a closed pipe would fail the server's next print).
    _stdout: BufReader<std::process::ChildStdout>,
    port: u16,
    token: String,
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An HTTP answer.
#[derive(Debug)]
struct Answer {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Answer {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }

    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }

    fn floats(&self) -> Vec<f32> {
        self.body
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }
}

impl Viewer {
    fn start(args: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_nam-cli"))
            .arg("view")
            .args(args)
            .args(["--port", "0", "--backend", "cpu"])
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot run nam-cli view: {e}"));
        let stdout = child.stdout.take().unwrap_or_else(|| panic!("no stdout"));
        let mut line = String::new();
        let mut stdout = BufReader::new(stdout);
        stdout
            .read_line(&mut line)
            .unwrap_or_else(|e| panic!("{e}"));
        let url = line
            .trim()
            .strip_prefix("nam viewer: ")
            .unwrap_or_else(|| panic!("no URL printed: {line:?}"))
            .to_string();
        let rest = url
            .strip_prefix("http://127.0.0.1:")
            .unwrap_or_else(|| panic!("not a loopback URL: {url}"));
        let (port, token) = rest
            .split_once("/?t=")
            .unwrap_or_else(|| panic!("no token in {url}"));
        Self {
            port: port.parse().unwrap_or_else(|e| panic!("{e}: {url}")),
            token: token.to_string(),
            child,
            _stdout: stdout,
        }
    }

    /// Sends one request (`Host` = the loopback address unless `host` says otherwise).
    fn send(
        &self,
        method: &str,
        target: &str,
        host: Option<&str>,
        extra: &str,
        body: &[u8],
    ) -> Answer {
        let mut stream =
            TcpStream::connect(("127.0.0.1", self.port)).unwrap_or_else(|e| panic!("{e}"));
        let host = host.map_or_else(|| format!("127.0.0.1:{}", self.port), str::to_string);
        let head = format!(
            "{method} {target} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n{extra}Content-Length: {}\r\n\r\n",
            body.len()
        );
        stream
            .write_all(head.as_bytes())
            .unwrap_or_else(|e| panic!("{e}"));
        let _ = stream.write_all(body); // the server may answer (413) before reading it all
        let mut raw = Vec::new();
        stream
            .read_to_end(&mut raw)
            .unwrap_or_else(|e| panic!("{e}"));
        let split = raw
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .unwrap_or_else(|| panic!("no header end in {}", String::from_utf8_lossy(&raw)));
        let head = String::from_utf8_lossy(&raw[..split]).into_owned();
        let mut lines = head.lines();
        let status = lines
            .next()
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|c| c.parse().ok())
            .unwrap_or_else(|| panic!("bad status line in {head}"));
        let headers = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
            .collect();
        Answer {
            status,
            headers,
            body: raw[split + 4..].to_vec(),
        }
    }

    fn get(&self, target: &str) -> Answer {
        self.send("GET", target, None, "", &[])
    }

    /// `GET /api/{path}?t=token&{query}`.
    fn api(&self, path: &str, query: &str) -> Answer {
        self.get(&format!("/api/{path}?t={}&{query}", self.token))
    }

    fn post_photo(&self, query: &str, body: &[u8]) -> Answer {
        let target = format!("/api/estimate?t={}&{query}", self.token);
        self.send("POST", &target, None, "", body)
    }
}

fn assert_close(got: &[f32], want: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= FRAME_REL_TOL * w.abs().max(1e-3),
            "{what}: value {k}: served {g}, facade {w}"
        );
    }
}

#[test]
fn served_frames_equal_the_facade_and_bad_requests_get_4xx() {
    let dir = tmp();
    let photo = small_photo(dir.path(), 64);
    let viewer = Viewer::start(&[s(&photo)]);

    // The page and its assets; nothing else outside /api/.
    let page = viewer.get(&format!("/?t={}", viewer.token));
    assert_eq!(page.status, 200);
    assert!(page.text().contains("<title>nam viewer</title>"));
    for asset in [
        "/viewer.js",
        "/webgpu.js",
        "/viewer.css",
        "/shaders/matmul.wgsl",
        "/shaders/pos_enc.wgsl",
    ] {
        assert_eq!(viewer.get(asset).status, 200, "{asset}");
    }
    for path in [
        "/../Cargo.toml",
        "/shaders/../../Cargo.toml",
        "/etc/passwd",
        "/api/../viewer.js",
    ] {
        let a = viewer.get(path);
        assert!(matches!(a.status, 403 | 404), "{path}: {}", a.status);
        assert!(!a.text().contains("[workspace]"), "{path} leaked a file");
    }

    let state = viewer.api("state", "").json();
    let d = state["material"]["capture_distance"]
        .as_f64()
        .unwrap_or_else(|| panic!("no capture distance: {state}"));
    assert_eq!(state["material"]["width"], 64);
    assert_eq!(state["generation"], 1);

    // The facade's frames of the same photo.
    let model = NeuralModel::embedded().unwrap_or_else(|e| panic!("{e}"));
    let material = model
        .estimate(&Photo::load(&photo).unwrap_or_else(|e| panic!("{e}")))
        .unwrap_or_else(|e| panic!("{e}"));
    let facade = |scene: &Scene| {
        relight(&model, &material, scene)
            .unwrap_or_else(|e| panic!("{e}"))
            .data()
            .to_vec()
    };
    let point = viewer.api("frame", &format!("light=0.5,0.4,3&view=0,0,{d}&fmt=f32"));
    assert_eq!(point.status, 200, "{}", point.text());
    assert_eq!(point.header("X-Nam-Width"), Some("64"));
    assert!(
        point
            .header("X-Nam-Path")
            .is_some_and(|p| p.contains("general path"))
    );
    let scene = Scene::new(
        Light::Point(DVec3::new(0.5, 0.4, 3.0)),
        View::Point(DVec3::new(0.0, 0.0, d)),
    );
    assert_close(&point.floats(), &facade(&scene), "point light");

    let fast = viewer.api(
        "frame",
        "light=0.3,-0.2,1&directional=1&view=0,0,1&ortho=1&intensity=2&fmt=f32",
    );
    assert_eq!(fast.status, 200, "{}", fast.text());
    assert!(
        fast.header("X-Nam-Path")
            .is_some_and(|p| p.contains("directional fast path"))
    );
    let mut scene = Scene::new(
        Light::Directional(DVec3::new(0.3, -0.2, 1.0)),
        View::Orthographic(DVec3::new(0.0, 0.0, 1.0)),
    );
    scene.intensity = 2.0;
    assert_close(&fast.floats(), &facade(&scene), "directional light");

    let preview = viewer.api(
        "frame",
        &format!("light=0.5,0.4,3&view=0,0,{d}&preview=1&fmt=f32"),
    );
    assert_eq!(preview.status, 200, "{}", preview.text());
    assert_eq!(preview.header("X-Nam-Width"), Some("32"));
    assert_eq!(preview.header("X-Nam-Preview"), Some("1"));
    assert_eq!(preview.floats().len(), 32 * 32 * 3);
    assert!(preview.floats().iter().all(|v| v.is_finite() && *v >= 0.0));

    let rgb8 = viewer.api("frame", &format!("light=0.5,0.4,3&view=0,0,{d}"));
    assert_eq!(rgb8.body.len(), 64 * 64 * 3);
    let png = viewer.api("frame", &format!("light=0.5,0.4,3&view=0,0,{d}&fmt=png"));
    assert!(png.body.starts_with(b"\x89PNG"));
    assert!(viewer.api("photo", "").body.starts_with(b"\x89PNG"));
    let floats = |a: Answer| a.floats().len();
    assert_eq!(floats(viewer.api("params", "")), 64 * 64 * 64);
    let net = viewer.api("net", "").json();
    let layer_floats: u64 = ["nd_enc", "mlp"]
        .iter()
        .flat_map(|k| net[k].as_array().cloned().unwrap_or_default())
        .map(|l| l["out"].as_u64().unwrap_or(0) * l["inp"].as_u64().unwrap_or(0))
        .sum();
    assert_eq!(floats(viewer.api("weights", "")) as u64, layer_floats);

    // Bad requests: a clear 4xx each, never a crash.
    let no_token = viewer.get("/api/state");
    assert_eq!(no_token.status, 403);
    assert!(
        no_token.json()["error"]
            .as_str()
            .is_some_and(|e| e.contains("token"))
    );
    assert_eq!(viewer.get("/api/state?t=0123").status, 403);
    let rebind = viewer.send(
        "GET",
        &format!("/api/state?t={}", viewer.token),
        Some("evil.example:80"),
        "",
        &[],
    );
    assert_eq!(rebind.status, 403);
    for (query, needle) in [
        ("view=0,0,4", "missing light"),
        ("light=0,0,-1&view=0,0,4", "not above the surface"),
        ("light=1,2&view=0,0,4", "x,y,z"),
        ("light=0,0,4&view=0,0,4&fmt=gif", "fmt"),
        ("light=0,0,4&view=0,0,4&intensity=-2", "intensity"),
        ("light=nan,0,4&view=0,0,4", "light"),
        ("light=1e999,0,4&view=0,0,4", "light"),
    ] {
        let a = viewer.api("frame", query);
        assert_eq!(a.status, 400, "{query}: {}", a.text());
        let e = a.json()["error"].as_str().unwrap_or_default().to_string();
        assert!(e.contains(needle), "{query}: {e:?} lacks {needle:?}");
    }
    assert_eq!(viewer.api("nope", "").status, 404);
    assert_eq!(
        viewer
            .send(
                "POST",
                &format!("/api/frame?t={}", viewer.token),
                None,
                "",
                b"x"
            )
            .status,
        405
    );

    // Uploads: not an image, an image cut short, too large, then a good one.
    let gif = viewer.post_photo("name=a.gif", b"GIF89a....");
    assert_eq!(gif.status, 415, "{}", gif.text());
    let bytes = std::fs::read(&photo).unwrap_or_else(|e| panic!("{e}"));
    let cut = viewer.post_photo("name=cut.png", &bytes[..bytes.len() / 2]);
    assert_eq!(cut.status, 400, "{}", cut.text());
    assert!(
        cut.json()["error"]
            .as_str()
            .is_some_and(|e| e.contains("cut.png") && !e.contains("nam-view-"))
    );
    let huge = viewer.send(
        "POST",
        &format!("/api/estimate?t={}", viewer.token),
        None,
        "",
        &vec![0u8; (32 << 20) + 1],
    );
    assert_eq!(huge.status, 413, "{}", huge.text());
    let bad_fov = viewer.post_photo("fov=400", &bytes);
    assert_eq!(bad_fov.status, 400);
    let wide = small_photo(dir.path(), 48);
    let up = viewer.post_photo(
        "name=wide.png&fov=40",
        &std::fs::read(&wide).unwrap_or_else(|e| panic!("{e}")),
    );
    assert_eq!(up.status, 200, "{}", up.text());
    let state = up.json();
    assert_eq!(state["generation"], 2);
    assert_eq!(state["material"]["name"], "wide.png");
    assert_eq!(state["material"]["width"], 48);
    let after = viewer.api("frame", "light=0,0,3&view=0,0,3&fmt=f32");
    assert_eq!(
        after.status,
        200,
        "the server keeps serving: {}",
        after.text()
    );
    assert_eq!(after.floats().len(), 48 * 48 * 3);
    assert_eq!(after.header("X-Nam-Generation"), Some("2"));
}

#[test]
fn a_saved_material_is_viewed_without_a_photo_and_large_photos_are_fitted() {
    let dir = tmp();
    let photo = small_photo(dir.path(), 80);
    let nam_file = dir.path().join("m.nam");
    ok(&["estimate", s(&photo), "-o", s(&nam_file)]);
    let viewer = Viewer::start(&[s(&nam_file)]);
    let state = viewer.api("state", "").json();
    assert_eq!(state["material"]["has_photo"], false);
    assert_eq!(viewer.api("photo", "").status, 404);
    let saved = NeuralMaterial::load(&nam_file).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(saved.size(), (80, 80));
    let frame = viewer.api("frame", "light=0,1,3&view=0,0,4&fmt=f32");
    assert_eq!(frame.status, 200, "{}", frame.text());
    drop(viewer);

    // Started without a material: the page asks for a photo; frames say so.
    let viewer = Viewer::start(&[]);
    assert!(viewer.api("state", "").json()["material"].is_null());
    let none = viewer.api("frame", "light=0,0,3&view=0,0,3");
    assert_eq!(none.status, 409, "{}", none.text());
    assert!(none.text().contains("drop a photo"));
    drop(viewer);

    // --max-side resamples a larger photo before estimating it.
    let viewer = Viewer::start(&[s(&photo), "--max-side", "32"]);
    assert_eq!(viewer.api("state", "").json()["material"]["width"], 32);
    let o = common::run(&["view", s(&photo), "--max-side", "4"]);
    assert!(!o.status.success());
    assert!(common::stderr(&o).contains("--max-side 4"));
}
