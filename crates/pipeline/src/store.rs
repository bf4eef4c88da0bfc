//! The on-disk artifact cache.
//!
//! Layout: `ROOT/<stage>/<hex key>.<ext>` data files (`bin` full artifact, `sum` small summary,
//! `png` heat map, ...) plus `ROOT/<stage>/<hex key>.json`, the manifest, written last: an entry
//! without a manifest is incomplete and ignored by `ls` and removed by `gc`. Every write goes to a
//! temporary file in the same directory, is fsynced and then renamed, so a crash or a concurrent
//! run never leaves a half-written artifact under a real name (temporary files are named
//! `.tmp-<pid>-<n>-<name>`: readers never open them, `verify --repair` and `gc` remove those whose
//! writer process is gone). A data file is used only if its blake3 equals the one its manifest
//! records and the manifest names this stage and key (so a truncated, bit-flipped or foreign file,
//! e.g. a valid artifact of another key copied over this one, is rejected); the codec then checks
//! its own header checksum. A rejected file is moved to `ROOT/quarantine/` and recomputed.
//!
//! Concurrency: `ROOT/locks/<stage>/<key>.lock` are per-entry compute locks: exclusive lock files
//! with owner, host and heartbeat (`lockfile.rs`), which hold on NFS where `flock` may not; a lock
//! of a dead process is taken over (at once on its own host, after `BVHLAB_LOCK_STALE_SECS` of
//! silence from another host). A process computes an entry only while holding its lock and after
//! re-checking, under the lock, that no other process completed it meanwhile; see `run.rs`
//! (`cached`, `commit`) for the protocol and why it cannot deadlock. Temporary files carry their
//! writer's host tag, so cleanup judges a writer's liveness by `/proc` only on its own host.
use crate::atomic;
use crate::codec;
use crate::error::{Error, Result};
use crate::key::Key;
use crate::lockfile::{self, LockTiming};
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::collections::BTreeMap;
use std::collections::HashMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

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
    /// CPU model ("model name" of /proc/cpuinfo; else the architecture). Timings of different
    /// models are never combined without saying so (issue 12). Empty in manifests written before
    /// it was recorded: unknown.
    #[serde(default)]
    pub cpu_model: String,
}

/// This machine's CPU model, read once.
pub fn cpu_model() -> &'static str {
    static M: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    M.get_or_init(|| {
        fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|t| {
                t.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split_once(':'))
                    .map(|(_, v)| v.split_whitespace().collect::<Vec<_>>().join(" "))
            })
            .filter(|m| !m.is_empty())
            .unwrap_or_else(|| std::env::consts::ARCH.to_string())
    })
}

