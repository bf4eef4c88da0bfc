//! Wavefront OBJ (and .obj.gz) through tobj: positions only, polygons triangulated.
//!
//! tobj does the parsing and fan triangulation, but its errors carry no line number and a few
//! malformed inputs slip through it (faces with fewer than three vertices become degenerate
//! triangles, polylines become triangles, some out-of-range texture/normal indices overflow).
//! So one light validation scan runs first: it checks every statement tobj would act on and
//! reports the first problem as `file:line: reason`. Only input that passed the scan reaches tobj.
use crate::{LoadError, Scene, Triangle};
use glam::Vec3;
use std::io::{BufRead, Read};
use std::path::Path;
use std::sync::mpsc::{Receiver, SyncSender};

/// Load an `.obj` or gzip-compressed `.obj.gz` file (detected by the gzip magic bytes, so a
/// misnamed file still loads). Non-finite triangles are dropped and counted; zero-area ones kept.
pub fn load_obj(path: &Path) -> Result<Scene, LoadError> {
    let err = |line: Option<usize>, reason: String| LoadError {
        file: path.to_path_buf(),
        line,
        reason,
    };
    let file =
        std::fs::File::open(path).map_err(|e| err(None, format!("cannot open file: {e}")))?;
    let mut file = std::io::BufReader::with_capacity(1 << 16, file);
    let head = file
        .fill_buf()
        .map_err(|e| err(None, format!("cannot read file: {e}")))?;
    let result = if head.starts_with(&[0x1f, 0x8b]) {
        parse_obj_reader(flate2::bufread::MultiGzDecoder::new(file))
    } else if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gz"))
    {
        return Err(err(
            None,
            "not a gzip file (missing gzip header) despite the .gz extension".into(),
        ));
    } else {
        parse_obj_reader(file)
    };
    result.map_err(|(line, reason)| err(line, reason))
}

/// Parse OBJ text held in memory. Errors are (1-based line, reason).
pub fn parse_obj_bytes(bytes: &[u8]) -> Result<Scene, (Option<usize>, String)> {
    parse_obj_reader(bytes)
}

/// Parse OBJ text from a reader. Errors are (1-based line, reason).
///
/// Two threads: one reads (and gunzips) and validates blocks of whole lines, and hands each
/// block on only once it passed validation (with the lines tobj mishandles neutralised, see
/// [`filter`]); tobj parses the validated blocks as they arrive. So tobj never sees input the
/// scan rejected, reading + validation overlap with parsing, and the text is never held whole
/// (it was, until 2026-11-27: 33 MB of the dragon's 160 MB peak while loading).
pub fn parse_obj_reader<R: Read + Send>(reader: R) -> Result<Scene, (Option<usize>, String)> {
    // Other fields exist only under tobj features (merging, reordering); keep them at default.
    #[allow(clippy::needless_update)]
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials are irrelevant to positions-only loading: never open .mtl files.
    let run_tobj = |mut r: &mut dyn BufRead| {
        tobj::load_obj_buf(&mut r, &opts, |_| Ok(Default::default()))
            .map_err(|e| (None, format!("OBJ parse error: {e}")))
    };
    let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<u8>>(8);
    let (produced, streamed) = std::thread::scope(|s| {
        let producer = s.spawn(move || produce(reader, tx));
        let mut chan = ChannelReader {
            rx,
            buf: Vec::new(),
            pos: 0,
        };
        let streamed = run_tobj(&mut chan);
        // Drop the receiver before joining so a producer blocked on a full channel wakes up.
        drop(chan);
        let produced = producer
            .join()
            .unwrap_or_else(|_| Err((None, "internal: reader thread panicked".into())));
        (produced, streamed)
    });
    let scan = produced?;
    if scan.faces == 0 {
        return Err((
            None,
            format!(
                "no triangles (no face statements; {} vertices)",
                scan.vertices
            ),
        ));
    }
    let models = streamed?.0;

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
    drop(models);
    let scene = Scene::from_triangles(tris);
    release_freed_memory();
    if scene.triangles.is_empty() {
        return Err((
            None,
            format!(
                "no triangles with finite coordinates ({} non-finite dropped)",
                scene.dropped_triangles
            ),
        ));
    }
    Ok(scene)
}

