//! Exclusive lock files that hold on NFS (issue 12), for the cache's per-entry compute locks.
//!
//! `flock` is advisory and, on NFS, depends on the lock manager (NLM/NFSv4 leases) that clusters
//! often misconfigure or disable, and it is silently local on some mounts. This protocol needs only
//! what NFSv3+ guarantees: exclusive `link` (and O_EXCL), atomic rename within a directory, and
//! close-to-open consistency (a file opened after another client closed it shows its writes).
//!
//! - **Acquire**: write one fixed-width record (host, pid, the owner's token, unique per `Store`, and
//!   a heartbeat counter) to a temporary file and hard-link it to the lock's name: `link` fails if
//!   the name exists (as exclusive as O_EXCL), and the lock never exists without its record, so a
//!   process killed while acquiring leaves nothing a waiter cannot judge.
//! - **Heartbeat**: while a process holds locks, a background thread rewrites each held record in
//!   place every `heartbeat` with the counter incremented (through a handle whose token it checked
//!   first; never by rename, which could replace a new owner's lock).
//! - **Waiting**: poll with backoff (10 ms up to 500 ms), reading the record with open/read/close
//!   each time. A lock is stale when its host is ours and its pid is gone (`/proc`; a crash on this
//!   host is taken over at once), or when its record has not changed for `stale` as measured by
//!   the waiter's own monotonic clock. Clocks of different hosts are never compared (skew), and
//!   mtimes are not used (NFS attribute caching can hide a change for a minute).
//! - **Takeover**: take the takeover lock `<lock>.takeover` (created the same way), re-read the
//!   lock and delete it if it still holds the stale record, release, then try to create again.
//!   Only takeover-lock holders delete another's lock, so the lock cannot be replaced between the
//!   re-read and the delete. A takeover lock left by a waiter that died holding it is itself
//!   stale by the same rules and removed by rename-aside, re-read and restore-if-changed.
//! - **Release**: remove the file if it still holds our token.
//!
//! A lock lost to a takeover (an owner frozen for longer than `stale`, e.g. SIGSTOP or a hung NFS
//! client) is detected at the next heartbeat and reported; the computation goes on. Artifacts are
//! deterministic and written atomically, so the cache stays correct; only "computed once" is lost.
use std::fs;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Heartbeat interval and the silence after which a lock of another host is stale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LockTiming {
    pub heartbeat: Duration,
    pub stale: Duration,
}

impl Default for LockTiming {
    /// 5 s heartbeats; stale after 60 s without one (12 missed beats: an NFS server hiccup or a
    /// busy client does not make a live lock stale).
    fn default() -> Self {
        LockTiming {
            heartbeat: Duration::from_secs(5),
            stale: Duration::from_secs(60),
        }
    }
}

impl LockTiming {
    /// Defaults overridden by `BVHLAB_LOCK_HEARTBEAT_SECS` / `BVHLAB_LOCK_STALE_SECS` (seconds,
    /// fractions allowed); invalid values are ignored with a warning.
    pub fn from_env() -> LockTiming {
        let mut t = LockTiming::default();
        let read = |name: &str| -> Option<Duration> {
            let v = std::env::var(name).ok()?;
            match v.trim().parse::<f64>() {
                Ok(s) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
                _ => {
                    eprintln!("warning: {name}=`{v}` is not a positive number of seconds; ignored");
                    None
                }
            }
        };
        if let Some(h) = read("BVHLAB_LOCK_HEARTBEAT_SECS") {
            t.heartbeat = h;
        }
        if let Some(s) = read("BVHLAB_LOCK_STALE_SECS") {
            t.stale = s;
        }
        if t.stale < t.heartbeat * 3 {
            eprintln!(
                "warning: lock stale time {:?} is under 3 heartbeats ({:?}): live locks may be taken over",
                t.stale, t.heartbeat
            );
        }
        t
    }
}

/// This machine's host name as the system gives it: `/etc/hostname` (trimmed), `$HOSTNAME`, else
/// "unknown" (manifests record it so).
pub fn system_host_name() -> String {
    fs::read_to_string("/etc/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown".into())
}

/// [`system_host_name`] without whitespace (lock files and temporary file names).
pub fn host_name() -> &'static str {
    static H: OnceLock<String> = OnceLock::new();
    H.get_or_init(|| system_host_name().split_whitespace().collect::<Vec<_>>().join("_"))
}

/// 8 hex digits of blake3(host name): tags temporary file names with their writer's host.
pub fn host_tag() -> &'static str {
    static T: OnceLock<String> = OnceLock::new();
    T.get_or_init(|| blake3::hash(host_name().as_bytes()).to_hex()[..8].to_string())
}

