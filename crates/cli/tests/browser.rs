//! The report in a real browser (issue 16 item 8): the quick report opened in headless Chromium
//! must have no missing or undecodable image, no broken local link (a file that does not exist, or
//! a `#anchor` with no element of that id) and no script error. Also saves the first screen
//! (1400x900) and an A4 print of the report under `target/browser/`; asserts that the summary
//! (`#summary`) ends within that first screen, that the page is no wider than it, and that the
//! print has at most 25 pages.
//!
//! How: Chromium loads a copy of the page (same directory, so every relative URL resolves the
//! same) with a script appended that, after `load`, decodes every `<img>` again and writes the ones
//! that failed into the DOM; `--dump-dom` returns that DOM, whose `src` / `href` attributes are then
//! resolved against the file system here, and `--enable-logging=stderr` gives the console, where an
//! uncaught exception is logged as `Uncaught ...`.
//!
//! Without Chromium (`chromium`, `chromium-browser`, `google-chrome` on PATH, or `BVHLAB_CHROMIUM`)
//! the tests skip with a message, unless `BVHLAB_REQUIRE_CHROMIUM=1` (CI) makes that a failure.
//! `scripts/setup.sh` installs the Debian package `chromium`.
//!
//! The failure kinds are tested on a hand-made page (`checker_catches_each_failure_kind`), so the
//! checks stay proven to fail when they should.
mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const CHROMIUM_FLAGS: [&str; 9] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1400,900",
];

/// Longest a single Chromium run may take before the test fails.
const DEADLINE: Duration = Duration::from_secs(180);

/// Id of the element the appended script writes the undecodable images into.
const CHECK_ID: &str = "bvhlab-browser-check";

/// Appended to the page: after `load`, every image is decoded again (lazy or not); the sources
/// that fail go into `<pre id=CHECK_ID>` as a JSON array.
const CHECK_SCRIPT: &str = r#"<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  Promise.all(imgs.map(function (img) {
    var src = img.getAttribute('src') || '';
    return new Promise(function (done) {
      var t = new Image();
      t.onload = function () { done(t.naturalWidth > 0 ? null : src); };
      t.onerror = function () { done(src); };
      t.src = img.src;
    });
  })).then(function (bad) {
    var pre = document.createElement('pre');
    pre.id = 'bvhlab-browser-check';
    pre.textContent = JSON.stringify(bad.filter(function (b) { return b !== null; }));
    document.body.appendChild(pre);
    var s = document.getElementById('summary');
    var q = document.createElement('pre');
    q.id = 'bvhlab-summary-bottom';
    q.textContent = s ? String(Math.ceil(s.getBoundingClientRect().bottom)) + ' ' + String(document.documentElement.scrollWidth) : 'none';
    document.body.appendChild(q);
  });
});
</script>"#;

fn find_browser() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("BVHLAB_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    [
        "chromium",
        "chromium-browser",
        "google-chrome",
        "google-chrome-stable",
    ]
    .iter()
    .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
    .find(|p| p.is_file())
}

/// The browser, or None after a skip message (a failure when `BVHLAB_REQUIRE_CHROMIUM=1`).
fn browser_or_skip(test: &str) -> Option<PathBuf> {
    let b = find_browser();
    if b.is_none() {
        let msg = "no Chromium: none of chromium, chromium-browser, google-chrome on PATH and \
                   BVHLAB_CHROMIUM unset (scripts/setup.sh installs the Debian package `chromium`)";
        if std::env::var("BVHLAB_REQUIRE_CHROMIUM").as_deref() == Ok("1") {
            panic!("{test}: {msg}, and BVHLAB_REQUIRE_CHROMIUM=1");
        }
        eprintln!("skipping {test}: {msg}");
    }
    b
}

/// `target/browser/` (beside `target/tmp`, Cargo's scratch directory for integration tests).
fn artifact_dir() -> PathBuf {
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let d = tmp.parent().unwrap_or(tmp).join("browser");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn file_url(p: &Path) -> String {
    let p = std::fs::canonicalize(p).unwrap();
    let mut s = String::from("file://");
    for b in p.to_string_lossy().bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'/' | b'-' | b'_' | b'.' | b'~' => {
                s.push(b as char)
            }
            _ => s.push_str(&format!("%{b:02X}")),
        }
    }
    s
}