/// Hands the memory loading freed back to the system. glibc keeps freed blocks in the arena of the
/// thread that allocated them (the reader's 1 MiB blocks, tobj's growing vectors), resident: 5-15 MB
/// on the dragon, a different amount each run, counted in every later peak (issue 19.4's peak RSS
/// per builder). Elsewhere a no-op.
fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory of the allocator's arenas to the system; it
    // touches no live allocation.
    unsafe {
        libc::malloc_trim(0);
    }
}

type LineErr = (Option<usize>, String);

/// Read everything, validate block by block (whole lines only), forward validated blocks to tobj
/// (filtered once a line needing it was seen: [`filter`] is line by line). Keeps only the lines not
/// yet validated. Returns the scan result.
fn produce<R: Read>(mut reader: R, tx: SyncSender<Vec<u8>>) -> Result<ScanResult, LineErr> {
    const BLOCK: usize = 1 << 20;
    let mut tx = Some(tx);
    let mut text: Vec<u8> = Vec::new();
    let mut scanner = Scanner::default();
    let mut done = 0usize; // bytes of `text` already validated and forwarded
    let mut eof = false;
    let mut first = true;
    while !eof {
        // Drop what was forwarded: only an unfinished line stays.
        text.drain(..done);
        done = 0;
        let start = text.len();
        text.resize(start + BLOCK, 0);
        let mut filled = start;
        while filled < text.len() {
            match reader.read(&mut text[filled..]) {
                Ok(0) => {
                    eof = true;
                    break;
                }
                Ok(k) => filled += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                    return Err((
                        None,
                        format!(
                            "truncated gzip file: the compressed stream ends after {filled} bytes of OBJ text ({e})"
                        ),
                    ))
                }
                Err(e) => {
                    return Err((
                        None,
                        format!("read error (truncated or corrupt gzip?): {e}"),
                    ))
                }
            }
        }
        text.truncate(filled);
        // A UTF-8 byte-order mark (written by some Windows tools) is not part of the first
        // statement: left in, it hid the first line from the scan and from tobj.
        if first && text.starts_with(b"\xef\xbb\xbf") {
            text.drain(..3);
        }
        first = false;
        // Validate up to the last complete line (everything at end of input).
        let end = if eof {
            text.len()
        } else {
            // Bytes before `start` held no newline past `done`: search only the new data.
            match text[start.max(done)..].iter().rposition(|&b| b == b'\n') {
                Some(i) => start.max(done) + i + 1,
                None => {
                    // One long line so far: fail early on binary data instead of reading it all.
                    if let Err(e) = std::str::from_utf8(&text[done..]) {
                        if e.error_len().is_some() {
                            return Err((
                                Some(scanner.line + 1),
                                "invalid UTF-8 (binary data?)".into(),
                            ));
                        }
                    }
                    continue;
                }
            }
        };
        let block = &text[done..end];
        let chunk = match std::str::from_utf8(block) {
            Ok(t) => t,
            Err(e) => {
                let line = scanner.line
                    + 1
                    + block[..e.valid_up_to()]
                        .iter()
                        .filter(|&&b| b == b'\n')
                        .count();
                return Err((Some(line), "invalid UTF-8 (binary data?)".into()));
            }
        };
        // tobj resolves an object's face indices when the object ends: a new object may start
        // here only if no face before refers to a vertex (texture coordinate, normal) not yet
        // defined (absolute indices may point forward; `forward_references_resolve_against_the_
        // whole_file`).
        let cut = scanner.resolved();
        scanner.feed(chunk).map_err(|(l, r)| (Some(l), r))?;
        if let Some(t) = &tx {
            // Once a line needing a rewrite was seen (it may be in this block), every block goes
            // through the line-by-line filter; before, none needed it.
            // Each block starts a new object for tobj (when `cut`): it holds an object's faces
            // (about 80 bytes each) until the object ends, which for a one-object file was the
            // whole file (70 MB of the dragon's 130 MB loading peak); per block they are at most a
            // few MB. The triangles and their order are unchanged (faces index the global vertex
            // list).
            let mut out = Vec::with_capacity(PART.len() + block.len());
            if cut {
                out.extend_from_slice(PART);
            }
            if scanner.needs_filter {
                out.extend_from_slice(filter(chunk).as_bytes());
            } else {
                out.extend_from_slice(block);
            }
            if t.send(out).is_err() {
                tx = None; // tobj stopped early (its own error); the scan still decides
            }
        }
        done = end;
    }
    scanner.finish().map_err(|(l, r)| (Some(l), r))
}

