//! The on-disk artifact cache.
//!
//! Layout: `ROOT/<stage>/<hex key>.<ext>` data files (`bin` full artifact, `sum` small summary,
//! `png` heat map, ...) plus `ROOT/<stage>/<hex key>.json`, the manifest, written last: an entry
//! without a manifest is incomplete and ignored by `ls` and removed by `gc`. Every write goes to a
//! temporary file in the same directory, is fsynced and then renamed, so a crash or a concurrent
//! run never leaves a half-written artifact under a real name. A file that fails its checksum is
//! moved to `ROOT/quarantine/` and treated as missing (it will be recomputed, never used).
use crate::codec;
use crate::error::{Error, Result};
use crate::key::Key;
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// What produced an artifact, stored beside it as JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub key: String,
    pub stage: String,
    pub version: u32,
    pub params: BTreeMap<String, String>,
    /// Input stage keys, `stage:hex`.
    pub inputs: Vec<String>,
    /// Data files of this entry: extension -> blake3 hex of the file bytes.
    pub files: BTreeMap<String, String>,
    /// Software versions: bvhlab, artifact format.
    pub versions: BTreeMap<String, String>,
    pub machine: Machine,
    /// Seconds since the Unix epoch when the artifact was written.
    pub time_unix: u64,
    /// Wall seconds the stage took to compute (all repeats included).
    pub compute_seconds: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    pub hostname: String,
    pub os: String,
    pub arch: String,
    pub cpus: usize,
    /// Rayon threads the stage ran with.
    pub threads: usize,
}

impl Machine {
    pub fn current() -> Machine {
        let hostname = fs::read_to_string("/etc/hostname")
            .map(|s| s.trim().to_string())
            .ok()
            .filter(|s| !s.is_empty())
            .or_else(|| std::env::var("HOSTNAME").ok())
            .unwrap_or_else(|| "unknown".into());
        Machine {
            hostname,
            os: std::env::consts::OS.into(),
            arch: std::env::consts::ARCH.into(),
            cpus: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            threads: rayon::current_num_threads(),
        }
    }
}

pub fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

/// `--cache DIR` > `BVHLAB_CACHE` > `./cache`.
pub fn resolve_root(cli: Option<&Path>) -> PathBuf {
    if let Some(p) = cli {
        return p.to_path_buf();
    }
    match std::env::var_os("BVHLAB_CACHE") {
        Some(v) if !v.is_empty() => PathBuf::from(v),
        _ => PathBuf::from("cache"),
    }
}

pub struct Store {
    root: PathBuf,
    /// Removed on drop (`--no-cache`).
    temporary: bool,
}

impl Drop for Store {
    fn drop(&mut self) {
        if self.temporary {
            let _ = fs::remove_dir_all(&self.root);
        }
    }
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

fn io_err(what: &str, path: &Path, e: std::io::Error) -> Error {
    Error::internal(format!("{what} {}: {e}", path.display()))
}

#[derive(Debug, Default, Clone, Serialize)]
pub struct VerifyReport {
    pub entries: u64,
    pub files_ok: u64,
    /// `path: reason` of every bad file (moved to quarantine).
    pub bad: Vec<String>,
}

#[derive(Debug, Default, Clone, Serialize)]
pub struct GcReport {
    pub removed_files: u64,
    pub removed_bytes: u64,
}

impl Store {
    pub fn open(root: impl Into<PathBuf>) -> Result<Store> {
        let root = root.into();
        fs::create_dir_all(&root).map_err(|e| io_err("cannot create cache dir", &root, e))?;
        Ok(Store {
            root,
            temporary: false,
        })
    }

    /// A throw-away store in the system temp dir, deleted when dropped.
    pub fn temporary() -> Result<Store> {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let root =
            std::env::temp_dir().join(format!("bvhlab-nocache-{}-{nanos}", std::process::id()));
        let mut s = Store::open(root)?;
        s.temporary = true;
        Ok(s)
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn path(&self, stage: &str, key: &Key, ext: &str) -> PathBuf {
        self.root.join(stage).join(format!("{}.{ext}", key.hex()))
    }

    /// Reads and verifies an artifact. Missing => None; corrupt => quarantined and None.
    pub fn get<T: DeserializeOwned>(&self, stage: &str, key: &Key, ext: &str) -> Option<T> {
        let path = self.path(stage, key, ext);
        let bytes = fs::read(&path).ok()?;
        match codec::decode(&bytes) {
            Ok(v) => Some(v),
            Err(reason) => {
                eprintln!(
                    "warning: corrupt cache artifact {}: {reason}; recomputing",
                    path.display()
                );
                self.quarantine(&path);
                None
            }
        }
    }

    /// Whether an entry is complete (manifest present).
    pub fn has_manifest(&self, stage: &str, key: &Key) -> bool {
        self.path(stage, key, "json").is_file()
    }

    pub fn quarantine(&self, path: &Path) {
        let q = self.root.join("quarantine");
        let _ = fs::create_dir_all(&q);
        let stage = path
            .parent()
            .and_then(|p| p.file_name())
            .map(|s| s.to_string_lossy().to_string());
        let name = path
            .file_name()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        let target = q.join(format!(
            "{}.{name}.{}",
            stage.unwrap_or_default(),
            now_unix()
        ));
        if fs::rename(path, &target).is_err() {
            let _ = fs::remove_file(path);
        }
    }

    /// Writes `bytes` atomically to `path` (temp file in the same dir, fsync, rename).
    pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
        Self::write_atomic_with(path, |tmp| fs::write(tmp, bytes).map_err(|e| e.to_string()))
    }

