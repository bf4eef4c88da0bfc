//! The one atomic file write of the workspace (cache artifacts, manifests, report files): the
//! content goes to a temporary sibling, is fsynced, renamed over the final name, and the directory
//! is fsynced, so a crashed or failed run never leaves a half-written file under the final name.
//!
//! Temporary names are `.tmp-<pid>-<n>-h<host tag>-<name>`: the cache's gc (`store::writer_alive`)
//! and the report's `remove_stale_temps` read the writer's pid (and host) from them.
use crate::lockfile;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// A fresh temporary sibling of `path`. The real extension stays last: some writers (plotters,
/// image) pick the format from it.
pub fn tmp_path(path: &Path) -> PathBuf {
    let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let name = path
        .file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    path.with_file_name(format!(
        ".tmp-{}-{n}-h{}-{name}",
        std::process::id(),
        lockfile::host_tag()
    ))
}

/// Lets `write` produce the file at a temporary path, then fsyncs it, renames it into place and
/// fsyncs the directory. Creates the parent directory. An error of `write` comes back unchanged;
/// the others name the file. On error the temporary file is removed.
pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), String> {
    let dir = path
        .parent()
        .ok_or_else(|| format!("no parent dir: {}", path.display()))?;
    fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let tmp = tmp_path(path);
    let result = (|| {
        write(&tmp)?;
        let f = fs::OpenOptions::new()
            .write(true)
            .open(&tmp)
            .map_err(|e| format!("cannot open {}: {e}", tmp.display()))?;
        f.sync_all()
            .map_err(|e| format!("cannot fsync {}: {e}", tmp.display()))?;
        drop(f);
        fs::rename(&tmp, path).map_err(|e| format!("cannot rename into {}: {e}", path.display()))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    } else if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
    result
}

/// `write_atomic_with` for writers that take an open file.
pub fn write_atomic_file(
    path: &Path,
    write: impl FnOnce(&mut fs::File) -> Result<(), String>,
) -> Result<(), String> {
    write_atomic_with(path, |tmp| {
        let mut f = fs::File::create(tmp).map_err(|e| e.to_string())?;
        write(&mut f)?;
        f.flush().map_err(|e| e.to_string())
    })
}

/// Writes `bytes` atomically to `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), String> {
    write_atomic_with(path, |tmp| fs::write(tmp, bytes).map_err(|e| e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_replace_and_leave_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub").join("a.png");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"two");
        let err = write_atomic_with(&p, |_| Err("boom".into())).unwrap_err();
        assert!(err.contains("boom"), "{err}");
        assert_eq!(fs::read(&p).unwrap(), b"two");
        let names: Vec<_> = fs::read_dir(p.parent().unwrap()).unwrap().flatten().collect();
        assert_eq!(names.len(), 1);
        let t = tmp_path(&p);
        let t = t.file_name().unwrap().to_string_lossy();
        assert!(t.starts_with(&format!(".tmp-{}-", std::process::id())) && t.ends_with(".png"));
    }
}