/// The object statement [`produce`] puts before every block it forwards to tobj.
const PART: &[u8] = b"o bvhlab_block\n";

/// `BufRead` over the blocks arriving from the validating thread; the closed channel is EOF.
struct ChannelReader {
    rx: Receiver<Vec<u8>>,
    buf: Vec<u8>,
    pos: usize,
}

impl Read for ChannelReader {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let avail = self.fill_buf()?;
        let k = avail.len().min(out.len());
        out[..k].copy_from_slice(&avail[..k]);
        self.consume(k);
        Ok(k)
    }
}

impl BufRead for ChannelReader {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        while self.pos >= self.buf.len() {
            match self.rx.recv() {
                Ok(b) => {
                    self.buf = b;
                    self.pos = 0;
                }
                Err(_) => return Ok(&[]),
            }
        }
        Ok(&self.buf[self.pos..])
    }
    fn consume(&mut self, amt: usize) {
        self.pos = (self.pos + amt).min(self.buf.len());
    }
}

struct ScanResult {
    vertices: usize,
    faces: usize,
}

fn parse_floats(words: &mut std::str::SplitWhitespace, n: usize) -> bool {
    (0..n).all(|_| words.next().is_some_and(|w| w.parse::<f32>().is_ok()))
}

/// Absolute indices above this are rejected at once: no file is that large, and it keeps tobj's
/// unchecked `index * 3 + 2` style arithmetic far from overflow.
const MAX_INDEX: u64 = 1 << 40;

/// Validates everything tobj acts on, block by block; the first problem is (line, reason).
#[derive(Default)]
struct Scanner {
    /// Lines seen so far.
    line: usize,
    /// Elements defined so far: positions, texture coordinates, normals.
    counts: [usize; 3],
    faces: usize,
    needs_filter: bool,
    /// Largest absolute index referenced, per kind. Absolute indices may point forward (tobj
    /// resolves them after reading the whole file), so they are checked in `finish`.
    max_ref: [u64; 3],
    /// (kind, index, line) of each absolute index beyond what was defined when it was read and
    /// above every index of its kind before it: the only ones that can be the first out of range
    /// at the end, kept to name its line.
    forward: Vec<(usize, u64, usize)>,
    /// Faces since the last `o` or `g` statement that ended an object (tobj ends one there when it
    /// has faces, and resolves their indices then).
    object_faces: usize,
}

const KIND: [&str; 3] = ["vertex", "texture coordinate", "normal"];
const KINDS: [&str; 3] = ["vertices", "texture coordinates", "normals"];

impl Scanner {
    /// `chunk` holds whole lines (only the last chunk of a file may lack the final newline).
    fn feed(&mut self, chunk: &str) -> Result<(), (usize, String)> {
        for raw in chunk.split_inclusive('\n') {
            self.line += 1;
            let line = raw.strip_suffix('\n').unwrap_or(raw);
            let line = line.strip_suffix('\r').unwrap_or(line);
            self.line_ok(line).map_err(|r| (self.line, r))?;
        }
        Ok(())
    }

