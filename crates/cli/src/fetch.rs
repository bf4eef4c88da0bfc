//! `bvhlab scenes fetch NAME...|--all [--from URL|DIR] [--dir SCENE_DIR]`: copies catalogued real
//! scenes (experiments/scenes.toml, compiled in) from a web server or a directory holding the stored
//! files, verifies size and BLAKE3 against the catalogue, and only then moves each file into place
//! (temporary file in the scene directory + rename). A file that fails verification is deleted and
//! nothing in place is touched; files already present and verified are skipped.
use bvhlab_pipeline::atomic::write_atomic_file;
use bvhlab_pipeline::catalogue::{self, SceneEntry, StoredFile, FROM_ENV};
use bvhlab_pipeline::{Error, Result};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::{IsTerminal, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where the files come from.
enum Source {
    /// Base URL ending in `/`: FILE is fetched from BASE + FILE.
    Http {
        base: String,
        agent: ureq::Agent,
    },
    Dir(PathBuf),
}

impl Source {
    fn parse(from: &str) -> Result<Source> {
        if from.starts_with("http://") || from.starts_with("https://") {
            let base = if from.ends_with('/') {
                from.to_string()
            } else {
                format!("{from}/")
            };
            let config = ureq::Agent::config_builder()
                .timeout_connect(Some(Duration::from_secs(30)))
                // A stalled server fails the file instead of hanging the command.
                .timeout_recv_response(Some(Duration::from_secs(60)))
                .timeout_recv_body(None)
                .timeout_per_read(Some(Duration::from_secs(60)))
                .build();
            Ok(Source::Http {
                base,
                agent: config.into(),
            })
        } else if from.contains("://") {
            Err(Error::input(format!(
                "--from {from}: only http://, https:// or a directory"
            )))
        } else {
            let dir = PathBuf::from(from);
            if !dir.is_dir() {
                return Err(Error::input(format!(
                    "--from {from}: not a directory (nor an http(s):// address)"
                )));
            }
            Ok(Source::Dir(dir))
        }
    }

    fn describe(&self, file: &str) -> String {
        match self {
            Source::Http { base, .. } => format!("{base}{file}"),
            Source::Dir(d) => d.join(file).display().to_string(),
        }
    }

    /// A reader over FILE's bytes and the length the source announces (if any).
    fn open(&self, file: &str) -> std::result::Result<(Box<dyn Read>, Option<u64>), String> {
        match self {
            Source::Http { base, agent } => {
                let resp = agent
                    .get(&format!("{base}{file}"))
                    .call()
                    .map_err(|e| e.to_string())?;
                let len = resp
                    .headers()
                    .get("content-length")
                    .and_then(|v| v.to_str().ok())
                    .and_then(|v| v.parse().ok());
                Ok((Box::new(resp.into_body().into_reader()), len))
            }
            Source::Dir(d) => {
                let f = std::fs::File::open(d.join(file)).map_err(|e| e.to_string())?;
                let len = f.metadata().ok().map(|m| m.len());
                Ok((Box::new(f), len))
            }
        }
    }
}

/// Size and BLAKE3 of a file on disk.
fn hash_file(path: &Path) -> std::io::Result<(u64, String)> {
    let mut h = blake3::Hasher::new();
    let mut f = std::fs::File::open(path)?;
    let n = std::io::copy(&mut f, &mut h)?;
    Ok((n, h.finalize().to_hex().to_string()))
}

/// The scene directory when --dir is not given: `../shared/scenes` next to the repository this
/// command is run in (the first ancestor of the working directory holding `experiments/scenes.toml`), which is
/// where the shipped experiments look when run from the repository root.
pub fn default_dir() -> Result<PathBuf> {
    let cwd =
        std::env::current_dir().map_err(|e| Error::internal(format!("working directory: {e}")))?;
    for d in cwd.ancestors() {
        if d.join("experiments/scenes.toml").is_file() {
            let rel = pathdiff(d, &cwd).join("../shared/scenes");
            return Ok(rel);
        }
    }
    Err(Error::input(format!(
        "{}: not inside a bvhlab checkout (no experiments/scenes.toml here or above); give the scene directory with --dir",
        cwd.display()
    )))
}

/// `..` components leading from `cwd` up to its ancestor `root` (empty when equal).
fn pathdiff(root: &Path, cwd: &Path) -> PathBuf {
    let ups = cwd.components().count() - root.components().count();
    let mut p = PathBuf::new();
    for _ in 0..ups {
        p.push("..");
    }
    p
}

#[derive(Default)]
struct Outcome {
    fetched: Vec<String>,
    present: Vec<String>,
    failed: Vec<String>,
    bytes: u64,
}

/// Fetches one file into `dir`; returns Ok(true) when fetched, Ok(false) when already present and
/// verified, Err(message) when it failed (the message names file, expected and actual values).
fn fetch_one(
    f: &StoredFile,
    src: Option<&Source>,
    dir: &Path,
    replace: bool,
    bar: &ProgressBar,
) -> std::result::Result<bool, String> {
    let dest = dir.join(&f.file);
    if dest.exists() {
        match hash_file(&dest) {
            Ok((n, h)) if n == f.bytes && h == f.blake3 => return Ok(false),
            Ok((n, h)) if !replace => {
                return Err(format!(
                    "{}: present but not the catalogued file (expected {} bytes, blake3 {}; found {n} bytes, blake3 {h}); \
                     not replacing it: move it away or pass --replace",
                    dest.display(),
                    f.bytes,
                    f.blake3
                ))
            }
            Ok(_) => {}
            Err(e) => return Err(format!("{}: cannot read: {e}", dest.display())),
        }
    }
    let Some(src) = src else {
        return Err(format!(
            "{}: missing and no --from given (nor ${FROM_ENV}): the catalogue's origin addresses serve the original \
             models in other formats, not the stored files it verifies; pass --from URL|DIR of a copy of the stored \
             files (e.g. another checkout's ../shared/scenes, or a web server serving it)",
            dest.display()
        ));
    };
    let what = src.describe(&f.file);
    let (mut reader, announced) = src.open(&f.file).map_err(|e| format!("{what}: {e}"))?;
    if let Some(n) = announced.filter(|&n| n != f.bytes) {
        return Err(format!(
            "{what}: size mismatch for {}: expected {} bytes, blake3 {}; the source has {n} bytes; not fetched",
            f.file, f.bytes, f.blake3
        ));
    }
    // The rename survives a crash: the temporary is fsynced, then the directory.
    let result = write_atomic_file(&dest, |out| {
        let mut hasher = blake3::Hasher::new();
        let mut n = 0u64;
        let mut buf = vec![0u8; 1 << 16];
        bar.set_message(f.file.clone());
        loop {
            let k = match reader.read(&mut buf) {
                Ok(0) => break,
                Ok(k) => k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(format!("{what}: read failed after {n} bytes: {e}")),
            };
            n += k as u64;
            // Never write more than the catalogue's size (+1 to tell "too long" apart).
            if n > f.bytes {
                return Err(format!(
                    "{what}: size mismatch for {}: expected {} bytes, blake3 {}; the source sent more; rejected",
                    f.file, f.bytes, f.blake3
                ));
            }
            hasher.update(&buf[..k]);
            out.write_all(&buf[..k])
                .map_err(|e| format!("{}: {e}", dest.display()))?;
            bar.inc(k as u64);
        }
        let actual = hasher.finalize().to_hex().to_string();
        if n != f.bytes || actual != f.blake3 {
            return Err(format!(
                "{what}: checksum mismatch for {}: expected {} bytes, blake3 {}; got {n} bytes, blake3 {actual}; rejected{}",
                f.file,
                f.bytes,
                f.blake3,
                if dest.exists() { " (the file in place is unchanged)" } else { " (nothing written)" }
            ));
        }
        Ok(())
    });
    result.map(|()| true)
}

/// The `scenes fetch` command.
pub fn run(
    names: &[String],
    all: bool,
    from: Option<String>,
    dir: Option<PathBuf>,
    replace: bool,
) -> Result<()> {
    let t0 = Instant::now();
    let entries: Vec<&SceneEntry> = if all {
        if !names.is_empty() {
            return Err(Error::input("give scene names or --all, not both"));
        }
        catalogue::catalogue().iter().collect()
    } else if names.is_empty() {
        return Err(Error::input(
            "name the scenes to fetch (see `bvhlab scenes`) or pass --all",
        ));
    } else {
        let mut v = Vec::new();
        for n in names {
            let e = catalogue::by_name(n).ok_or_else(|| {
                let known: Vec<&str> = catalogue::catalogue()
                    .iter()
                    .map(|s| s.name.as_str())
                    .collect();
                Error::input(format!(
                    "unknown scene `{n}`; the catalogue (experiments/scenes.toml) has: {}",
                    known.join(", ")
                ))
            })?;
            v.push(e);
        }
        v
    };
    let from = from.or_else(|| std::env::var(FROM_ENV).ok().filter(|v| !v.is_empty()));
    let src = from.as_deref().map(Source::parse).transpose()?;
    let dir = match dir {
        Some(d) => d,
        None => default_dir()?,
    };
    std::fs::create_dir_all(&dir).map_err(|e| {
        Error::input(format!(
            "{}: cannot create scene directory: {e}",
            dir.display()
        ))
    })?;
    let files: Vec<StoredFile> = entries.iter().flat_map(|e| e.files()).collect();
    let total: u64 = files.iter().map(|f| f.bytes).sum();
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("{bar:40} {bytes}/{total_bytes} {bytes_per_sec} {msg}")
        {
            b.set_style(style);
        }
        b
    } else {
        ProgressBar::hidden()
    };
    let mut out = Outcome::default();
    for f in &files {
        match fetch_one(f, src.as_ref(), &dir, replace, &bar) {
            Ok(true) => {
                bar.suspend(|| {
                    println!("fetched  {} ({} bytes, blake3 verified)", f.file, f.bytes)
                });
                out.fetched.push(f.file.clone());
                out.bytes += f.bytes;
            }
            Ok(false) => {
                bar.inc(f.bytes);
                bar.suspend(|| println!("present  {} (verified, left as it is)", f.file));
                out.present.push(f.file.clone());
            }
            Err(msg) => {
                bar.suspend(|| eprintln!("error: {msg}"));
                out.failed.push(f.file.clone());
            }
        }
    }
    bar.finish_and_clear();
    println!(
        "{}",
        serde_json::json!({
            "dir": dir.display().to_string(),
            "from": from,
            "fetched": out.fetched,
            "present": out.present,
            "failed": out.failed,
            "bytes": out.bytes,
            "seconds": t0.elapsed().as_secs_f64(),
        })
    );
    if out.failed.is_empty() {
        Ok(())
    } else {
        Err(Error::internal(format!(
            "{} of {} files not fetched ({}); the messages above say why",
            out.failed.len(),
            files.len(),
            out.failed.join(", ")
        )))
    }
}

/// The catalogue part of `bvhlab scenes`.
pub fn list() {
    println!("real scenes (experiments/scenes.toml; `bvhlab scenes fetch NAME|--all --from URL|DIR [--dir SCENE_DIR]`):");
    for s in catalogue::catalogue() {
        println!(
            "  {:<22} {:<30} {:>8} triangles  {}",
            s.name, s.file, s.triangles, s.title
        );
        println!("      source: {}", s.source);
        println!("      licence: {}", s.licence);
    }
}
