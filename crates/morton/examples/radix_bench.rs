//! Radix sort speed: `cargo run --release -p bvhlab-morton --example radix_bench [N] [RUNS]`.
//! Sorts N (default 10 M) random 64-bit codes with their indices; median of RUNS (default 5) at
//! 1 and 2 threads, beside `slice::sort_unstable` and rayon's `par_sort_unstable` of the same
//! (code, index) pairs as anchors. One line per method and thread count.
use bvhlab_geom::stats::median;
use bvhlab_geom::rng::SplitMix64;
use bvhlab_morton::radix;
use rayon::prelude::*;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(10_000_000);
    let runs: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    // `radix1`: only the radix sort at 1 thread (for CPU-time comparisons with `time`).
    let only_radix = args.get(3).is_some_and(|a| a == "radix1");
    let mut rng = SplitMix64::new(7);
    let codes: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
    let mut reference: Option<Vec<u32>> = None;
    for threads in if only_radix { vec![1usize] } else { vec![1, 2] } {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut t_radix = Vec::new();
            let mut t_std = Vec::new();
            let mut t_par = Vec::new();
            for _ in 0..runs {
                let input = codes.clone();
                let t = Instant::now();
                let (sorted, order) = radix::sort_with_index(input);
                t_radix.push(t.elapsed().as_secs_f64());
                assert!(sorted.windows(2).all(|w| w[0] <= w[1]));
                match &reference {
                    None => reference = Some(order),
                    Some(r) => assert!(r == &order, "radix output differs between runs/thread counts"),
                }

                if only_radix {
                    continue;
                }
                let mut pairs: Vec<(u64, u32)> = codes.iter().enumerate().map(|(i, &c)| (c, i as u32)).collect();
                let t = Instant::now();
                pairs.sort_unstable();
                t_std.push(t.elapsed().as_secs_f64());

                let mut pairs: Vec<(u64, u32)> = codes.iter().enumerate().map(|(i, &c)| (c, i as u32)).collect();
                let t = Instant::now();
                pairs.par_sort_unstable();
                t_par.push(t.elapsed().as_secs_f64());
            }
            let ms = |v: Vec<f64>| median(&v) * 1e3;
            println!("radix::sort_with_index   n={n} threads={threads} median_ms={:.1}", ms(t_radix));
            if only_radix {
                return;
            }
            println!(
                "slice::sort_unstable     n={n} threads={threads} median_ms={:.1} (single-threaded anchor)",
                ms(t_std)
            );
            println!("rayon par_sort_unstable  n={n} threads={threads} median_ms={:.1}", ms(t_par));
        });
    }
}
