//! `bvhlab scenes fetch` against a local HTTP server (a std TcpListener thread on 127.0.0.1 serving
//! ../shared/scenes, optionally with some files' bytes altered) and a local directory, and the fetch
//! command in the errors for missing catalogued scenes. Tests needing ../shared skip without it.
mod common;
use common::{command, json_line};
use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn shared_scenes() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}

/// Serves files of `root` on 127.0.0.1 (one request per connection), with the bytes of the files
/// named in `corrupt` altered (same length, one byte flipped in the middle). Stops when dropped, and
/// by itself after 5 minutes or 1000 requests.
struct Server {
    url: String,
    stop: Arc<AtomicBool>,
    requests: Arc<AtomicUsize>,
}

impl Server {
    fn start(root: &Path, corrupt: &[&str]) -> Server {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let url = format!("http://{}/", listener.local_addr().unwrap());
        let stop = Arc::new(AtomicBool::new(false));
        let requests = Arc::new(AtomicUsize::new(0));
        let (root, corrupt) = (
            root.to_path_buf(),
            corrupt.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
        );
        let (stop2, requests2) = (stop.clone(), requests.clone());
        std::thread::spawn(move || {
            let t0 = Instant::now();
            while !stop2.load(Ordering::Relaxed) && t0.elapsed() < Duration::from_secs(300) {
                let stream = match listener.accept() {
                    Ok((s, _)) => s,
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(5));
                        continue;
                    }
                    Err(_) => break,
                };
                if requests2.fetch_add(1, Ordering::Relaxed) >= 1000 {
                    break;
                }
                stream.set_nonblocking(false).unwrap();
                stream
                    .set_read_timeout(Some(Duration::from_secs(10)))
                    .unwrap();
                let _ = serve(stream, &root, &corrupt);
            }
        });
        Server {
            url,
            stop,
            requests,
        }
    }

    fn requests(&self) -> usize {
        self.requests.load(Ordering::Relaxed)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn serve(stream: std::net::TcpStream, root: &Path, corrupt: &[String]) -> std::io::Result<()> {
    let mut reader = BufReader::new(stream.try_clone()?);
    let mut first = String::new();
    reader.read_line(&mut first)?;
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line)? == 0 || line == "\r\n" || line == "\n" {
            break;
        }
    }
    let path = first
        .split_whitespace()
        .nth(1)
        .unwrap_or("/")
        .trim_start_matches('/')
        .to_string();
    let mut out = stream;
    let body = if path.contains("..") || path.contains('/') {
        None
    } else {
        std::fs::read(root.join(&path)).ok()
    };
    match body {
        Some(mut b) => {
            if corrupt.contains(&path) && !b.is_empty() {
                let mid = b.len() / 2;
                b[mid] ^= 0x55;
            }
            write!(out, "HTTP/1.1 200 OK\r\nContent-Length: {}\r\nContent-Type: application/octet-stream\r\nConnection: close\r\n\r\n", b.len())?;
            out.write_all(&b)?;
        }
        None => write!(
            out,
            "HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
        )?,
    }
    out.flush()
}

fn fetch(args: &[&str], cwd: &Path) -> std::process::Output {
    let mut a = vec!["scenes", "fetch"];
    a.extend_from_slice(args);
    command(&a, cwd)
        .env_remove("BVHLAB_SCENES_FROM")
        .output()
        .unwrap()
}

fn strings(v: &serde_json::Value) -> Vec<String> {
    let mut s: Vec<String> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_str().unwrap().to_string())
        .collect();
    s.sort();
    s
}

/// Every file of the shared scene directory that the catalogue names (scenes and their notes).
fn catalogued_files(shared: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(shared)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".obj.gz") || n.ends_with(".txt"))
        .collect();
    v.sort();
    v
}