/// Whether process `pid` of this host exists (Linux: `/proc/<pid>`; elsewhere assume it does).
pub fn pid_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    if Path::new("/proc/self").exists() {
        Path::new("/proc").join(pid.to_string()).exists()
    } else {
        true
    }
}

/// A token unique to one lock owner (host, pid, time, counter).
pub fn new_token() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!(
        "{}-{}-{nanos:x}-{}",
        host_tag(),
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

#[derive(Debug, PartialEq)]
struct Record {
    host: String,
    pid: u32,
    token: String,
    beat: u64,
}

impl Record {
    /// Fixed width for a given owner: only the zero-padded counter changes between beats, so an
    /// in-place rewrite never leaves a longer old tail behind.
    fn encode(&self) -> Vec<u8> {
        format!(
            "bvhlab-lock 1 host={} pid={} token={} beat={:020}\n",
            self.host, self.pid, self.token, self.beat
        )
        .into_bytes()
    }

    fn parse(bytes: &[u8]) -> Option<Record> {
        let s = std::str::from_utf8(bytes).ok()?;
        let mut it = s.trim_end().split(' ');
        if it.next()? != "bvhlab-lock" || it.next()? != "1" {
            return None;
        }
        let mut field = |k: &str| it.next()?.strip_prefix(k).map(str::to_string);
        Some(Record {
            host: field("host=")?,
            pid: field("pid=")?.parse().ok()?,
            token: field("token=")?,
            beat: field("beat=")?.parse().ok()?,
        })
    }
}

/// A held lock: released (file removed if still ours) when dropped.
#[derive(Debug)]
pub struct Guard {
    path: PathBuf,
    token: String,
    beat: AtomicU64,
    lost: AtomicBool,
}

impl Guard {
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Rewrites the record with the next counter value. Returns false (once warned) if the lock is
    /// no longer ours.
    pub fn heartbeat(&self) -> bool {
        if self.lost.load(Ordering::Relaxed) {
            return false;
        }
        let ours = (|| -> std::io::Result<bool> {
            // One handle for check and write: if the file is renamed aside meanwhile, the write
            // lands in the renamed file, never in a new owner's lock.
            let mut f = fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(&self.path)?;
            let mut buf = Vec::new();
            f.read_to_end(&mut buf)?;
            match Record::parse(&buf) {
                Some(r) if r.token == self.token => {
                    let next = Record {
                        beat: self.beat.fetch_add(1, Ordering::Relaxed) + 1,
                        ..r
                    };
                    f.seek(SeekFrom::Start(0))?;
                    f.write_all(&next.encode())?;
                    f.sync_data()?;
                    Ok(true)
                }
                _ => Ok(false),
            }
        })()
        .unwrap_or(false);
        if !ours && !self.lost.swap(true, Ordering::Relaxed) {
            eprintln!(
                "warning: compute lock {} was taken over by another process (this one was silent for longer \
                 than the stale time); the entry may be computed twice, the cache stays correct",
                self.path.display()
            );
        }
        ours
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(bytes) = fs::read(&self.path) {
            if Record::parse(&bytes).is_some_and(|r| r.token == self.token) {
                let _ = fs::remove_file(&self.path);
            }
        }
    }
}

/// Creates the lock with its record already inside: the record goes to `<lock>.new-<token>`
/// first and is then hard-linked to the lock's name. `link` fails if the name exists, so it is
/// as exclusive as O_EXCL, and a process killed at any moment never leaves an empty or half-written
/// lock (which no waiter could judge by its pid). This is the classic NFS lock-file recipe; on NFS a
/// lost reply can make a successful `link` report an error, so the temporary's link count decides.
fn create(path: &Path, token: &str) -> std::io::Result<Option<Guard>> {
    use std::os::unix::fs::MetadataExt;
    let tmp = path.with_file_name(format!(
        "{}.new-{token}",
        path.file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default()
    ));
    let rec = Record {
        host: host_name().to_string(),
        pid: std::process::id(),
        token: token.to_string(),
        beat: 0,
    };
    let write = |tmp: &Path| -> std::io::Result<()> {
        let mut f = fs::File::create(tmp)?;
        f.write_all(&rec.encode())?;
        f.sync_data()
    };
    if let Err(e) = write(&tmp) {
        if e.kind() != std::io::ErrorKind::NotFound {
            let _ = fs::remove_file(&tmp);
            return Err(e);
        }
        if let Some(d) = path.parent() {
            fs::create_dir_all(d)?;
        }
        if let Err(e) = write(&tmp) {
            let _ = fs::remove_file(&tmp);
            return Err(e);
        }
    }
    let linked = match fs::hard_link(&tmp, path) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e) => match fs::metadata(&tmp) {
            Ok(m) if m.nlink() == 2 => Ok(true),
            _ => Err(e),
        },
    };
    let _ = fs::remove_file(&tmp);
    if !linked? {
        return Ok(None);
    }
    Ok(Some(Guard {
        path: path.to_path_buf(),
        token: token.to_string(),
        beat: AtomicU64::new(0),
        lost: AtomicBool::new(false),
    }))
}