    /// Lets `write` produce the file at a temporary path, then fsyncs and renames it into place.
    pub fn write_atomic_with(
        path: &Path,
        write: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<()> {
        let dir = path
            .parent()
            .ok_or_else(|| Error::internal(format!("no parent dir: {}", path.display())))?;
        fs::create_dir_all(dir).map_err(|e| io_err("cannot create", dir, e))?;
        let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        let name = path
            .file_name()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_default();
        // Keep the real extension last: some writers (PNG) pick the format from it.
        let tmp = dir.join(format!(".tmp-{}-{n}-{name}", std::process::id()));
        let result = (|| {
            write(&tmp)
                .map_err(|e| Error::internal(format!("cannot write {}: {e}", tmp.display())))?;
            let f = fs::OpenOptions::new()
                .write(true)
                .open(&tmp)
                .map_err(|e| io_err("cannot open", &tmp, e))?;
            f.sync_all().map_err(|e| io_err("cannot fsync", &tmp, e))?;
            drop(f);
            fs::rename(&tmp, path).map_err(|e| io_err("cannot rename into", path, e))
        })();
        if result.is_err() {
            let _ = fs::remove_file(&tmp);
        } else if let Ok(d) = fs::File::open(dir) {
            let _ = d.sync_all();
        }
        result
    }

    /// Encodes and writes one data file; returns the blake3 hex of the written bytes.
    pub fn put<T: Serialize>(
        &self,
        stage: &str,
        key: &Key,
        ext: &str,
        value: &T,
    ) -> Result<String> {
        let bytes = codec::encode(value).map_err(Error::internal)?;
        Self::write_atomic(&self.path(stage, key, ext), &bytes)?;
        Ok(blake3::hash(&bytes).to_hex().to_string())
    }

    /// Writes the manifest, which completes the entry. Call after every data file is in place.
    pub fn commit(&self, manifest: &Manifest) -> Result<()> {
        let key =
            Key::from_hex(&manifest.key).ok_or_else(|| Error::internal("bad manifest key"))?;
        let json =
            serde_json::to_vec_pretty(manifest).map_err(|e| Error::internal(e.to_string()))?;
        Self::write_atomic(&self.path(&manifest.stage, &key, "json"), &json)
    }

    pub fn read_manifest(&self, stage: &str, key: &Key) -> Option<Manifest> {
        let bytes = fs::read(self.path(stage, key, "json")).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    fn stage_dirs(&self) -> Vec<PathBuf> {
        let mut dirs: Vec<PathBuf> = fs::read_dir(&self.root)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.is_dir() && p.file_name().is_some_and(|n| n != "quarantine"))
            .collect();
        dirs.sort();
        dirs
    }

    fn files(dir: &Path) -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = fs::read_dir(dir)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .collect();
        v.sort();
        v
    }

    /// All complete entries (manifests), sorted by stage then key.
    pub fn entries(&self) -> Vec<Manifest> {
        let mut out = Vec::new();
        for dir in self.stage_dirs() {
            for f in Self::files(&dir) {
                if f.extension().is_some_and(|e| e == "json") {
                    if let Some(m) = fs::read(&f)
                        .ok()
                        .and_then(|b| serde_json::from_slice::<Manifest>(&b).ok())
                    {
                        out.push(m);
                    }
                }
            }
        }
        out
    }

    /// Checks every file listed by every manifest against its recorded blake3 (and codec
    /// checksums for artifacts). Bad files are quarantined (and so recomputed on the next run).
    pub fn verify(&self) -> VerifyReport {
        let mut r = VerifyReport::default();
        for m in self.entries() {
            r.entries += 1;
            let Some(key) = Key::from_hex(&m.key) else {
                r.bad.push(format!("{}/{}.json: bad key", m.stage, m.key));
                continue;
            };
            for (ext, want) in &m.files {
                let path = self.path(&m.stage, &key, ext);
                let problem = match fs::read(&path) {
                    Err(e) => Some(format!("unreadable: {e}")),
                    Ok(bytes) => {
                        if blake3::hash(&bytes).to_hex().as_str() != want {
                            Some("blake3 differs from manifest".to_string())
                        } else if ext == "bin" || ext == "sum" {
                            codec::verify(&bytes).err()
                        } else {
                            None
                        }
                    }
                };
                match problem {
                    None => r.files_ok += 1,
                    Some(p) => {
                        r.bad.push(format!("{}: {p}", path.display()));
                        if path.exists() {
                            self.quarantine(&path);
                        }
                    }
                }
            }
        }
        r
    }