/// Runs Chromium on `url` with `args`; (stdout, stderr). Fails the test on a non-zero exit or
/// after `DEADLINE`.
fn chromium(exe: &Path, args: &[String], url: &str) -> (String, String) {
    let scratch = tempfile::tempdir().unwrap();
    let out_path = scratch.path().join("stdout");
    let err_path = scratch.path().join("stderr");
    let mut child = Command::new(exe)
        .args(CHROMIUM_FLAGS)
        .arg(format!(
            "--user-data-dir={}",
            scratch.path().join("profile").display()
        ))
        .args(args)
        .arg(url)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .unwrap_or_else(|e| panic!("{}: {e}", exe.display()));
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > DEADLINE {
            let _ = child.kill();
            let _ = child.wait();
            panic!("chromium {args:?} {url}: no exit after {DEADLINE:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = String::from_utf8_lossy(&std::fs::read(&out_path).unwrap()).into_owned();
    let err = String::from_utf8_lossy(&std::fs::read(&err_path).unwrap()).into_owned();
    assert!(
        status.success(),
        "chromium {args:?} {url}: {status}\n{}",
        err.lines().rev().take(30).collect::<Vec<_>>().join("\n")
    );
    (out, err)
}

struct Tag {
    name: String,
    attrs: Vec<(String, String)>,
}

fn unescape(s: &str) -> String {
    s.replace("&quot;", "\"")
        .replace("&#39;", "'")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&nbsp;", "\u{a0}")
        .replace("&amp;", "&")
}

/// Start tags and their attributes of serialized HTML (script and style bodies skipped).
fn tags(html: &str) -> Vec<Tag> {
    let lower = html.to_ascii_lowercase();
    let b = html.as_bytes();
    let n = b.len();
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(off) = html[i..].find('<') {
        let s = i + off;
        if html[s..].starts_with("<!--") {
            i = html[s..].find("-->").map_or(n, |e| s + e + 3);
            continue;
        }
        if !b.get(s + 1).is_some_and(|c| c.is_ascii_alphabetic()) {
            i = s + 1;
            continue;
        }
        let mut j = s + 1;
        while j < n && !(b[j].is_ascii_whitespace() || b[j] == b'>' || b[j] == b'/') {
            j += 1;
        }
        let name = lower[s + 1..j].to_string();
        let mut attrs = Vec::new();
        loop {
            while j < n && (b[j].is_ascii_whitespace() || b[j] == b'/') {
                j += 1;
            }
            if j >= n {
                break;
            }
            if b[j] == b'>' {
                j += 1;
                break;
            }
            let ns = j;
            while j < n && !(b[j].is_ascii_whitespace() || matches!(b[j], b'=' | b'>' | b'/')) {
                j += 1;
            }
            let an = lower[ns..j].to_string();
            while j < n && b[j].is_ascii_whitespace() {
                j += 1;
            }
            let mut val = String::new();
            if j < n && b[j] == b'=' {
                j += 1;
                while j < n && b[j].is_ascii_whitespace() {
                    j += 1;
                }
                if j < n && (b[j] == b'"' || b[j] == b'\'') {
                    let q = b[j];
                    let vs = j + 1;
                    j = vs;
                    while j < n && b[j] != q {
                        j += 1;
                    }
                    val = unescape(&html[vs..j.min(n)]);
                    j += 1;
                } else {
                    let vs = j;
                    while j < n && !(b[j].is_ascii_whitespace() || b[j] == b'>') {
                        j += 1;
                    }
                    val = unescape(&html[vs..j]);
                }
            }
            if an.is_empty() {
                j += 1;
                continue;
            }
            attrs.push((an, val));
        }
        i = j.min(n);
        if name == "script" || name == "style" {
            if let Some(e) = lower[i..].find(&format!("</{name}")) {
                i += e;
            }
        }
        out.push(Tag { name, attrs });
    }
    out
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && b[i + 1].is_ascii_hexdigit()
            && b[i + 2].is_ascii_hexdigit()
        {
            if let Ok(v) = u8::from_str_radix(&s[i + 1..i + 3], 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Every `src` / `href` of the DOM that names a local file must exist, and every `#anchor` must
/// name an element id (of this page, or of the linked local HTML file).
fn link_problems(dom: &str, page: &Path) -> Vec<String> {
    let all = tags(dom);
    let ids: BTreeSet<String> = all
        .iter()
        .flat_map(|t| {
            t.attrs
                .iter()
                .filter(|(k, _)| k == "id" || (t.name == "a" && k == "name"))
                .map(|(_, v)| v.clone())
        })
        .collect();
    let dir = page.parent().unwrap();
    let mut problems = Vec::new();
    for t in &all {
        for (k, v) in &t.attrs {
            if k != "src" && k != "href" {
                continue;
            }
            let v = v.trim();
            let scheme = v
                .find(|c: char| matches!(c, ':' | '/' | '?' | '#'))
                .filter(|&i| v.as_bytes()[i] == b':')
                .map(|i| v[..i].to_ascii_lowercase());
            let local = match scheme.as_deref() {
                None => v,
                Some("file") => v.trim_start_matches("file://"),
                Some(_) => continue, // http(s), mailto, data, javascript: not local
            };
            let (path, frag) = local.split_once('#').unwrap_or((local, ""));
            let path = path.split('?').next().unwrap_or("");
            let frag = percent_decode(frag);
            let what = format!("<{} {k}=\"{v}\">", t.name);
            if path.is_empty() {
                if !frag.is_empty() && !ids.contains(&frag) {
                    problems.push(format!("{what}: no element with id \"{frag}\" on the page"));
                }
                continue;
            }
            let target = dir.join(percent_decode(path));
            if !target.exists() {
                problems.push(format!("{what}: {} does not exist", target.display()));
                continue;
            }
            let is_html = target
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("html") || e.eq_ignore_ascii_case("htm"));
            if !frag.is_empty() && is_html {
                let text = std::fs::read_to_string(&target).unwrap_or_default();
                let found = tags(&text).iter().any(|t| {
                    t.attrs
                        .iter()
                        .any(|(k, v)| (k == "id" || (t.name == "a" && k == "name")) && *v == frag)
                });
                if !found {
                    problems.push(format!(
                        "{what}: no element with id \"{frag}\" in {}",
                        target.display()
                    ));
                }
            }
        }
    }
    problems
}

/// Console lines of a Chromium log that report an error: uncaught exceptions, failed loads.
fn console_errors(stderr: &str) -> Vec<String> {
    stderr
        .lines()
        .filter(|l| l.contains(":CONSOLE"))
        .filter(|l| {
            ["Uncaught", "Failed to load resource", "ERR_", "Error"]
                .iter()
                .any(|k| l.contains(k))
        })
        .map(|l| format!("console: {}", l.split_once("] ").map_or(l, |x| x.1)))
        .collect()
}

/// Opens `page` in Chromium and lists what is wrong with it (empty: nothing).
fn page_problems(exe: &Path, page: &Path) -> Vec<String> {
    page_check(exe, page).0
}

/// `page_problems` and the text of `#bvhlab-summary-bottom`: the bottom edge of the element
/// `#summary` in pixels at 1400x900 and the page's width, or `none`.
fn page_check(exe: &Path, page: &Path) -> (Vec<String>, String) {
    let html = std::fs::read_to_string(page).unwrap();
    let probe = page.with_file_name(".bvhlab-browser-check.html");
    let with_check = match html.rfind("</body>") {
        Some(i) => format!("{}{CHECK_SCRIPT}{}", &html[..i], &html[i..]),
        None => format!("{html}{CHECK_SCRIPT}"),
    };
    std::fs::write(&probe, with_check).unwrap();
    let args = [
        "--enable-logging=stderr".to_string(),
        "--virtual-time-budget=5000".to_string(),
        "--dump-dom".to_string(),
    ];
    let (dom, log) = chromium(exe, &args, &file_url(&probe));
    std::fs::remove_file(&probe).unwrap();
    let mut problems = console_errors(&log);
    let marker = format!("<pre id=\"{CHECK_ID}\">");
    match dom.find(&marker) {
        None => problems.push(format!(
            "the image check did not finish (no #{CHECK_ID} in the DOM after the virtual time budget)"
        )),
        Some(i) => {
            let rest = &dom[i + marker.len()..];
            let json = unescape(&rest[..rest.find("</pre>").unwrap_or(rest.len())]);
            let bad: Vec<String> = serde_json::from_str(&json)
                .unwrap_or_else(|e| panic!("#{CHECK_ID}: {e}: {json}"));
            problems.extend(bad.iter().map(|s| format!("<img src=\"{s}\">: did not load or decode")));
        }
    }
    problems.extend(link_problems(&dom, page));
    let marker = "<pre id=\"bvhlab-summary-bottom\">";
    let summary = dom
        .find(marker)
        .map(|i| {
            let rest = &dom[i + marker.len()..];
            rest[..rest.find("</pre>").unwrap_or(rest.len())].to_string()
        })
        .unwrap_or_else(|| "no check".into());
    (problems, summary)
}

/// Pages of a PDF: its `/Type /Page` objects (not `/Pages`).
fn pdf_pages(pdf: &[u8]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while let Some(off) = pdf[i..].windows(5).position(|w| w == b"/Type") {
        let mut j = i + off + 5;
        while j < pdf.len() && pdf[j].is_ascii_whitespace() {
            j += 1;
        }
        if pdf[j..].starts_with(b"/Page")
            && !pdf.get(j + 5).is_some_and(|c| c.is_ascii_alphanumeric())
        {
            n += 1;
        }
        i = j;
    }
    n
}

/// A 1x1 RGB PNG.
const PNG: [u8; 69] = [
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x90, 0x77, 0x53,
    0xde, 0x00, 0x00, 0x00, 0x0c, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0xf8, 0xcf, 0xc0, 0x00,
    0x00, 0x03, 0x01, 0x01, 0x00, 0xc9, 0xfe, 0x92, 0xef, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e,
    0x44, 0xae, 0x42, 0x60, 0x82,
];

const FIXTURE: &str = r##"<!DOCTYPE html>
<html><head><title>fixture</title><link rel="stylesheet" href="style.css"></head>
<body>
<nav><a href="#top">top</a> <a href="other.html#sec">other</a> <a href="plots/p%20q.png">plot</a>
<a href="https://example.invalid/">external</a></nav>
<h2 id="top">Top</h2>
<img src="a.png" alt="a"> <img src="plots/p q.png" alt="b">
<!-- <a href="commented-out.html"> -->
<script>var s = '<a href="in-a-script.html">';</script>
<!--EXTRA-->
</body></html>
"##;

/// The fixture page with `extra` inserted; `setup` may then break the directory.
fn fixture(extra: &str) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    std::fs::create_dir(p.join("plots")).unwrap();
    std::fs::write(p.join("a.png"), PNG).unwrap();
    std::fs::write(p.join("plots/p q.png"), PNG).unwrap();
    std::fs::write(p.join("style.css"), "body { font-family: sans-serif; }").unwrap();
    std::fs::write(
        p.join("other.html"),
        "<html><body><p id=\"sec\">x</p></body></html>",
    )
    .unwrap();
    std::fs::write(p.join("index.html"), FIXTURE.replace("<!--EXTRA-->", extra)).unwrap();
    d
}

#[test]
fn checker_catches_each_failure_kind() {
    let Some(exe) = browser_or_skip("checker_catches_each_failure_kind") else {
        return;
    };
    let clean = fixture("");
    let problems = page_problems(&exe, &clean.path().join("index.html"));
    assert!(problems.is_empty(), "the clean fixture: {problems:#?}");

    // Each case: extra HTML, what to break, and what the problems must mention.
    type Break = fn(&Path);
    let cases: [(&str, &str, Break, &[&str]); 6] = [
        (
            "deleted png",
            "",
            |d| std::fs::remove_file(d.join("a.png")).unwrap(),
            &["<img src=\"a.png\">: did not load", "a.png does not exist"],
        ),
        (
            "corrupt png",
            "",
            |d| std::fs::write(d.join("plots/p q.png"), b"not a png").unwrap(),
            &["<img src=\"plots/p q.png\">: did not load or decode"],
        ),
        (
            "bad href",
            "<a href=\"nowhere.html\">x</a>",
            |_| {},
            &["nowhere.html does not exist"],
        ),
        (
            "bad anchor",
            "<a href=\"#nope\">x</a>",
            |_| {},
            &["no element with id \"nope\" on the page"],
        ),
        (
            "bad anchor in another page",
            "<a href=\"other.html#gone\">x</a>",
            |_| {},
            &["no element with id \"gone\" in"],
        ),
        (
            "script error",
            "<script>throw 1</script>",
            |_| {},
            &["console: \"Uncaught 1\""],
        ),
    ];
    for (name, extra, break_it, expect) in cases {
        let d = fixture(extra);
        break_it(d.path());
        let problems = page_problems(&exe, &d.path().join("index.html"));
        for e in expect {
            assert!(
                problems.iter().any(|p| p.contains(e)),
                "{name}: expected a problem containing {e:?}, got {problems:#?}"
            );
        }
        eprintln!("{name}: caught: {problems:?}");
    }
}

#[test]
fn quick_report_in_headless_chromium() {
    let Some(exe) = browser_or_skip("quick_report_in_headless_chromium") else {
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let art = artifact_dir();
    let out = tempfile::tempdir().unwrap();
    let report = out.path().join("quick");
    // The cache lives in target/browser/cache: cold the first time, warm after.
    let cache = art.join("cache");
    let exp = root.join("experiments/quick.toml");
    let o = common::command(
        &[
            "sweep",
            exp.to_str().unwrap(),
            "--cache",
            cache.to_str().unwrap(),
            "--out",
            report.to_str().unwrap(),
        ],
        &root,
    )
    .output()
    .unwrap();
    let summary = common::ok(o, "quick sweep");
    let page = report.join("index.html");
    assert!(page.is_file(), "{summary}");

    let (problems, summary_box) = page_check(&exe, &page);

    let shot = art.join("first-screen.png");
    let _ = std::fs::remove_file(&shot);
    chromium(
        &exe,
        &[format!("--screenshot={}", shot.display())],
        &file_url(&page),
    );
    assert!(shot.is_file(), "no screenshot at {}", shot.display());

    // A4: the report sets no page size, so a copy with `@page { size: A4 }` is printed.
    let html = std::fs::read_to_string(&page).unwrap();
    let a4 = page.with_file_name(".bvhlab-a4.html");
    let style = "<style>@page { size: A4; }</style>";
    let with_a4 = match html.find("</head>") {
        Some(i) => format!("{}{style}{}", &html[..i], &html[i..]),
        None => format!("{style}{html}"),
    };
    std::fs::write(&a4, with_a4).unwrap();
    let pdf = art.join("quick-a4.pdf");
    let _ = std::fs::remove_file(&pdf);
    chromium(
        &exe,
        &[
            "--no-pdf-header-footer".to_string(),
            format!("--print-to-pdf={}", pdf.display()),
        ],
        &file_url(&a4),
    );
    let pages = pdf_pages(&std::fs::read(&pdf).unwrap());
    let lines = format!(
        "first screen (1400x900): {}\nsummary bottom, page width: {summary_box} px\nA4 print: {} ({pages} pages; target <= 25)\nproblems: {}\n",
        shot.display(),
        pdf.display(),
        problems.len()
    );
    std::fs::write(art.join("summary.txt"), &lines).unwrap();
    println!("{lines}");
    assert!(
        problems.is_empty(),
        "the quick report in Chromium: {problems:#?}"
    );
    // The summary is the first screen: it ends within 900 px, and the page is no wider than the
    // 1400 px window (issue 16).
    let (bottom, width) = summary_box
        .split_once(' ')
        .map(|(b, w)| (b.parse::<i64>().unwrap_or(i64::MAX), w.parse::<i64>().unwrap_or(i64::MAX)))
        .unwrap_or_else(|| panic!("no #summary in the report ({summary_box})"));
    assert!(bottom <= 900, "#summary ends at {bottom} px, below the first 1400x900 screen");
    assert!(width <= 1400, "the page is {width} px wide, wider than the 1400 px window");
    {
        assert!(
            pages <= 25,
            "the quick report prints on {pages} A4 pages (target <= 25)"
        );
    }
}

#[test]
fn pdf_page_count_ignores_the_pages_tree() {
    let pdf = b"1 0 obj << /Type /Pages /Kids [2 0 R 3 0 R] /Count 2 >> endobj\n\
                2 0 obj << /Type /Page /Parent 1 0 R >> endobj 3 0 obj <</Type/Page>> endobj";
    assert_eq!(pdf_pages(pdf), 2);
}
