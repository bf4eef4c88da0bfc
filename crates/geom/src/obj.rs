//! Wavefront OBJ (and .obj.gz) through tobj: positions only, polygons triangulated.
//!
//! tobj does the parsing and fan triangulation, but its errors carry no line number and a few
//! malformed inputs slip through it (faces with fewer than three vertices become degenerate
//! triangles, polylines become triangles, some out-of-range texture/normal indices overflow).
//! So one light validation scan runs first: it checks every statement tobj would act on and
//! reports the first problem as `file:line: reason`. Only input that passed the scan reaches tobj.
use crate::{LoadError, Scene, Triangle};
use glam::Vec3;
use std::io::Read;
use std::path::Path;

/// Load an `.obj` or gzip-compressed `.obj.gz` file (detected by the gzip magic bytes, so a
/// misnamed file still loads). Non-finite triangles are dropped and counted; zero-area ones kept.
pub fn load_obj(path: &Path) -> Result<Scene, LoadError> {
    let err = |line: Option<usize>, reason: String| LoadError { file: path.to_path_buf(), line, reason };
    let raw = std::fs::read(path).map_err(|e| err(None, format!("cannot read file: {e}")))?;
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::with_capacity(raw.len() * 4);
        flate2::read::MultiGzDecoder::new(&raw[..])
            .read_to_end(&mut out)
            .map_err(|e| err(None, format!("bad gzip data: {e}")))?;
        out
    } else if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz")) {
        return Err(err(None, "not a gzip file (missing gzip header) despite the .gz extension".into()));
    } else {
        raw
    };
    parse_obj_bytes(&bytes).map_err(|(line, reason)| err(line, reason))
}