impl Machine {
    pub fn current() -> Machine {
        Machine {
            hostname: crate::lockfile::system_host_name(),
            os: std::env::consts::OS.into(),
            arch: std::env::consts::ARCH.into(),
            cpus: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            threads: rayon::current_num_threads(),
            cpu_model: cpu_model().to_string(),
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
    /// Compute locks this store holds, (stage, key) -> the lock's guard. Shared with `LockRelease`
    /// guards and the heartbeat thread; dropping a guard releases its lock.
    locks: HeldLocks,
    /// Owner token of this store's locks (unique per store, so two stores of one process exclude
    /// each other like two processes).
    token: String,
    lock_timing: LockTiming,
    heartbeat_started: Arc<AtomicBool>,
}

type HeldLocks = Arc<Mutex<HashMap<(String, Key), lockfile::Guard>>>;

/// Releases every compute lock of its store when dropped (end of a chain, also on error).
pub struct LockRelease(HeldLocks);

impl Drop for LockRelease {
    fn drop(&mut self) {
        if let Ok(mut m) = self.0.lock() {
            m.clear();
        }
    }
}

/// Whether the process that wrote a temporary file `.tmp-<pid>-<n>-h<host tag>-<name>` (or the
/// older `.tmp-<pid>-<n>-<name>`, taken as this host's) may still be writing it. Its own host:
/// `/proc/<pid>` exists. Another host (a shared cache), or no /proc: assume alive unless the file
/// is a day old.
fn writer_alive(name: &str, path: &Path) -> bool {
    let mut parts = name.strip_prefix(".tmp-").unwrap_or("").splitn(4, '-');
    let pid = parts.next().and_then(|p| p.parse::<u32>().ok());
    let Some(pid) = pid else { return false };
    let _n = parts.next();
    let host = parts
        .next()
        .and_then(|h| h.strip_prefix('h'))
        .filter(|h| h.len() == 8 && h.chars().all(|c| c.is_ascii_hexdigit()));
    let local = host.is_none_or(|h| h == lockfile::host_tag());
    if local && pid == std::process::id() {
        return true;
    }
    if local && Path::new("/proc/self").exists() {
        return lockfile::pid_alive(pid);
    }
    fs::metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.elapsed().ok())
        .is_none_or(|age| age.as_secs() < 86_400)
}

impl Drop for Store {
    fn drop(&mut self) {
        if self.temporary {
            let _ = fs::remove_dir_all(&self.root);
        }
    }
}

fn io_err(what: &str, path: &Path, e: std::io::Error) -> Error {
    Error::internal(format!("{what} {}: {e}", path.display()))
}

#[derive(Debug, Default, Clone, Serialize)]
pub struct VerifyReport {
    pub entries: u64,
    pub files_ok: u64,
    /// `path: reason` of every bad manifest or data file (quarantined when repairing).
    pub bad: Vec<String>,
    /// Temporary files of dead writers (a killed run): harmless, never read; removed when repairing.
    pub stale_temp: u64,
    /// Data files without a manifest (an entry a killed run did not finish): never read, removed by
    /// `gc`. Not an error either.
    pub incomplete: u64,
    /// Manifests rewritten without their bad files, or removed when no file was left (repair).
    pub manifests_fixed: u64,
    /// Entries skipped because another process holds their compute lock (repair only).
    pub busy: u64,
}

impl VerifyReport {
    /// No bad manifest or data file (stale temporaries and incomplete entries do not count).
    pub fn clean(&self) -> bool {
        self.bad.is_empty()
    }
}

#[derive(Debug, Default, Clone, Serialize)]
pub struct GcReport {
    pub removed_files: u64,
    pub removed_bytes: u64,
    /// Compute locks of dead processes (this host: pid gone) and leftovers of interrupted
    /// takeovers older than a day.
    pub removed_locks: u64,
}

impl Store {
    pub fn open(root: impl Into<PathBuf>) -> Result<Store> {
        let root = root.into();
        fs::create_dir_all(&root).map_err(|e| io_err("cannot create cache dir", &root, e))?;
        Ok(Store {
            root,
            temporary: false,
            locks: Arc::default(),
            token: lockfile::new_token(),
            lock_timing: LockTiming::from_env(),
            heartbeat_started: Arc::default(),
        })
    }

    /// Heartbeat interval and stale time of the compute locks (default 5 s / 60 s, or
    /// `BVHLAB_LOCK_HEARTBEAT_SECS` / `BVHLAB_LOCK_STALE_SECS`).
    pub fn set_lock_timing(&mut self, timing: LockTiming) {
        self.lock_timing = timing;
    }