/// What a waiter knows about a lock file it did not get.
struct Observed {
    bytes: Vec<u8>,
    since: Instant,
}

fn is_stale(obs: &Observed, timing: &LockTiming) -> bool {
    dead_here(&obs.bytes) || obs.since.elapsed() >= timing.stale
}

fn sibling(path: &Path, suffix: &str) -> PathBuf {
    path.with_file_name(format!(
        "{}.{suffix}",
        path.file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default()
    ))
}

/// Renames a stale file aside and removes it if it still holds what was observed; restores it
/// otherwise. Used only for the takeover lock, whose holder keeps it for microseconds: the
/// restore leaves a moment in which the name is free, harmless only for a lock so rarely stale.
fn remove_if_unchanged(path: &Path, observed: &[u8], token: &str) -> bool {
    let aside = sibling(path, &format!("stale-{token}"));
    if fs::rename(path, &aside).is_err() {
        return false; // another waiter took it, or the owner released it
    }
    if fs::read(&aside).unwrap_or_default() == observed {
        let _ = fs::remove_file(&aside);
        true
    } else {
        let _ = fs::hard_link(&aside, path);
        let _ = fs::remove_file(&aside);
        false
    }
}

enum TakeOver {
    /// The stale lock is gone (or was already).
    Gone,
    /// The lock changed since it was observed: not stale after all, or a new owner.
    Changed,
    /// Another waiter holds the takeover lock; its record as read.
    Busy(Vec<u8>),
}

/// Removes a stale lock under the takeover lock `<lock>.takeover` (see the module doc). Renaming
/// the lock itself aside is not enough: a waiter whose observation is a moment old can rename a
/// new owner's lock instead of the stale one, and restoring it leaves the name free for a third
/// (found by `takeover_of_one_stale_lock_is_exclusive`: two owners at once, about 1 run in 20).
fn take_over(path: &Path, observed: &[u8]) -> TakeOver {
    let tk = sibling(path, "takeover");
    let guard = match create(&tk, &new_token()) {
        Ok(Some(g)) => g,
        Ok(None) => return TakeOver::Busy(fs::read(&tk).unwrap_or_default()),
        Err(_) => return TakeOver::Changed,
    };
    // Holding the takeover lock, nobody else removes the lock: it can only be created (if it is
    // absent) or rewritten by its owner (a heartbeat, which makes it differ from `observed`).
    let r = match fs::read(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => TakeOver::Gone,
        Ok(now) if now == observed => {
            let _ = fs::remove_file(path);
            let who = Record::parse(&now)
                .map(|r| format!("host {} pid {}", r.host, r.pid))
                .unwrap_or_else(|| "an unreadable record".into());
            eprintln!(
                "note: took over the stale compute lock {} ({who})",
                path.display()
            );
            TakeOver::Gone
        }
        _ => TakeOver::Changed,
    };
    drop(guard);
    r
}

/// Takes the lock at `path`, waiting (and taking over stale locks) as long as needed.
pub fn acquire(path: &Path, token: &str, timing: &LockTiming) -> std::io::Result<Guard> {
    let mut backoff = Duration::from_millis(10);
    let mut obs: Option<Observed> = None;
    // The takeover lock as last seen busy: a waiter that died holding it makes it stale too.
    let mut obs_tk: Option<Observed> = None;
    loop {
        if let Some(g) = create(path, token)? {
            return Ok(g);
        }
        match fs::read(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                obs = None;
                continue;
            }
            Err(e) => return Err(e),
            Ok(bytes) => observe(&mut obs, bytes),
        }
        if let Some(o) = &obs {
            if is_stale(o, timing) {
                match take_over(path, &o.bytes) {
                    TakeOver::Gone | TakeOver::Changed => {
                        obs = None;
                        obs_tk = None;
                        continue;
                    }
                    TakeOver::Busy(b) => {
                        observe(&mut obs_tk, b);
                        if let Some(t) = &obs_tk {
                            if is_stale(t, timing) {
                                remove_if_unchanged(&sibling(path, "takeover"), &t.bytes, token);
                                obs_tk = None;
                                continue;
                            }
                        }
                    }
                }
            }
        }
        std::thread::sleep(backoff);
        backoff = (backoff * 2).min(Duration::from_millis(500));
    }
}

