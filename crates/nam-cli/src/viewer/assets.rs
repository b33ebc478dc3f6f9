//! The page's files, embedded at build time: the only paths the server answers outside
//! `/api/` (no file-system access, so no path can escape). The WGSL files are the project's
//! own render shaders (`shaders/`), which the page runs when the browser has WebGPU.

/// One embedded file.
#[derive(Debug)]
pub struct Asset {
    /// URL path.
    pub path: &'static str,
    /// `Content-Type` header value.
    pub content_type: &'static str,
    /// The file.
    pub body: &'static str,
}

/// Every static path the server answers.
pub const ASSETS: &[Asset] = &[
    Asset {
        path: "/",
        content_type: "text/html; charset=utf-8",
        body: include_str!("../../web/index.html"),
    },
    Asset {
        path: "/viewer.css",
        content_type: "text/css; charset=utf-8",
        body: include_str!("../../web/viewer.css"),
    },
    Asset {
        path: "/viewer.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_str!("../../web/viewer.js"),
    },
    Asset {
        path: "/webgpu.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_str!("../../web/webgpu.js"),
    },
    Asset {
        path: "/shaders/pos_enc.wgsl",
        content_type: "text/plain; charset=utf-8",
        body: include_str!("../../../../shaders/pos_enc.wgsl"),
    },
    Asset {
        path: "/shaders/matmul.wgsl",
        content_type: "text/plain; charset=utf-8",
        body: include_str!("../../../../shaders/matmul.wgsl"),
    },
];

/// The asset at `path` (`/index.html` is `/`).
pub fn find(path: &str) -> Option<&'static Asset> {
    let path = if path == "/index.html" { "/" } else { path };
    ASSETS.iter().find(|a| a.path == path)
}
