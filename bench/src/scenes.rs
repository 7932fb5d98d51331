//! The scene files the benchmarks read: finding them, naming them in tables, parsing them.
//! Each benchmark builds its scenes itself, at its own size.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use tessera_tracer::{Limits, SceneDesc, parse};

/// `.ray` files named directly or found in the given directories, sorted.
pub fn scene_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for p in paths {
        anyhow::ensure!(
            p.exists(),
            "{}: no such file or folder (the default scenes are named from the repository's \
             root: run the benchmark there, or pass --scenes)",
            p.display()
        );
        if p.is_dir() {
            for e in std::fs::read_dir(p).with_context(|| format!("cannot list {}", p.display()))? {
                let path = e?.path();
                if path.extension().is_some_and(|x| x == "ray") {
                    files.push(path);
                }
            }
        } else {
            files.push(p.clone());
        }
    }
    files.sort();
    anyhow::ensure!(!files.is_empty(), "no .ray scenes found in {paths:?}");
    Ok(files)
}

/// A scene file's name in the tables: its file name without `.ray`.
pub fn scene_name(path: &Path) -> String {
    path.file_stem()
        .map_or("scene".into(), |s| s.to_string_lossy().to_string())
}

/// Reads and parses a scene file; a mistake is reported as `file:line:col: message`.
pub fn read_desc(path: &Path) -> Result<SceneDesc> {
    let src =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse(&src, &Limits::default())
        .map_err(|e| anyhow::anyhow!("{}", e.with_file(&path.display().to_string())))
}