/// Records what a waiter read, restarting the silence clock when it changed.
fn observe(obs: &mut Option<Observed>, bytes: Vec<u8>) {
    if obs.as_ref().is_none_or(|o| o.bytes != bytes) {
        *obs = Some(Observed {
            bytes,
            since: Instant::now(),
        });
    }
}

fn dead_here(bytes: &[u8]) -> bool {
    Record::parse(bytes).is_some_and(|r| r.host == host_name() && !pid_alive(r.pid))
}

/// One attempt: Some(guard) if the lock was free (or held by a dead process of this host, taken
/// over), None if a live owner may hold it.
pub fn try_acquire(path: &Path, token: &str) -> std::io::Result<Option<Guard>> {
    if let Some(g) = create(path, token)? {
        return Ok(Some(g));
    }
    let Ok(bytes) = fs::read(path) else {
        return create(path, token);
    };
    if !dead_here(&bytes) {
        return Ok(None);
    }
    match take_over(path, &bytes) {
        TakeOver::Gone => create(path, token),
        TakeOver::Changed => Ok(None),
        TakeOver::Busy(b) => {
            if dead_here(&b) {
                remove_if_unchanged(&sibling(path, "takeover"), &b, token);
            }
            Ok(None)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;
    use std::sync::Arc;

    fn fast() -> LockTiming {
        LockTiming {
            heartbeat: Duration::from_millis(50),
            stale: Duration::from_millis(400),
        }
    }

    #[test]
    fn record_round_trip_and_fixed_width() {
        let r = Record {
            host: "h".into(),
            pid: 7,
            token: "t".into(),
            beat: 3,
        };
        assert_eq!(Record::parse(&r.encode()), Some(r));
        let a = Record {
            host: "h".into(),
            pid: 7,
            token: "t".into(),
            beat: 0,
        }
        .encode();
        let b = Record {
            host: "h".into(),
            pid: 7,
            token: "t".into(),
            beat: u64::MAX,
        }
        .encode();
        assert_eq!(a.len(), b.len());
        assert_eq!(Record::parse(b"garbage"), None);
    }

    #[test]
    fn second_owner_waits_for_release() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("locks/x.lock");
        let g = acquire(&p, &new_token(), &fast()).unwrap();
        assert!(
            try_acquire(&p, &new_token()).unwrap().is_none(),
            "held by a live owner"
        );
        let p2 = p.clone();
        let t0 = Instant::now();
        let waiter = std::thread::spawn(move || {
            let g = acquire(&p2, &new_token(), &fast()).unwrap();
            (t0.elapsed(), g)
        });
        // Beat while holding for longer than the stale time: the waiter must not take over.
        for _ in 0..20 {
            std::thread::sleep(Duration::from_millis(50));
            assert!(g.heartbeat());
        }
        let held_for = t0.elapsed();
        drop(g);
        let (waited, g2) = waiter.join().unwrap();
        assert!(
            waited >= held_for,
            "got the lock only after the release ({waited:?} < {held_for:?})"
        );
        drop(g2);
        assert!(!p.exists(), "released");
    }

    #[test]
    fn dead_local_owner_is_taken_over_at_once() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.lock");
        // pid above Linux's pid_max: dead.
        let dead = Record {
            host: host_name().into(),
            pid: 4_999_999,
            token: "dead".into(),
            beat: 9,
        };
        fs::write(&p, dead.encode()).unwrap();
        let t0 = Instant::now();
        let slow = LockTiming {
            heartbeat: Duration::from_secs(5),
            stale: Duration::from_secs(60),
        };
        let g = acquire(&p, &new_token(), &slow).unwrap();
        assert!(t0.elapsed() < Duration::from_secs(5));
        assert!(g.heartbeat());
        // try_acquire takes a dead owner's lock too.
        drop(g);
        fs::write(&p, dead.encode()).unwrap();
        assert!(try_acquire(&p, &new_token()).unwrap().is_some());
    }

    #[test]
    fn silent_remote_owner_is_taken_over_after_the_stale_time() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.lock");
        let remote = Record {
            host: "elsewhere".into(),
            pid: 1,
            token: "r".into(),
            beat: 1,
        };
        fs::write(&p, remote.encode()).unwrap();
        assert!(
            try_acquire(&p, &new_token()).unwrap().is_none(),
            "another host's lock is not judged by pid"
        );
        let t0 = Instant::now();
        let g = acquire(&p, &new_token(), &fast()).unwrap();
        let waited = t0.elapsed();
        assert!(
            waited >= fast().stale,
            "not before the stale time: {waited:?}"
        );
        assert!(waited < Duration::from_secs(5), "{waited:?}");
        drop(g);
        // A remote owner that keeps beating is never taken over.
        fs::write(&p, remote.encode()).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let beater = {
            let (p, stop) = (p.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut beat = 1;
                while !stop.load(Ordering::Relaxed) {
                    beat += 1;
                    let r = Record {
                        host: "elsewhere".into(),
                        pid: 1,
                        token: "r".into(),
                        beat,
                    };
                    let mut f = fs::OpenOptions::new().write(true).open(&p).unwrap();
                    f.write_all(&r.encode()).unwrap();
                    std::thread::sleep(Duration::from_millis(50));
                }
                fs::remove_file(&p).unwrap();
            })
        };
        let p2 = p.clone();
        let t0 = Instant::now();
        let waiter = std::thread::spawn(move || {
            let g = acquire(&p2, &new_token(), &fast()).unwrap();
            (t0.elapsed(), g)
        });
        std::thread::sleep(Duration::from_millis(1200));
        stop.store(true, Ordering::Relaxed);
        beater.join().unwrap();
        let (waited, _g) = waiter.join().unwrap();
        assert!(
            waited >= Duration::from_millis(1200),
            "a beating owner kept its lock: {waited:?}"
        );
    }

    #[test]
    fn takeover_of_one_stale_lock_is_exclusive() {
        let d = tempfile::tempdir().unwrap();
        let p = Arc::new(d.path().join("x.lock"));
        let dead = Record {
            host: host_name().into(),
            pid: 4_999_999,
            token: "dead".into(),
            beat: 0,
        };
        fs::write(&*p, dead.encode()).unwrap();
        let inside = Arc::new(AtomicUsize::new(0));
        let max_inside = Arc::new(AtomicUsize::new(0));
        let threads: Vec<_> = (0..8)
            .map(|_| {
                let (p, inside, max_inside) = (p.clone(), inside.clone(), max_inside.clone());
                std::thread::spawn(move || {
                    for _ in 0..20 {
                        let g = acquire(&p, &new_token(), &fast()).unwrap();
                        let n = inside.fetch_add(1, Ordering::SeqCst) + 1;
                        max_inside.fetch_max(n, Ordering::SeqCst);
                        std::thread::sleep(Duration::from_micros(200));
                        inside.fetch_sub(1, Ordering::SeqCst);
                        drop(g);
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(max_inside.load(Ordering::SeqCst), 1, "mutual exclusion");
        assert!(!p.exists());
        let leftovers: Vec<_> = fs::read_dir(d.path()).unwrap().flatten().collect();
        assert!(leftovers.is_empty(), "no .stale- files left: {leftovers:?}");
    }

    #[test]
    fn takeover_lock_left_by_a_dead_waiter_is_removed() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.lock");
        let dead = |token: &str| Record {
            host: host_name().into(),
            pid: 4_999_999,
            token: token.into(),
            beat: 0,
        };
        fs::write(&p, dead("owner").encode()).unwrap();
        fs::write(sibling(&p, "takeover"), dead("waiter").encode()).unwrap();
        // One try finds the takeover lock busy and removes it (its holder is dead); the next
        // takes the lock over.
        assert!(try_acquire(&p, &new_token()).unwrap().is_none());
        assert!(!sibling(&p, "takeover").exists());
        let g = try_acquire(&p, &new_token()).unwrap().expect("taken over");
        drop(g);
        let g = acquire(&p, &new_token(), &fast()).unwrap();
        drop(g);
        let left: Vec<_> = fs::read_dir(d.path()).unwrap().flatten().collect();
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn lost_lock_is_detected_by_the_heartbeat() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.lock");
        let g = acquire(&p, &new_token(), &fast()).unwrap();
        // Someone removed it and a new owner exists.
        fs::remove_file(&p).unwrap();
        let g2 = acquire(&p, &new_token(), &fast()).unwrap();
        assert!(!g.heartbeat(), "the first owner sees it lost the lock");
        drop(g); // must not remove the new owner's lock
        assert!(p.exists());
        assert!(g2.heartbeat());
    }
}