#[test]
fn fetch_all_over_http_verifies_every_scene_and_skips_present_ones() {
    let Some(shared) = shared_scenes() else {
        return;
    };
    let server = Server::start(&shared, &[]);
    let tmp = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let o = fetch(
        &["--all", "--from", &server.url, "--dir", "scenes"],
        tmp.path(),
    );
    let wall = t0.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = json_line(&o);
    let files = catalogued_files(&shared);
    assert_eq!(files.iter().filter(|f| f.ends_with(".obj.gz")).count(), 9);
    assert_eq!(strings(&j["fetched"]), files);
    assert!(strings(&j["failed"]).is_empty());
    for f in &files {
        let got = std::fs::read(tmp.path().join("scenes").join(f)).unwrap();
        assert!(got == std::fs::read(shared.join(f)).unwrap(), "{f} differs");
    }
    let leftovers: Vec<_> = std::fs::read_dir(tmp.path().join("scenes"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    eprintln!(
        "fetch --all over http://127.0.0.1: {} bytes in {:.3} s (command's own figure), {wall:.3} s wall",
        j["bytes"], j["seconds"].as_f64().unwrap()
    );

    // Again: every file is present and verified, nothing is requested.
    let before = server.requests();
    let o = fetch(
        &["--all", "--from", &server.url, "--dir", "scenes"],
        tmp.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = json_line(&o);
    assert_eq!(strings(&j["present"]), files);
    assert!(strings(&j["fetched"]).is_empty());
    assert_eq!(server.requests(), before);
}

#[test]
fn corrupted_download_is_rejected_and_nothing_in_place_replaced() {
    let Some(shared) = shared_scenes() else {
        return;
    };
    let server = Server::start(
        &shared,
        &[
            "stanford_bunny.obj.gz",
            "sibenik.obj.gz",
            "conference.obj.gz",
        ],
    );
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("scenes");
    std::fs::create_dir(&dir).unwrap();
    // sibenik: a good copy in place; conference: a stale one (not the catalogued bytes).
    std::fs::copy(shared.join("sibenik.obj.gz"), dir.join("sibenik.obj.gz")).unwrap();
    let good_sibenik = std::fs::read(dir.join("sibenik.obj.gz")).unwrap();
    std::fs::write(dir.join("conference.obj.gz"), b"stale").unwrap();
    let o = fetch(
        &[
            "stanford_bunny",
            "sibenik",
            "conference",
            "--from",
            &server.url,
            "--dir",
            "scenes",
            "--replace",
        ],
        tmp.path(),
    );
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(1), "{err}");
    let j = json_line(&o);
    assert_eq!(
        strings(&j["failed"]),
        ["conference.obj.gz", "stanford_bunny.obj.gz"]
    );
    assert_eq!(strings(&j["present"]), ["sibenik.obj.gz"]);
    // The notes were not corrupted: fetched.
    assert_eq!(
        strings(&j["fetched"]),
        ["conference.copyright.txt", "sibenik.copyright.txt"]
    );
    // The message names file, expected and actual checksum.
    let bunny = "2a0c1502ae7ea26f73932e61826e747eb2773691d0d762c1f98b43dc3b3a571b";
    let line = err
        .lines()
        .find(|l| l.contains("stanford_bunny.obj.gz") && l.contains("checksum mismatch"))
        .unwrap_or_else(|| panic!("{err}"));
    assert!(
        line.contains(&format!("expected 819422 bytes, blake3 {bunny}")),
        "{line}"
    );
    assert!(line.contains("got 819422 bytes, blake3 "), "{line}");
    assert!(!dir.join("stanford_bunny.obj.gz").exists());
    // The good file was never replaced (not even requested), the stale one was not replaced by bad bytes.
    assert_eq!(
        std::fs::read(dir.join("sibenik.obj.gz")).unwrap(),
        good_sibenik
    );
    assert_eq!(
        std::fs::read(dir.join("conference.obj.gz")).unwrap(),
        b"stale"
    );
    assert!(err.contains("the file in place is unchanged"), "{err}");
    let names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().to_string())
        .collect();
    assert!(
        names.iter().all(|n| !n.starts_with('.')),
        "temporary files left: {names:?}"
    );

    // Without --replace a stale file is refused before anything is downloaded.
    let before = server.requests();
    let o = fetch(
        &["conference", "--from", &server.url, "--dir", "scenes"],
        tmp.path(),
    );
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success());
    assert!(
        err.contains("present but not the catalogued file") && err.contains("--replace"),
        "{err}"
    );
    assert_eq!(server.requests(), before);
}