/// Parse OBJ text held in memory. Errors are (1-based line, reason).
pub fn parse_obj_bytes(bytes: &[u8]) -> Result<Scene, (Option<usize>, String)> {
    let text = match std::str::from_utf8(bytes) {
        Ok(t) => t,
        Err(e) => {
            let line = 1 + bytes[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count();
            return Err((Some(line), "invalid UTF-8 (binary data?)".into()));
        }
    };
    let scan = scan(text).map_err(|(l, r)| (Some(l), r))?;
    if scan.faces == 0 {
        return Err((None, format!("no triangles (no face statements; {} vertices)", scan.vertices)));
    }
    let filtered;
    let src: &str = if scan.needs_filter {
        filtered = filter(text);
        &filtered
    } else {
        text
    };

    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials are irrelevant to positions-only loading: never open .mtl files.
    let (models, _) = tobj::load_obj_buf(&mut src.as_bytes(), &opts, |_| Ok(Default::default()))
        .map_err(|e| (None, format!("OBJ parse error: {e}")))?;

    let n: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    let mut tris = Vec::with_capacity(n);
    for m in &models {
        let p = &m.mesh.positions;
        let vert = |i: u32| -> Option<Vec3> {
            let i = i as usize * 3;
            Some(Vec3::new(*p.get(i)?, *p.get(i + 1)?, *p.get(i + 2)?))
        };
        for f in m.mesh.indices.chunks_exact(3) {
            match (vert(f[0]), vert(f[1]), vert(f[2])) {
                (Some(a), Some(b), Some(c)) => tris.push(Triangle::new(a, b, c)),
                _ => return Err((None, "internal: tobj returned an index out of range".into())),
            }
        }
    }
    let scene = Scene::from_triangles(tris);
    if scene.triangles.is_empty() {
        return Err((
            None,
            format!("no triangles with finite coordinates ({} non-finite dropped)", scene.dropped_triangles),
        ));
    }
    Ok(scene)
}

struct ScanResult {
    vertices: usize,
    faces: usize,
    /// Lines tobj would mishandle are present (`l` polylines, `usemtl`, per-vertex colours).
    needs_filter: bool,
}

fn parse_floats(words: &mut std::str::SplitWhitespace, n: usize) -> bool {
    (0..n).all(|_| words.next().is_some_and(|w| w.parse::<f32>().is_ok()))
}

/// Validate everything tobj acts on; the first problem is returned as (line, reason).
fn scan(text: &str) -> Result<ScanResult, (usize, String)> {
    let (mut nv, mut nvt, mut nvn, mut faces) = (0usize, 0usize, 0usize, 0usize);
    let mut needs_filter = false;
    // Absolute indices may point forward (tobj resolves them after reading the whole file):
    // remember the first line reaching past what was defined so far, per kind.
    let mut forward: [Option<(usize, usize)>; 3] = [None; 3]; // (line, largest index on it)
    let mut max_ref = [0usize; 3];
    for (i, raw) in text.split('\n').enumerate() {
        let lineno = i + 1;
        let line = raw.strip_suffix('\r').unwrap_or(raw);
        let mut words = line.split_whitespace();
        let bad = |r: String| Err((lineno, r));
        match words.next() {
            Some("v") => {
                if !parse_floats(&mut words, 3) {
                    return bad(format!("vertex needs three numeric coordinates: {:?}", clip(line)));
                }
                let extra: Vec<&str> = words.collect();
                match extra.len() {
                    0 => {}
                    1 => match extra[0].parse::<f32>() {
                        Ok(w) if w == 0.0 => return bad("vertex weight w is zero".into()),
                        Ok(_) => {}
                        Err(_) => return bad(format!("vertex weight is not a number: {:?}", clip(extra[0]))),
                    },
                    3 => needs_filter = true, // colours: stripped, tobj misaligns mixed colour/no-colour
                    k => return bad(format!("vertex has {} values (expected 3, 4 or 6)", 3 + k)),
                }
                nv += 1;
            }
            Some("vt") => {
                if !parse_floats(&mut words, 2) {
                    return bad(format!("texture coordinate needs two numbers: {:?}", clip(line)));
                }
                nvt += 1;
            }
            Some("vn") => {
                if !parse_floats(&mut words, 3) {
                    return bad(format!("normal needs three numbers: {:?}", clip(line)));
                }
                nvn += 1;
            }
            Some("f") => {
                let counts = [nv, nvt, nvn];
                let mut k = 0usize;
                for w in words {
                    k += 1;
                    let mut parts = w.split('/');
                    for (kind, part) in parts.by_ref().take(3).enumerate() {
                        if part.is_empty() {
                            if kind == 0 {
                                return bad(format!("face vertex {w:?} has no position index"));
                            }
                            continue;
                        }
                        let what = ["vertex", "texture coordinate", "normal"][kind];
                        let x: i64 = match part.parse() {
                            Ok(x) => x,
                            Err(_) => return bad(format!("face index {part:?} in {w:?} is not an integer")),
                        };
                        let have = counts[kind];
                        if x == 0 {
                            return bad(format!("face {what} index 0 (OBJ indices start at 1)"));
                        } else if x < 0 {
                            if x.unsigned_abs() > have as u64 {
                                return bad(format!(
                                    "relative face {what} index {x} reaches before the first {what} \
                                     ({have} defined so far)"
                                ));
                            }
                        } else {
                            let x = usize::try_from(x).unwrap_or(usize::MAX);
                            if x > have && forward[kind].is_none() {
                                forward[kind] = Some((lineno, x));
                            }
                            max_ref[kind] = max_ref[kind].max(x);
                        }
                    }
                    if parts.next().is_some() {
                        return bad(format!("face vertex {w:?} has more than three '/'-separated indices"));
                    }
                }
                if k < 3 {
                    return bad(format!("face with {k} vertices (a face needs at least 3)"));
                }
                faces += 1;
            }
            Some("l") | Some("usemtl") => needs_filter = true,
            _ => {}
        }
    }
    // Forward references: valid only if the file eventually defines enough elements.
    let totals = [nv, nvt, nvn];
    for kind in 0..3 {
        if max_ref[kind] > totals[kind] {
            let what = ["vertex", "texture coordinate", "normal"][kind];
            // Find the first face line whose index exceeds the final total (rescan, error path only).
            let line = first_line_over(text, kind, totals[kind]).or(forward[kind].map(|f| f.0)).unwrap_or(0);
            return Err((
                line,
                format!("face {what} index out of range (the file defines {} {what}s)", totals[kind]),
            ));
        }
    }
    Ok(ScanResult { vertices: nv, faces, needs_filter })
}

fn first_line_over(text: &str, kind: usize, total: usize) -> Option<usize> {
    for (i, line) in text.split('\n').enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("f") {
            continue;
        }
        for w in words {
            if let Some(Ok(x)) = w.split('/').nth(kind).map(|p| p.parse::<i64>()) {
                if x > 0 && x as u64 > total as u64 {
                    return Some(i + 1);
                }
            }
        }
    }
    None
}

/// Copy of the text with lines tobj mishandles neutralised, keeping line numbering:
/// polylines and material switches become comments, vertex colours are cut off.
fn filter(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for (i, raw) in text.split('\n').enumerate() {
        if i > 0 {
            out.push('\n');
        }
        let mut words = raw.split_whitespace();
        match words.next() {
            Some("l") | Some("usemtl") => out.push('#'),
            Some("v") => {
                let w: Vec<&str> = words.collect();
                if w.len() == 6 {
                    out.push_str("v ");
                    out.push_str(&w[..3].join(" "));
                } else {
                    out.push_str(raw);
                }
            }
            _ => out.push_str(raw),
        }
    }
    out
}

fn clip(s: &str) -> String {
    s.chars().take(60).collect()
}
