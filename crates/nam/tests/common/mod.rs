//! Helpers shared by the facade's integration tests.

use nam::Photo;

/// The real flash photos of `../shared/real_photos` (sorted by name), or `None` with a printed
/// reason when `shared/` is not beside the checkout. They are read from there, never copied
/// into the repository (no licence to redistribute).
pub fn real_photos() -> Option<Vec<(String, Photo)>> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/real_photos");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        eprintln!(
            "SKIP: no real photos at {} (shared/ is not beside the checkout)",
            dir.display()
        );
        return None;
    };
    let mut paths: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    paths.sort();
    if paths.is_empty() {
        eprintln!("SKIP: {} holds no PNG photos", dir.display());
        return None;
    }
    Some(
        paths
            .into_iter()
            .map(|p| {
                let name = p
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                (name, Photo::load(&p).unwrap_or_else(|e| panic!("{e}")))
            })
            .collect(),
    )
}
