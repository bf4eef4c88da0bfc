//! Helpers shared by the CLI integration tests that compare result tables.
#![allow(dead_code)]
use std::path::Path;
use std::process::{Command, Output};

/// `bvhlab ARGS` in `cwd`, with the cache and memory environment cleared.
pub fn command(args: &[&str], cwd: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bvhlab"));
    c.args(args)
        .current_dir(cwd)
        .env_remove("BVHLAB_CACHE")
        .env_remove("BVHLAB_MAX_MEMORY");
    c
}

/// The last stdout line of a run, as JSON (every command ends with its JSON summary).
pub fn json_line(o: &Output) -> serde_json::Value {
    let s = String::from_utf8_lossy(&o.stdout);
    let last = s
        .lines()
        .last()
        .unwrap_or_else(|| panic!("no stdout; stderr: {}", String::from_utf8_lossy(&o.stderr)));
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {last}"))
}

/// `json_line` of a run that must have succeeded.
pub fn ok(o: Output, what: &str) -> serde_json::Value {
    assert!(
        o.status.success(),
        "{what}: exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    json_line(&o)
}

/// Quoted-field-aware CSV reader.
pub fn parse_csv(text: &str) -> Vec<Vec<String>> {
    let mut rows = Vec::new();
    let (mut row, mut field, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => row.push(std::mem::take(&mut field)),
            ('\n', false) => {
                row.push(std::mem::take(&mut field));
                rows.push(std::mem::take(&mut row));
            }
            ('\r', false) => {}
            (c, _) => field.push(c),
        }
    }
    if !field.is_empty() || !row.is_empty() {
        row.push(field);
        rows.push(row);
    }
    rows
}

/// results.csv without the columns that depend on where and when a stage ran: timings, the
/// heat map path (inside the cache), the thread count and machine of the run.
pub fn untimed_rows(report: &Path) -> Vec<Vec<(String, String)>> {
    let text = std::fs::read_to_string(report.join("results.csv"))
        .unwrap_or_else(|e| panic!("{}: {e}", report.display()));
    let rows = parse_csv(&text);
    let header = rows[0].clone();
    let mut out: Vec<Vec<(String, String)>> = rows[1..]
        .iter()
        .map(|r| {
            header
                .iter()
                .zip(r)
                .filter(|(h, _)| {
                    !(h.contains("seconds")
                || h.contains("heap") // a measurement: parallel builds allocate in any order
                        || h.contains("mrays")
                        || h.contains("machine")
                        || h.starts_with("slowdown")
                        || h.starts_with("auto_search_slowdown")
                        || *h == "optimize_trace"
                        || *h == "heatmap"
                        || *h == "threads")
                })
                .map(|(h, v)| (h.clone(), v.clone()))
                .collect()
        })
        .collect();
    out.sort();
    out
}
