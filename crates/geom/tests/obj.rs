//! OBJ loading: triangulation, gzip, non-finite handling, and file:line errors for malformed input.
use bvhlab_geom::obj::load_obj;
use bvhlab_geom::LoadError;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

static COUNTER: AtomicUsize = AtomicUsize::new(0);

/// A unique temp file holding `bytes` (removed on drop).
struct Tmp(PathBuf);
impl Drop for Tmp {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}
fn tmp(name: &str, bytes: &[u8]) -> Tmp {
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let p = std::env::temp_dir().join(format!(
        "bvhlab-geom-test-{}-{n}-{name}",
        std::process::id()
    ));
    std::fs::write(&p, bytes).unwrap();
    Tmp(p)
}
fn gz(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}
fn load_str(s: &str) -> Result<bvhlab_geom::Scene, LoadError> {
    let f = tmp("t.obj", s.as_bytes());
    load_obj(&f.0)
}
fn err_line(s: &str) -> (Option<usize>, String) {
    match load_str(s) {
        Ok(sc) => panic!(
            "expected an error for {s:?}, got {} triangles",
            sc.triangles.len()
        ),
        Err(e) => {
            // The message names the file and (when known) the line.
            let msg = e.to_string();
            assert!(msg.contains("t.obj"), "{msg}");
            if let Some(l) = e.line {
                assert!(msg.contains(&format!(":{l}:")), "{msg}");
            }
            (e.line, e.reason)
        }
    }
}

const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";

#[test]
fn triangle_and_quad_and_polygon_triangulated() {
    let s = load_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(s.triangles.len(), 1);
    assert_eq!(s.triangles[0].v[1].x, 1.0);
    let s = load_str(QUAD).unwrap();
    assert_eq!(s.triangles.len(), 2);
    let area: f32 = s.triangles.iter().map(|t| t.area()).sum();
    assert!((area - 1.0).abs() < 1e-6);
    // Hexagon with v/vt/vn syntax, relative indices, a group and CRLF line ends.
    let hex = "o hex\r\nvt 0 0\r\nvn 0 0 1\r\n".to_string()
        + &(0..6)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 6.0;
                format!("v {} {} 0\r\n", a.cos(), a.sin())
            })
            .collect::<String>()
        + "f -6/1/1 -5/1/1 -4//1 -3/1 -2 -1\r\n";
    let s = load_str(&hex).unwrap();
    assert_eq!(s.triangles.len(), 4);
    let area: f32 = s.triangles.iter().map(|t| t.area()).sum();
    assert!((area - 3.0 * 3f32.sqrt() / 2.0).abs() < 1e-5, "{area}");
}

#[test]
fn gzip_works_and_matches_plain() {
    let plain = load_str(QUAD).unwrap();
    let f = tmp("q.obj.gz", &gz(QUAD.as_bytes()));
    let z = load_obj(&f.0).unwrap();
    assert_eq!(plain.triangles, z.triangles);
    // Concatenated gzip members are one stream (MultiGzDecoder).
    let mut two = gz(b"v 0 0 0\nv 1 0 0\n");
    two.extend(gz(b"v 0 1 0\nf 1 2 3\n"));
    let f = tmp("two.obj.gz", &two);
    assert_eq!(load_obj(&f.0).unwrap().triangles.len(), 1);
}

#[test]
fn bad_gzip_is_an_error() {
    let full = gz(QUAD.repeat(50).as_bytes());
    let f = tmp("trunc.obj.gz", &full[..full.len() / 2]);
    let e = load_obj(&f.0).unwrap_err();
    assert!(e.reason.contains("gzip"), "{e}");
    let f = tmp("notgz.obj.gz", QUAD.as_bytes());
    let e = load_obj(&f.0).unwrap_err();
    assert!(e.reason.contains("gzip"), "{e}");
}

#[test]
fn missing_file_is_an_error() {
    let e = load_obj(std::path::Path::new("/nonexistent/dir/x.obj")).unwrap_err();
    assert_eq!(e.file, PathBuf::from("/nonexistent/dir/x.obj"));
    assert!(e.to_string().contains("/nonexistent/dir/x.obj"));
}