    fn line_ok(&mut self, line: &str) -> Result<(), String> {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                if !parse_floats(&mut words, 3) {
                    return Err(format!(
                        "vertex needs three numeric coordinates: {:?}",
                        clip(line)
                    ));
                }
                let extra: Vec<&str> = words.collect();
                match extra.len() {
                    0 => {}
                    1 => match extra[0].parse::<f32>() {
                        Ok(0.0) => return Err("vertex weight w is zero".into()),
                        Ok(_) => {}
                        Err(_) => {
                            return Err(format!(
                                "vertex weight is not a number: {:?}",
                                clip(extra[0])
                            ))
                        }
                    },
                    // Colours: cut off before tobj, which misaligns files mixing coloured and plain vertices.
                    3 => self.needs_filter = true,
                    k => return Err(format!("vertex has {} values (expected 3, 4 or 6)", 3 + k)),
                }
                self.counts[0] += 1;
            }
            Some("vt") => {
                if !parse_floats(&mut words, 2) {
                    return Err(format!(
                        "texture coordinate needs two numbers: {:?}",
                        clip(line)
                    ));
                }
                self.counts[1] += 1;
            }
            Some("vn") => {
                if !parse_floats(&mut words, 3) {
                    return Err(format!("normal needs three numbers: {:?}", clip(line)));
                }
                self.counts[2] += 1;
            }
            Some("f") => {
                let mut k = 0usize;
                for w in words {
                    k += 1;
                    let mut parts = w.split('/');
                    for (kind, part) in parts.by_ref().take(3).enumerate() {
                        if part.is_empty() {
                            if kind == 0 {
                                return Err(format!(
                                    "face vertex {:?} has no position index",
                                    clip(w)
                                ));
                            }
                            continue;
                        }
                        let what = KIND[kind];
                        let Ok(x) = part.parse::<i64>() else {
                            return Err(format!("face index {:?} is not an integer", clip(part)));
                        };
                        let have = self.counts[kind];
                        if x == 0 {
                            return Err(format!("face {what} index 0 (OBJ indices start at 1)"));
                        } else if x < 0 {
                            if x.unsigned_abs() > have as u64 {
                                return Err(format!(
                                    "relative face {what} index {x} reaches before the first {what} \
                                     ({have} defined so far)"
                                ));
                            }
                        } else if x as u64 > MAX_INDEX {
                            return Err(format!("face {what} index {x} is out of range"));
                        } else {
                            // Only a new largest index can be the first one out of range at the
                            // end (every earlier index is smaller), so only those are kept.
                            if x as u64 > have as u64 && x as u64 > self.max_ref[kind] {
                                self.forward.push((kind, x as u64, self.line));
                            }
                            self.max_ref[kind] = self.max_ref[kind].max(x as u64);
                        }
                    }
                    if parts.next().is_some() {
                        return Err(format!(
                            "face vertex {:?} has more than three '/'-separated indices",
                            clip(w)
                        ));
                    }
                }
                if k < 3 {
                    return Err(format!("face with {k} vertices (a face needs at least 3)"));
                }
                self.faces += 1;
                self.object_faces += 1;
            }
            // tobj ends the object here and resolves its faces' indices: one still pointing ahead
            // would fail there as "index out of bounds" without a line; name it instead.
            Some("o") | Some("g") if self.object_faces > 0 => {
                if let Some(&(kind, x, at)) = self.unresolved() {
                    return Err(format!(
                        "face on line {at} refers to {} {x}, which is defined only after its object ends \
                         here ({} defined so far): an index may point ahead only within its object",
                        KIND[kind], self.counts[kind]
                    ));
                }
                self.object_faces = 0;
            }
            // Polylines would be fanned into triangles by tobj, and `usemtl` without a name is a
            // tobj error: neither matters for positions only, so both become comments.
            Some("l") | Some("usemtl") => self.needs_filter = true,
            _ => {}
        }
        Ok(())
    }

    /// Check forward references against the final totals (the first line with one out of range).
    /// Whether every index read so far refers to an element already defined.
    fn resolved(&self) -> bool {
        self.max_ref.iter().zip(self.counts).all(|(&r, c)| r <= c as u64)
    }

    /// The first remembered forward index still beyond what is defined: (kind, index, line).
    fn unresolved(&self) -> Option<&(usize, u64, usize)> {
        if self.resolved() {
            return None;
        }
        self.forward.iter().find(|&&(k, x, _)| x > self.counts[k] as u64)
    }

    fn finish(&self) -> Result<ScanResult, (usize, String)> {
        for (kind, &total) in self.counts.iter().enumerate() {
            if self.max_ref[kind] > total as u64 {
                let what = KIND[kind];
                let line = self
                    .forward
                    .iter()
                    .find(|&&(k, x, _)| k == kind && x > total as u64)
                    .map_or(self.line, |f| f.2);
                let defined = if total == 1 { what } else { KINDS[kind] };
                return Err((
                    line,
                    format!("face {what} index out of range (the file defines {total} {defined})"),
                ));
            }
        }
        Ok(ScanResult {
            vertices: self.counts[0],
            faces: self.faces,
        })
    }
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
