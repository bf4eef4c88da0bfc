//! Load scenes and print triangle count, dropped count, seconds and an FNV-1a hash of the
//! triangles' coordinate bits (in order: a loader change that keeps the scene keeps the hash):
//! `cargo run --release -p bvhlab-geom --example load -- FILE_OR_GEN_SPEC...`
fn main() {
    let mut failed = false;
    for spec in std::env::args().skip(1) {
        let t = std::time::Instant::now();
        match bvhlab_geom::load_scene(&spec) {
            Ok(s) => {
                let secs = t.elapsed().as_secs_f64();
                let mut h: u64 = 0xcbf29ce484222325;
                for v in s.triangles.iter().flat_map(|t| t.v) {
                    for c in v.to_array() {
                        h = (h ^ c.to_bits() as u64).wrapping_mul(0x100000001b3);
                    }
                }
                println!(
                    "{spec}: triangles {} dropped {} seconds {secs:.3} fnv {h:016x}",
                    s.triangles.len(),
                    s.dropped_triangles,
                )
            }
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    if failed {
        std::process::exit(2);
    }
}
