//! Inputs found by the cargo-fuzz targets (fuzz/): each must load or fail with a clear error,
//! promptly, never panic or hang.
use bvhlab_geom::obj;
use std::time::{Duration, Instant};

/// Runs `f` on a thread and fails if it does not finish within `secs` (a hang is a failure).
fn within<T: Send + 'static>(secs: u64, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(Duration::from_secs(secs)).expect("hang: no result in time")
}

/// fuzz/artifacts/obj/timeout-14db43...: invalid UTF-8 before a face statement, as .obj and .obj.gz.
#[test]
fn invalid_utf8_line_then_face_does_not_hang() {
    let data: Vec<u8> = vec![
        0x61, 0x0a, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb,
        0xeb, 0xeb, 0xb1, 0xb1, 0xb1, 0x01, 0x80, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1,
        0x01, 0x80, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0xb1, 0x65, 0x20, 0x30, 0x2f, 0xca, 0x2f, 0x61, 0x2f, 0x2f, 0x61,
        0x32, 0x32, 0x2f, 0x31, 0x31, 0x20, 0x2d, 0x31, 0x2f, 0x31, 0x02, 0x66, 0x20, 0x31, 0x20, 0x32, 0x20, 0x33,
        0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb, 0xeb,
        0xeb, 0xeb, 0x20, 0x31, 0x0a,
    ];
    let t = Instant::now();
    let d = data.clone();
    let r = within(10, move || obj::parse_obj_bytes(&d));
    eprintln!("plain: {r:?} in {:?}", t.elapsed());
    assert!(r.is_err());
    let t = Instant::now();
    let r = within(10, move || {
        use std::io::Write;
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        enc.write_all(&data).unwrap();
        let gz = enc.finish().unwrap();
        obj::parse_obj_reader(flate2::read::MultiGzDecoder::new(&gz[..]))
    });
    eprintln!("gz: {r:?} in {:?}", t.elapsed());
    assert!(r.is_err());
}