    /// Starts the thread that beats every held lock (once per store; it ends with the store).
    fn start_heartbeat(&self) {
        if self.heartbeat_started.swap(true, Ordering::SeqCst) {
            return;
        }
        let held = Arc::downgrade(&self.locks);
        let every = self.lock_timing.heartbeat;
        let spawned = std::thread::Builder::new()
            .name("bvhlab-lock-heartbeat".into())
            .spawn(move || loop {
                std::thread::sleep(every);
                let Some(m) = held.upgrade() else { return };
                let m = m.lock().unwrap_or_else(|e| e.into_inner());
                for g in m.values() {
                    g.heartbeat();
                }
            });
        if spawned.is_err() {
            eprintln!("warning: cannot start the lock heartbeat thread; long stages may be taken over by other hosts");
        }
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

    /// Reads and verifies an artifact file on its own (codec header and checksum only). Missing =>
    /// None; corrupt => quarantined and None. The runner uses `get_entry`, which also checks the
    /// file against its manifest.
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

    /// Reads data file `ext` of a complete entry, checked end to end: the manifest exists, parses and
    /// names this stage and key; it lists `ext`; the file's blake3 equals the listed one (which
    /// rejects truncated, bit-flipped and foreign files, e.g. another key's valid artifact copied
    /// here); the codec header checks out and the payload decodes. Anything else is a miss.
    /// With `repair`, a problem is reported on stderr and the offending file quarantined; without
    /// it the miss is silent and nothing is touched (the caller re-checks under the entry's lock
    /// before acting, so it never quarantines a file another process is just replacing).
    pub fn get_entry<T: DeserializeOwned>(
        &self,
        stage: &str,
        key: &Key,
        ext: &str,
        repair: bool,
    ) -> Option<T> {
        self.get_entry_with(stage, key, ext, &[], repair)
    }

    /// `get_entry`, and the entry's raw files `also` (e.g. the heat map `png` a measure summary
    /// points to) must be listed by the manifest and match their blake3 too: a file the caller
    /// will hand on (copied into a report) is checked before use like the artifact itself, and
    /// one that a repair dropped from the manifest makes the entry a miss, so it is recomputed
    /// rather than silently missing downstream.
    pub fn get_entry_with<T: DeserializeOwned>(
        &self,
        stage: &str,
        key: &Key,
        ext: &str,
        also: &[&str],
        repair: bool,
    ) -> Option<T> {
        // With `repair`, what is wrong is said (and a bad file quarantined); the entry is recomputed.
        let warn = |what: String| {
            if repair {
                eprintln!("warning: {what}; recomputing");
            }
        };
        let bad = |path: &Path, reason: &str| {
            warn(format!("bad cache file {}: {reason}", path.display()));
            if repair && path.exists() {
                self.quarantine(path);
            }
        };
        let unreadable = |path: &Path, e: std::io::Error| {
            warn(format!("cache file {} listed by its manifest is unreadable ({e})", path.display()))
        };
        const DIFFERS: &str = "blake3 differs from its manifest (truncated, corrupt or foreign)";
        let mpath = self.path(stage, key, "json");
        let mbytes = match fs::read(&mpath) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
            Err(e) => {
                bad(&mpath, &format!("unreadable manifest: {e}"));
                return None;
            }
        };
        let m: Manifest = match serde_json::from_slice(&mbytes) {
            Ok(m) => m,
            Err(e) => {
                bad(&mpath, &format!("unparseable manifest: {e}"));
                return None;
            }
        };
        if m.key != key.hex() || m.stage != stage {
            bad(
                &mpath,
                &format!("manifest of {}/{} (foreign)", m.stage, m.key),
            );
            return None;
        }
        // Not listed: the entry lost this file to a repair; recompute the entry.
        let want = m.files.get(ext)?;
        let path = self.path(stage, key, ext);
        let bytes = match fs::read(&path) {
            Ok(b) => b,
            Err(e) => {
                unreadable(&path, e);
                return None;
            }
        };
        if blake3::hash(&bytes).to_hex().as_str() != want {
            bad(&path, DIFFERS);
            return None;
        }
        for x in also {
            let xpath = self.path(stage, key, x);
            let Some(xwant) = m.files.get(*x) else {
                warn(format!("cache entry {stage}/{} lost its {x} file (cache repair?)", key.hex()));
                return None;
            };
            match fs::read(&xpath) {
                Ok(b) if blake3::hash(&b).to_hex().as_str() == xwant => {}
                Ok(_) => {
                    bad(&xpath, DIFFERS);
                    return None;
                }
                Err(e) => {
                    unreadable(&xpath, e);
                    return None;
                }
            }
        }
        match codec::decode(&bytes) {
            Ok(v) => Some(v),
            Err(reason) => {
                bad(&path, &reason);
                None
            }
        }
    }

    // ---- compute locks ------------------------------------------------------------------------

    fn lock_path(&self, stage: &str, key: &Key) -> PathBuf {
        self.root
            .join("locks")
            .join(stage)
            .join(format!("{}.lock", key.hex()))
    }

    /// Takes the exclusive compute lock of an entry, blocking while another process holds it.
    /// Re-entrant within this process (a held lock is kept). On an I/O error it warns and goes on
    /// unlocked: atomic writes keep the cache correct, only the once-per-entry guarantee is lost.
    pub fn lock(&self, stage: &str, key: &Key) {
        if self.holds_lock(stage, key) {
            return;
        }
        // Block without holding the table's mutex.
        match lockfile::acquire(&self.lock_path(stage, key), &self.token, &self.lock_timing) {
            Ok(g) => {
                let mut held = self.locks.lock().unwrap_or_else(|e| e.into_inner());
                held.insert((stage.to_string(), *key), g);
                drop(held);
                self.start_heartbeat();
            }
            Err(e) => eprintln!(
                "warning: cannot lock {}: {e}; computing without a lock",
                self.lock_path(stage, key).display()
            ),
        }
    }

    /// Releases the entry's compute lock if this process holds it.
    pub fn unlock(&self, stage: &str, key: &Key) {
        let mut held = self.locks.lock().unwrap_or_else(|e| e.into_inner());
        // Dropping the guard removes the lock file.
        held.remove(&(stage.to_string(), *key));
    }

    pub fn holds_lock(&self, stage: &str, key: &Key) -> bool {
        let held = self.locks.lock().unwrap_or_else(|e| e.into_inner());
        held.contains_key(&(stage.to_string(), *key))
    }

    /// Number of compute locks this process holds.
    pub fn held_locks(&self) -> usize {
        self.locks.lock().map(|m| m.len()).unwrap_or(0)
    }