#[test]
fn fetch_from_a_directory_copies_and_verifies() {
    let Some(shared) = shared_scenes() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let from = shared.to_string_lossy().to_string();
    let o = fetch(
        &[
            "stanford_bunny",
            "breakfast_room",
            "--from",
            &from,
            "--dir",
            "s",
        ],
        tmp.path(),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j = json_line(&o);
    assert_eq!(
        strings(&j["fetched"]),
        [
            "breakfast_room.LICENSE.txt",
            "breakfast_room.obj.gz",
            "stanford_bunny.obj.gz"
        ]
    );
    for f in [
        "breakfast_room.obj.gz",
        "stanford_bunny.obj.gz",
        "breakfast_room.LICENSE.txt",
    ] {
        assert!(
            std::fs::read(tmp.path().join("s").join(f)).unwrap()
                == std::fs::read(shared.join(f)).unwrap()
        );
    }
    // The fetched scene loads.
    let o = command(
        &[
            "eval",
            "--scene",
            "s/stanford_bunny.obj.gz",
            "--build",
            "spatial-median",
            "--repeat",
            "1",
            "--no-cache",
            "--json",
        ],
        tmp.path(),
    )
    .output()
    .unwrap();
    assert_eq!(common::ok(o, "eval")["triangles"], 69451);
}

/// `eval` on a scene file that is not there: exit code and stderr.
fn eval_missing(scene: &str, cwd: &Path, from_env: Option<&str>) -> (Option<i32>, String) {
    let mut c = command(
        &[
            "eval",
            "--scene",
            scene,
            "--build",
            "spatial-median",
            "--no-cache",
        ],
        cwd,
    );
    match from_env {
        Some(v) => c.env("BVHLAB_SCENES_FROM", v),
        None => c.env_remove("BVHLAB_SCENES_FROM"),
    };
    let o = c.output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

#[test]
fn usage_errors_and_missing_scene_hints() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path();
    // No --from: a missing file is not invented; the message says why there is no default.
    let o = fetch(&["sibenik", "--dir", "s"], cwd);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success());
    assert!(
        err.contains("no --from given") && err.contains("other formats"),
        "{err}"
    );
    let o = fetch(&["nope", "--dir", "s"], cwd);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(2));
    assert!(
        err.contains("unknown scene `nope`") && err.contains("stanford_dragon"),
        "{err}"
    );
    let o = fetch(&["--dir", "s"], cwd);
    assert_eq!(o.status.code(), Some(2));
    let o = fetch(&["sibenik", "--from", "ftp://x/", "--dir", "s"], cwd);
    assert_eq!(o.status.code(), Some(2));
    // Outside a checkout without --dir: refused rather than guessing a directory.
    let o = fetch(&["sibenik"], cwd);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(err.contains("--dir"), "{err}");

    // eval on a missing catalogued scene names the fetch command.
    let (code, err) = eval_missing("data/conference.obj.gz", cwd, None);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("data/conference.obj.gz: cannot read scene"),
        "{err}"
    );
    assert!(
        err.contains("`bvhlab scenes fetch conference --from URL|DIR --dir data`"),
        "{err}"
    );
    // With $BVHLAB_SCENES_FROM the command is complete.
    let mirror = "http://mirror.example/scenes/";
    let (_, err) = eval_missing("data/conference.obj.gz", cwd, Some(mirror));
    assert!(
        err.contains(&format!(
            "`bvhlab scenes fetch conference --from {mirror} --dir data`"
        )),
        "{err}"
    );
    // An uncatalogued file: the plain message.
    let (_, err) = eval_missing("mine.obj", cwd, None);
    assert!(
        err.contains("mine.obj: cannot read scene") && !err.contains("fetch"),
        "{err}"
    );

    // An experiment naming a missing catalogued scene: file, line, column, reason and the command.
    std::fs::create_dir(cwd.join("experiments")).unwrap();
    std::fs::write(
        cwd.join("experiments/x.toml"),
        "name = \"x\"\nscenes = [\"../nowhere/scenes/sibenik.obj.gz\"]\n[[chain]]\nbuild = \"lbvh\"\n",
    )
    .unwrap();
    let o = command(&["sweep", "experiments/x.toml", "--plan"], cwd)
        .env_remove("BVHLAB_SCENES_FROM")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains(
            "experiments/x.toml:2:11: scene file not found: ../nowhere/scenes/sibenik.obj.gz"
        ),
        "{err}"
    );
    assert!(
        err.contains("`bvhlab scenes fetch sibenik --from URL|DIR --dir ../nowhere/scenes`"),
        "{err}"
    );
}
