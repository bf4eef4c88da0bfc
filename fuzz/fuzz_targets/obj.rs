//! Arbitrary bytes through the OBJ loader: as plain text, wrapped in a gzip stream (.obj.gz), and
//! raw bytes fed to the gzip path (corrupt or missing gzip headers); in memory and through the file
//! loader (the first byte picks the path). Every input gives Ok (a non-empty scene of finite triangles) or a clear error; a panic,
//! hang or abort is a crash.
#![no_main]
use bvhlab_geom::{obj, LoadError, Scene};
use libfuzzer_sys::fuzz_target;
use std::io::Write;
use std::path::PathBuf;

fn check_scene(s: &Scene) {
    assert!(!s.triangles.is_empty(), "Ok with no triangles");
    assert!(s.triangles.iter().all(|t| t.is_finite()), "non-finite triangle kept");
}

fn check_mem(r: Result<Scene, (Option<usize>, String)>) {
    match r {
        Ok(s) => check_scene(&s),
        Err((line, reason)) => {
            assert!(!reason.trim().is_empty(), "empty error reason");
            assert!(line != Some(0), "line numbers are 1-based");
        }
    }
}

fn check_file(r: Result<Scene, LoadError>, path: &PathBuf) {
    match r {
        Ok(s) => check_scene(&s),
        Err(e) => {
            assert!(!e.reason.trim().is_empty(), "empty error reason");
            assert_eq!(&e.file, path, "error names another file");
            assert!(e.line != Some(0), "line numbers are 1-based");
        }
    }
}

/// A per-process scratch file, in tmpfs when there is one (a disk under write-back pressure stalled
/// one execution past libFuzzer's timeout).
fn temp(name: &str) -> PathBuf {
    let shm = std::path::Path::new("/dev/shm");
    let dir = if shm.is_dir() { shm.to_path_buf() } else { std::env::temp_dir() };
    dir.join(format!("bvhlab-fuzz-{}-{name}", std::process::id()))
}

fuzz_target!(|input: &[u8]| {
    // The first byte picks one of the six paths (one parse per execution keeps the rate up).
    let Some((&sel, data)) = input.split_first() else {
        return;
    };
    let gz = || {
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        enc.write_all(data).unwrap();
        enc.finish().unwrap()
    };
    match sel % 8 {
        // Plain text, in memory.
        0 | 1 => check_mem(obj::parse_obj_bytes(data)),
        // The same bytes as a valid gzip stream (.obj.gz), in memory.
        2 | 3 => check_mem(obj::parse_obj_reader(flate2::read::MultiGzDecoder::new(&gz()[..]))),
        // Raw bytes on the gzip path: no header, corrupt or truncated streams.
        4 | 5 => check_mem(obj::parse_obj_reader(flate2::read::MultiGzDecoder::new(data))),
        // Through the file loader: plain, gzip, raw bytes named .obj.gz.
        6 => {
            let plain = temp("x.obj");
            std::fs::write(&plain, data).unwrap();
            check_file(obj::load_obj(&plain), &plain);
        }
        _ => {
            let gz_path = temp("y.obj.gz");
            std::fs::write(&gz_path, gz()).unwrap();
            check_file(obj::load_obj(&gz_path), &gz_path);
            let raw_gz = temp("z.obj.gz");
            std::fs::write(&raw_gz, data).unwrap();
            check_file(obj::load_obj(&raw_gz), &raw_gz);
        }
    }
});
