//! Small file helpers: removal of temporaries a killed writer left behind, copying through the
//! pipeline's atomic write (`bvhlab_pipeline::atomic`), file-name sanitizing.
use bvhlab_pipeline::atomic::write_atomic;
use bvhlab_pipeline::lockfile::pid_alive;
use std::collections::HashSet;
use std::path::Path;

/// Removes the `.tmp-<pid>-*` files a killed writer left in `dir` and its immediate
/// subdirectories (the report's plots/ and heatmaps/): nothing else would ever remove them. Files
/// of a live writer (another report being written right now, or this process) are kept. Returns
/// how many were removed.
pub fn remove_stale_temps(dir: &Path) -> usize {
    let mut removed = 0;
    let mut dirs = vec![dir.to_path_buf()];
    if let Ok(rd) = std::fs::read_dir(dir) {
        dirs.extend(rd.flatten().map(|e| e.path()).filter(|p| p.is_dir()));
    }
    for d in dirs {
        let Ok(rd) = std::fs::read_dir(&d) else { continue };
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(rest) = name.strip_prefix(".tmp-") else { continue };
            let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
            // A name we cannot read a pid from was not written by us: leave it.
            let Some(pid) = pid else { continue };
            if pid != std::process::id() && !pid_alive(pid) && std::fs::remove_file(e.path()).is_ok() {
                removed += 1;
            }
        }
    }
    removed
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stale_temps_of_dead_writers_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let plots = dir.path().join("plots");
        std::fs::create_dir(&plots).unwrap();
        // A pid that cannot exist (above the kernel's pid_max limit of 2^22).
        let dead = 4_194_399u32;
        let me = std::process::id();
        for (d, name) in [
            (dir.path(), format!(".tmp-{dead}-index.html")),
            (plots.as_path(), format!(".tmp-{dead}-pareto.png")),
            (dir.path(), format!(".tmp-{me}-results.csv")),
            (dir.path(), ".tmp-notapid-x".to_string()),
            (dir.path(), "index.html".to_string()),
        ] {
            std::fs::write(d.join(name), b"").unwrap();
        }
        assert_eq!(remove_stale_temps(dir.path()), 2);
        assert!(!dir.path().join(format!(".tmp-{dead}-index.html")).exists());
        assert!(!plots.join(format!(".tmp-{dead}-pareto.png")).exists());
        for keep in [format!(".tmp-{me}-results.csv"), ".tmp-notapid-x".into(), "index.html".into()] {
            assert!(dir.path().join(&keep).exists(), "{keep}");
        }
    }
}