#[test]
fn non_finite_dropped_and_counted_zero_area_kept() {
    let s = load_str(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 0 inf 0\nv 1e39 0 0\nv 2 0 0\n\
         f 1 2 3\nf 1 2 4\nf 5 1 2\nf 6 2 3\nf 1 2 7\nf 1 1 1\n",
    )
    .unwrap();
    assert_eq!(s.dropped_triangles, 3);
    // Kept: the good one, the collinear one (1 2 7) and the point-like one (1 1 1).
    assert_eq!(s.triangles.len(), 3);
    assert_eq!(s.triangles.iter().filter(|t| t.area() == 0.0).count(), 2);
    assert!(s.triangles.iter().all(|t| t.is_finite()));
}

#[test]
fn only_non_finite_triangles_is_an_error() {
    let (line, reason) = err_line("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert_eq!(line, None);
    assert!(reason.contains("no triangles"), "{reason}");
}

#[test]
fn no_triangles_is_an_error() {
    for s in [
        "",
        "\n\n",
        "# just a comment\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\n",
        "v 0 0 0\nv 1 0 0\nl 1 2\n",
    ] {
        let (_, reason) = err_line(s);
        assert!(reason.contains("no triangles"), "{s:?}: {reason}");
    }
}

#[test]
fn polylines_are_not_triangles() {
    // tobj would fan a 3-point polyline into a triangle; we ignore `l` for triangles.
    let s = load_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\nusemtl\nf 1 2 3\n").unwrap();
    assert_eq!(s.triangles.len(), 1);
}

#[test]
fn vertex_colours_are_ignored() {
    let s = load_str("v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(s.triangles.len(), 1);
    assert_eq!(s.triangles[0].v[2].y, 1.0);
}

#[test]
fn malformed_lines_are_reported_with_their_line() {
    let v3 = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"; // lines 1..=3, so line 4 is the first added
    let cases: &[(&str, usize, &str)] = &[
        ("f 1 2 0\n", 4, "index 0"),
        ("f 1 2 4\n", 4, "out of range"),
        ("f 1 2 99999999999999999999\n", 4, "integer"),
        ("f 1 2 9223372036854775807\n", 4, "out of range"),
        ("f 1 2 -4\n", 4, "before the first"),
        ("f 1 2 -9223372036854775808\n", 4, "before the first"),
        ("f 1 2 x\n", 4, "not an integer"),
        ("f 1 2\n", 4, "2 vertices"),
        ("f\n", 4, "0 vertices"),
        ("f 1 2 3/1\n", 4, "texture coordinate index out of range"),
        ("f 1 2 3//7\n", 4, "normal index out of range"),
        ("f 1 2 3/0/0\n", 4, "index 0"),
        ("f 1 2 3/1/1/1\n", 4, "three"),
        ("f 1 2 /1\n", 4, "no position"),
        ("v 1 2 abc\nf 1 2 3\n", 4, "numeric"),
        ("v 1 2\nf 1 2 3\n", 4, "numeric"),
        ("v 1 2 3 0\nf 1 2 3\n", 4, "zero"),
        ("v 1 2 3 -0.0\nf 1 2 3\n", 4, "zero"),
        ("v 1 2 3 4 5\nf 1 2 3\n", 4, "5 values"),
        ("vt x y\nf 1 2 3\n", 4, "texture"),
        ("vn 1 2\nf 1 2 3\n", 4, "normal"),
        ("f 1 2 3\n\n\n# c\nf 1 2 5\n", 8, "out of range"),
    ];
    for (tail, line, what) in cases {
        let (l, reason) = err_line(&format!("{v3}{tail}"));
        assert_eq!(l, Some(*line), "{tail:?}: {reason}");
        assert!(reason.contains(what), "{tail:?}: {reason:?} lacks {what:?}");
    }
}

#[test]
fn forward_references_resolve_against_the_whole_file() {
    // tobj accepts absolute indices to vertices defined later; so do we.
    let s = load_str("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n").unwrap();
    assert_eq!(s.triangles.len(), 1);
    let (l, _) = err_line("f 1 2 3\nv 0 0 0\nv 1 0 0\nf 1 2 4\nv 0 1 0\n");
    assert_eq!(l, Some(4));
    // Not past the end of the face's object, where tobj resolves it: named with both lines.
    let (l, reason) = err_line("v 0 0 0\nf 1 2 3\ng next\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    assert_eq!(l, Some(3), "{reason}");
    assert!(reason.contains("line 2") && reason.contains("vertex 2"), "{reason}");
    // An `o` or `g` before any face of its object ends nothing.
    let s = load_str("o a\nf 1 2 3\no b\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    assert!(s.is_err());
    let s = load_str("v 0 0 0\no a\ng b\nf 1 2 3\nv 1 0 0\nv 0 1 0\no c\nf 1 2 3\n").unwrap();
    assert_eq!(s.triangles.len(), 2);
}

#[test]
fn binary_junk_is_an_error_not_a_panic() {
    let mut junk = b"v 0 0 0\nv 1 0 0\n".to_vec();
    junk.extend((0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8));
    let f = tmp("junk.obj", &junk);
    let e = load_obj(&f.0).unwrap_err();
    assert!(e.line.is_some_and(|l| l >= 3), "{e}");
    // Pseudo-random printable garbage built from OBJ-ish tokens: must never panic.
    let toks = [
        "v", "f", "vt", "vn", "l", "o", "g", "usemtl", "1", "-1", "0", "2/1", "3//2", "1/2/3",
        "nan", "1e39", "-", "/", "//", "x", "#", "\n", "\n", " ", "99", "-7", "1.5", "s",
    ];
    let mut x = 12345u64;
    for _ in 0..300 {
        let mut s = String::new();
        for _ in 0..60 {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s.push_str(toks[(x >> 33) as usize % toks.len()]);
            s.push(' ');
        }
        let _ = load_str(&s);
    }
}

#[test]
fn many_lines_across_stream_blocks() {
    // More than one 1 MiB block: line numbers must continue across blocks.
    let mut s = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    let n = 200_000;
    for _ in 0..n {
        s.push_str("f 1 2 3\n");
    }
    assert!(s.len() > 1 << 20);
    assert_eq!(load_str(&s).unwrap().triangles.len(), n);
    s.push_str("f 1 2 9\n");
    let (l, _) = err_line(&s);
    assert_eq!(l, Some(3 + n + 1));
    let f = tmp("big.obj.gz", &gz(s.as_bytes()));
    assert_eq!(load_obj(&f.0).unwrap_err().line, Some(3 + n + 1));
}

#[test]
fn stanford_bunny_if_present() {
    let p = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/scenes/stanford_bunny.obj.gz"
    );
    if !std::path::Path::new(p).exists() {
        eprintln!("skipping: {p} not found");
        return;
    }
    let s = load_obj(std::path::Path::new(p)).unwrap();
    assert_eq!(s.triangles.len(), 69_451);
    assert_eq!(s.dropped_triangles, 0);
    let b = s.bounds();
    assert!(
        b.extent().min_element() > 0.0 && b.extent().max_element() < 1.0,
        "{b:?}"
    );
}

#[test]
fn long_binary_line_fails_early_with_its_line() {
    // 3 MiB of non-UTF-8 bytes without a newline, after two good lines.
    let mut junk = b"v 0 0 0\nv 1 0 0\n".to_vec();
    junk.extend(std::iter::repeat_n(0xffu8, 3 << 20));
    let f = tmp("longjunk.obj", &junk);
    let e = load_obj(&f.0).unwrap_err();
    assert_eq!(e.line, Some(3), "{e}");
    // A long but valid line is fine (many vertices of one huge polygon).
    let mut s = String::new();
    let k = 150_000;
    for i in 0..k {
        s.push_str(&format!("v {i} {} 0\n", (i * i) % 7));
    }
    s.push('f');
    for i in 1..=k {
        s.push_str(&format!(" {i}"));
    }
    s.push('\n');
    let f = tmp("longline.obj", s.as_bytes());
    assert_eq!(load_obj(&f.0).unwrap().triangles.len(), k - 2);
}

/// Issue 15: a UTF-8 byte-order mark made the first line vanish ("the file defines 2 vertexs").
#[test]
fn byte_order_mark_is_skipped() {
    let bom = format!("\u{feff}{QUAD}");
    let s = load_str(&bom).unwrap();
    assert_eq!(s.triangles, load_str(QUAD).unwrap().triangles);
    // Also gzip-compressed, and with the BOM right before a face.
    let f = tmp("bom.obj.gz", &gz(bom.as_bytes()));
    assert_eq!(load_obj(&f.0).unwrap().triangles.len(), 2);
    let s = load_str("\u{feff}v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(s.triangles.len(), 1);
    // A BOM elsewhere is still text on its line, not a statement: the line numbers stay right.
    let (line, reason) = err_line("v 0 0 0\nv 1 0 0\n\u{feff}v 0 1 0\nf 1 2 3\n");
    assert_eq!(line, Some(4), "{reason}");
    assert!(reason.contains("the file defines 2 vertices"), "{reason}");
}

#[test]
fn out_of_range_counts_are_plural_words() {
    for (text, needle) in [
        ("v 0 0 0\nf 1 2 3\n", "defines 1 vertex)"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/2\nvt 0 0\n",
            "defines 1 texture coordinate)",
        ),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 1 0\nf 1 2 3//3\n",
            "defines 2 normals)",
        ),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1\n",
            "defines 0 texture coordinates)",
        ),
    ] {
        let (_, reason) = err_line(text);
        assert!(reason.contains(needle), "{needle}: {reason}");
        assert!(
            !reason.contains("vertexs") && !reason.contains("normals)s"),
            "{reason}"
        );
    }
}

/// Issue 15: a truncated `.obj.gz` says so (and how much text it held).
#[test]
fn truncated_gzip_says_truncated() {
    let full = gz(QUAD.repeat(2000).as_bytes());
    let f = tmp("cut.obj.gz", &full[..full.len() / 2]);
    let e = load_obj(&f.0).unwrap_err();
    assert!(e.reason.starts_with("truncated gzip file"), "{e}");
    assert!(e.to_string().contains("cut.obj.gz"), "{e}");
}

/// The text streams to tobj in blocks of 1 MiB and is never held whole; lines tobj mishandles
/// (vertex colours, `usemtl`, polylines) are filtered block by block from the first one on. A file
/// of several blocks with such lines only in its later blocks loads exactly as the same file
/// without them, and an index out of range in its last block is reported at its line.
#[test]
fn multi_block_files_filter_late_lines_and_report_late_errors() {
    let n: usize = 60_000; // ~1.6 MB of vertex lines: two blocks at least
    let mut plain = String::new();
    let mut marked = String::new();
    for i in 0..n {
        let v = format!("v {} {} {}", i % 97, (i / 97) % 89, i / 8633);
        plain.push_str(&v);
        plain.push('\n');
        marked.push_str(&v);
        // Colours only on the last third, a material switch and a polyline near the end.
        marked.push_str(if i > 2 * n / 3 { " 0.5 0.5 0.5\n" } else { "\n" });
        if i == n - 10 {
            marked.push_str("usemtl red\nl 1 2 3\n");
            plain.push_str("# c\n# c\n");
        }
    }
    let faces: String = (1..n - 2).step_by(3).map(|i| format!("f {} {} {}\n", i, i + 1, i + 2)).collect();
    plain.push_str(&faces);
    marked.push_str(&faces);
    let (a, b) = (load_str(&plain).unwrap(), load_str(&marked).unwrap());
    assert_eq!(a.triangles.len(), (n - 3).div_ceil(3));
    assert_eq!(a.triangles, b.triangles);
    // A forward index beyond the file's vertices, on the last line.
    let lines = marked.lines().count();
    let bad = format!("{marked}f 1 2 {}\n", n + 5);
    let (line, reason) = err_line(&bad);
    assert_eq!(line, Some(lines + 1), "{reason}");
    assert!(reason.contains("out of range"), "{reason}");
}

#[test]
fn forward_references_across_blocks_load_in_order() {
    // Faces first (well over one 1 MiB block), then their vertices, then more faces and vertices:
    // the loader hands tobj block after block and may end tobj's object only where no face
    // refers ahead; the triangles are the ones of the same faces after their vertices.
    let n: usize = 200_000;
    let faces: String = (1..n - 2).step_by(3).map(|i| format!("f {} {} {}\n", i, i + 1, i + 2)).collect();
    let verts: String = (0..n).map(|i| format!("v {} {} {}\n", i % 97, (i / 97) % 89, i / 8633)).collect();
    let more_faces: String = (n + 1..2 * n - 2).step_by(3).map(|i| format!("f {} {} {}\n", i, i + 1, i + 2)).collect();
    let ahead = format!("{faces}{verts}{more_faces}{verts}");
    let behind = format!("{verts}{faces}{verts}{more_faces}");
    assert!(faces.len() > 1 << 20 && more_faces.len() > 1 << 20);
    let (a, b) = (load_str(&ahead).unwrap(), load_str(&behind).unwrap());
    assert_eq!(a.triangles.len(), 2 * (n - 3).div_ceil(3));
    assert_eq!(a.triangles, b.triangles);
}
