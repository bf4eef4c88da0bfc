//! Load scenes and print triangle count, dropped count and seconds:
//! `cargo run --release -p bvhlab-geom --example load -- FILE_OR_GEN_SPEC...`
fn main() {
    let mut failed = false;
    for spec in std::env::args().skip(1) {
        let t = std::time::Instant::now();
        match bvhlab_geom::load_scene(&spec) {
            Ok(s) => println!(
                "{spec}: triangles {} dropped {} seconds {:.3}",
                s.triangles.len(),
                s.dropped_triangles,
                t.elapsed().as_secs_f64()
            ),
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