    /// Removes temporary files, quarantined files and files of incomplete entries (no manifest).
    pub fn gc(&self) -> GcReport {
        let mut r = GcReport::default();
        let mut remove = |p: &Path| {
            let len = fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            if fs::remove_file(p).is_ok() {
                r.removed_files += 1;
                r.removed_bytes += len;
            }
        };
        for f in Self::files(&self.root.join("quarantine")) {
            remove(&f);
        }
        let _ = fs::remove_dir(self.root.join("quarantine"));
        for dir in self.stage_dirs() {
            for f in Self::files(&dir) {
                let name = f
                    .file_name()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                if name.starts_with(".tmp-") {
                    remove(&f);
                    continue;
                }
                let stem = name.split('.').next().unwrap_or("");
                if !dir.join(format!("{stem}.json")).is_file() {
                    remove(&f);
                }
            }
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(n: u8) -> Key {
        Key([n; 32])
    }

    fn manifest(stage: &str, k: &Key, files: BTreeMap<String, String>) -> Manifest {
        Manifest {
            key: k.hex(),
            stage: stage.into(),
            version: 1,
            params: BTreeMap::new(),
            inputs: vec![],
            files,
            versions: BTreeMap::new(),
            machine: Machine::current(),
            time_unix: now_unix(),
            compute_seconds: 0.0,
        }
    }

    #[test]
    fn put_get_verify_gc() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        let k = key(1);
        assert_eq!(s.get::<Vec<u32>>("build", &k, "bin"), None);
        let h = s.put("build", &k, "bin", &vec![1u32, 2, 3]).unwrap();
        s.commit(&manifest("build", &k, [("bin".to_string(), h)].into()))
            .unwrap();
        assert_eq!(s.get::<Vec<u32>>("build", &k, "bin"), Some(vec![1, 2, 3]));
        assert_eq!(s.entries().len(), 1);
        let v = s.verify();
        assert_eq!((v.entries, v.files_ok, v.bad.len()), (1, 1, 0));

        // An orphan (no manifest) and a temp file are garbage.
        s.put("build", &key(2), "bin", &5u8).unwrap();
        fs::write(dir.path().join("build").join(".tmp-1-0-x.bin"), b"x").unwrap();
        let g = s.gc();
        assert_eq!(g.removed_files, 2);
        assert!(s.path("build", &k, "bin").is_file());
        assert!(!s.path("build", &key(2), "bin").exists());
    }

    #[test]
    fn corrupt_file_is_quarantined_not_used() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        let k = key(3);
        let h = s.put("load", &k, "bin", &vec![9u64; 100]).unwrap();
        s.commit(&manifest("load", &k, [("bin".to_string(), h)].into()))
            .unwrap();
        let p = s.path("load", &k, "bin");
        let mut b = fs::read(&p).unwrap();
        let last = b.len() - 1;
        b[last] ^= 1;
        fs::write(&p, b).unwrap();
        let v = s.verify();
        assert_eq!(v.bad.len(), 1);
        assert!(!p.exists(), "verify quarantines the bad file");
        assert_eq!(s.get::<Vec<u64>>("load", &k, "bin"), None);
        assert_eq!(
            fs::read_dir(dir.path().join("quarantine")).unwrap().count(),
            1
        );
    }

    #[test]
    fn get_quarantines_corrupt() {
        let dir = tempfile::tempdir().unwrap();
        let s = Store::open(dir.path()).unwrap();
        let k = key(4);
        s.put("load", &k, "sum", &"abc".to_string()).unwrap();
        let p = s.path("load", &k, "sum");
        fs::write(&p, b"garbage").unwrap();
        assert_eq!(s.get::<String>("load", &k, "sum"), None);
        assert!(!p.exists());
    }

    #[test]
    fn temporary_store_is_removed() {
        let root;
        {
            let s = Store::temporary().unwrap();
            root = s.root().to_path_buf();
            s.put("x", &key(5), "bin", &1u8).unwrap();
            assert!(root.is_dir());
        }
        assert!(!root.exists());
    }

    #[test]
    fn root_resolution_prefers_cli() {
        assert_eq!(resolve_root(Some(Path::new("/a/b"))), PathBuf::from("/a/b"));
    }
}