    /// A guard releasing every lock this store holds when dropped.
    pub fn release_on_drop(&self) -> LockRelease {
        LockRelease(self.locks.clone())
    }

    /// The entry's lock if no live process holds it (repair and gc skip entries being computed).
    fn try_lock_entry(&self, stage: &str, key: &Key) -> Option<Option<lockfile::Guard>> {
        if self.holds_lock(stage, key) {
            return None;
        }
        match lockfile::try_acquire(&self.lock_path(stage, key), &self.token) {
            Ok(Some(g)) => Some(Some(g)),
            Ok(None) => None,
            // No lock directory (read-only cache...): nothing can be computing through it.
            Err(_) => Some(None),
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

    /// Writes `bytes` atomically to `path` (see `crate::atomic`).
    pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
        Self::write_atomic_with(path, |tmp| fs::write(tmp, bytes).map_err(|e| e.to_string()))
    }

    /// Lets `write` produce the file at a temporary path, then fsyncs and renames it into place.
    pub fn write_atomic_with(
        path: &Path,
        write: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<()> {
        atomic::write_atomic_with(path, |tmp| {
            write(tmp).map_err(|e| format!("cannot write {}: {e}", tmp.display()))
        })
        .map_err(Error::internal)
    }

    /// Encodes and writes one data file; returns the blake3 hex of the written bytes. Header and
    /// payload are written separately (no second in-memory copy of a large artifact). If the entry
    /// already has a manifest (a summary restored from its intact full artifact), the manifest is
    /// amended to list the file, so later runs accept it again.
    pub fn put<T: Serialize>(
        &self,
        stage: &str,
        key: &Key,
        ext: &str,
        value: &T,
    ) -> Result<String> {
        let (header, payload) = codec::encode_parts(value).map_err(Error::internal)?;
        Self::write_atomic_with(&self.path(stage, key, ext), |tmp| {
            let mut f = fs::File::create(tmp).map_err(|e| e.to_string())?;
            f.write_all(&header).map_err(|e| e.to_string())?;
            f.write_all(&payload).map_err(|e| e.to_string())
        })?;
        let mut h = blake3::Hasher::new();
        h.update(&header);
        h.update(&payload);
        let hash = h.finalize().to_hex().to_string();
        if let Some(mut m) = self.read_manifest(stage, key) {
            if m.key == key.hex() && m.stage == stage && m.files.get(ext) != Some(&hash) {
                m.files.insert(ext.to_string(), hash.clone());
                self.commit(&m)?;
            }
        }
        Ok(hash)
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
            .filter(|p| {
                p.is_dir()
                    && p.file_name()
                        .is_some_and(|n| n != "quarantine" && n != "locks")
            })
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
                if f.extension().is_some_and(|e| e == "json") && !is_temp(&f) {
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

    /// `check(true)`: verify and repair.
    pub fn verify(&self) -> VerifyReport {
        self.check(true)
    }

    /// Checks every manifest (parses, names its own stage and key) and every file it lists (blake3
    /// as recorded, codec header and checksum for `bin`/`sum`/... artifacts). With `repair`: bad
    /// files are quarantined and dropped from their manifest (a manifest left with no file, or one
    /// that is itself bad, is removed), so the next run recomputes exactly what is missing and a
    /// second `check` is clean; temporary files of dead writers are removed. Entries whose compute
    /// lock another process holds are skipped while repairing (they are being rewritten).
    pub fn check(&self, repair: bool) -> VerifyReport {
        let mut r = VerifyReport::default();
        for dir in self.stage_dirs() {
            let stage = dir
                .file_name()
                .map(|s| s.to_string_lossy().to_string())
                .unwrap_or_default();
            let files = Self::files(&dir);
            for f in &files {
                let name = f
                    .file_name()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                if name.starts_with(".tmp-") {
                    if !writer_alive(&name, f) {
                        r.stale_temp += 1;
                        if repair {
                            let _ = fs::remove_file(f);
                        }
                    }
                    continue;
                }
                let stem = name.split('.').next().unwrap_or("");
                if !name.ends_with(".json") {
                    if !dir.join(format!("{stem}.json")).is_file() {
                        r.incomplete += 1;
                    }
                    continue;
                }
                r.entries += 1;
                let Some(key) = Key::from_hex(stem) else {
                    r.bad.push(format!("{}: not a key", f.display()));
                    if repair {
                        self.quarantine(f);
                    }
                    continue;
                };
                let _guard = if repair {
                    match self.try_lock_entry(&stage, &key) {
                        Some(g) => g,
                        None => {
                            r.busy += 1;
                            continue;
                        }
                    }
                } else {
                    None
                };
                let manifest = fs::read(f)
                    .map_err(|e| format!("unreadable manifest: {e}"))
                    .and_then(|b| {
                        serde_json::from_slice::<Manifest>(&b)
                            .map_err(|e| format!("unparseable manifest: {e}"))
                    })
                    .and_then(|m| {
                        if m.key == stem && m.stage == stage {
                            Ok(m)
                        } else {
                            Err(format!("manifest of {}/{} (foreign)", m.stage, m.key))
                        }
                    });
                let mut m = match manifest {
                    Ok(m) => m,
                    Err(reason) => {
                        r.bad.push(format!("{}: {reason}", f.display()));
                        if repair {
                            self.quarantine(f);
                            r.manifests_fixed += 1;
                        }
                        continue;
                    }
                };
                let mut dropped = false;
                for (ext, want) in m.files.clone() {
                    let path = self.path(&stage, &key, &ext);
                    let problem = match fs::read(&path) {
                        Err(e) => Some(format!("unreadable: {e}")),
                        Ok(bytes) => {
                            if blake3::hash(&bytes).to_hex().as_str() != want {
                                Some(
                                    "blake3 differs from manifest (truncated, corrupt or foreign)"
                                        .to_string(),
                                )
                            } else if bytes.starts_with(&codec::MAGIC)
                                || ext == "bin"
                                || ext == "sum"
                            {
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
                            if repair {
                                if path.exists() {
                                    self.quarantine(&path);
                                }
                                m.files.remove(&ext);
                                dropped = true;
                            }
                        }
                    }
                }
                if dropped {
                    r.manifests_fixed += 1;
                    if m.files.is_empty() {
                        let _ = fs::remove_file(f);
                    } else if let Err(e) = self.commit(&m) {
                        r.bad
                            .push(format!("{}: cannot rewrite manifest: {e}", f.display()));
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
        let mut removed_locks = 0;
        for dir in Self::files(&self.root.join("locks")) {
            for f in Self::files(&dir) {
                let name = f
                    .file_name()
                    .map(|n| n.to_string_lossy().to_string())
                    .unwrap_or_default();
                if name.ends_with(".lock") || name.ends_with(".lock.takeover") {
                    // Taken (and so removed) only if no live process holds it.
                    if let Ok(Some(g)) = lockfile::try_acquire(&f, &self.token) {
                        drop(g);
                        removed_locks += 1;
                    }
                } else if name.contains(".stale-") || name.contains(".new-") {
                    // Leftovers of a process killed while taking or taking over a lock: removed
                    // once their writer is gone (its token names host tag and pid) or a day old.
                    let token = [".stale-", ".new-"]
                        .iter()
                        .find_map(|m| name.rsplit_once(m).map(|(_, t)| t))
                        .unwrap_or("");
                    let mut parts = token.splitn(3, '-');
                    let (tag, pid) = (
                        parts.next(),
                        parts.next().and_then(|p| p.parse::<u32>().ok()),
                    );
                    let dead_here = tag == Some(lockfile::host_tag())
                        && pid.is_some_and(|p| !lockfile::pid_alive(p));
                    let old = fs::metadata(&f)
                        .and_then(|m| m.modified())
                        .ok()
                        .and_then(|t| t.elapsed().ok())
                        .is_some_and(|age| age.as_secs() > 86_400);
                    if (dead_here || old) && fs::remove_file(&f).is_ok() {
                        removed_locks += 1;
                    }
                }
            }
        }
        for dir in self.stage_dirs() {
            for f in Self::files(&dir) {
                let name = f
                    .file_name()
                    .map(|s| s.to_string_lossy().to_string())
                    .unwrap_or_default();
                if name.starts_with(".tmp-") {
                    // A live writer's temp file is about to be renamed into place.
                    if !writer_alive(&name, &f) {
                        remove(&f);
                    }
                    continue;
                }
                let stem = name.split('.').next().unwrap_or("");
                if !dir.join(format!("{stem}.json")).is_file() {
                    // Skip entries another process is computing right now (lock held).
                    let stage = dir
                        .file_name()
                        .map(|s| s.to_string_lossy().to_string())
                        .unwrap_or_default();
                    let busy = Key::from_hex(stem)
                        .is_some_and(|k| self.try_lock_entry(&stage, &k).is_none());
                    if !busy {
                        remove(&f);
                    }
                }
            }
        }
        r.removed_locks = removed_locks;
        r
    }
}

fn is_temp(p: &Path) -> bool {
    p.file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with(".tmp-"))
}

#[cfg(test)]
#[path = "store_tests.rs"]
mod tests;
