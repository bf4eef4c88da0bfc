//! Small file helpers: write to a temporary sibling and rename, so a crashed or failed run never
//! leaves a half-written file under the final name; file-name sanitizing.
use std::collections::HashSet;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Temporary sibling that keeps the extension (plotters and image pick the format from it).
pub fn tmp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".tmp-{}-{name}", std::process::id()))
}

pub fn commit(tmp: &Path, path: &Path) -> Result<(), String> {
    std::fs::rename(tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(tmp);
        format!("{}: cannot rename from {}: {e}", path.display(), tmp.display())
    })
}

pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&mut File) -> Result<(), String>,
) -> Result<(), String> {
    let tmp = tmp_path(path);
    let res = (|| {
        let mut f = File::create(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
        write(&mut f).map_err(|e| format!("{}: {e}", path.display()))?;
        f.flush().map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(())
    })();
    match res {
        Ok(()) => commit(&tmp, path),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), String> {
    write_atomic_with(path, |f| f.write_all(bytes).map_err(|e| e.to_string()))
}

pub fn copy_atomic(from: &Path, to: &Path) -> Result<(), String> {
    let bytes = std::fs::read(from).map_err(|e| format!("{}: {e}", from.display()))?;
    write_atomic(to, &bytes)
}

/// File-name-safe form of a label: ASCII alphanumerics, `-` and `_` kept, runs of anything else
/// become one `_`.
pub fn sanitize(label: &str) -> String {
    let mut out = String::new();
    let mut last_replaced = false;
    for c in label.chars() {
        if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
            out.push(c);
            last_replaced = false;
        } else if !last_replaced {
            out.push('_');
            last_replaced = true;
        }
    }
    let out = out.trim_matches('_').to_string();
    if out.is_empty() {
        "x".to_string()
    } else {
        out
    }
}

/// Hands out unique file stems: a second `foo` becomes `foo_2`.
#[derive(Default)]
pub struct Stems(HashSet<String>);

impl Stems {
    pub fn unique(&mut self, label: &str) -> String {
        let base = sanitize(label);
        let mut stem = base.clone();
        let mut n = 2;
        while !self.0.insert(stem.clone()) {
            stem = format!("{base}_{n}");
            n += 1;
        }
        stem
    }
}
