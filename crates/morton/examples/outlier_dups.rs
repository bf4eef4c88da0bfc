//! Duplicate fractions on the far-outlier scene (Riemersma 2024's failure case):
//! `cargo run --release -p bvhlab-morton --example outlier_dups [E...]` (default e = 0 10 20 30).
//! One line per (e, encoder): duplicate_fraction, code bits, longest grid prefix (layout `g`s),
//! encode time (one run, for orientation only). `+tight` rows use `CellFrame::Tight` (an
//! extension: in-cell code over the tight centroid bounds of the cell).
use bvhlab_morton::{encode_cells, Bits, BoundsMode, CellFrame, EncodeConfig, Scheme};
use std::time::Instant;

fn main() {
    let es: Vec<u32> = {
        let a: Vec<u32> = std::env::args().skip(1).filter_map(|s| s.parse().ok()).collect();
        if a.is_empty() {
            vec![0, 10, 20, 30]
        } else {
            a
        }
    };
    let m = |bits| EncodeConfig {
        scheme: Scheme::Morton,
        bits: Bits::Fixed(bits),
        bounds: BoundsMode::Scene,
        grid_bits: 0,
    };
    let configs: Vec<(&str, EncodeConfig)> = vec![
        ("morton:10", m(10)),
        ("morton:10+concise", EncodeConfig { bounds: BoundsMode::Concise, ..m(10) }),
        ("morton:10+grid6", EncodeConfig { grid_bits: 6, ..m(10) }),
        ("morton:10+grid9", EncodeConfig { grid_bits: 9, ..m(10) }),
        ("morton:10+grid12", EncodeConfig { grid_bits: 12, ..m(10) }),
        ("morton:21", m(21)),
        ("morton:21+concise", EncodeConfig { bounds: BoundsMode::Concise, ..m(21) }),
        ("morton:21+grid6", EncodeConfig { grid_bits: 6, ..m(21) }),
        ("morton:21+grid9", EncodeConfig { grid_bits: 9, ..m(21) }),
        ("morton:21+grid12", EncodeConfig { grid_bits: 12, ..m(21) }),
        ("emc64-sort", EncodeConfig { scheme: Scheme::Emc64Sort, ..m(10) }),
        ("emc64-var", EncodeConfig { scheme: Scheme::Emc64Var, ..m(10) }),
        ("emc64-var+concise", EncodeConfig { scheme: Scheme::Emc64Var, bounds: BoundsMode::Concise, ..m(10) }),
        ("emc64-var+grid9", EncodeConfig { scheme: Scheme::Emc64Var, grid_bits: 9, ..m(10) }),
        ("emc64-var+grid12", EncodeConfig { scheme: Scheme::Emc64Var, grid_bits: 12, ..m(10) }),
    ];
    for e in es {
        let spec = format!("gen:outlier:e={e}");
        let scene = bvhlab_geom::load_scene(&spec).expect("scene");
        let (boxes, centers) = scene.boxes_and_centers();
        let tight =
            configs.iter().filter(|(_, c)| c.grid_bits > 0).map(|(n, c)| (format!("{n}+tight"), *c, CellFrame::Tight));
        let all: Vec<(String, EncodeConfig, CellFrame)> =
            configs.iter().map(|(n, c)| (n.to_string(), *c, CellFrame::Lattice)).chain(tight).collect();
        for (name, cfg, cf) in &all {
            let t = Instant::now();
            let enc = encode_cells(&boxes, &centers, cfg, *cf);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            let g = enc.layout.chars().take_while(|&c| c == 'g').count();
            println!(
                "{spec:<20} n={:<6} {name:<26} dup={:.4} code_bits={} grid_prefix_max={g} encode_ms={ms:.2}",
                boxes.len(),
                enc.duplicate_fraction(),
                enc.code_bits
            );
        }
    }
}
