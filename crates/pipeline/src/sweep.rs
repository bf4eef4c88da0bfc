//! Sweep: every chain of an experiment through one runner, scene by scene.
//!
//! Progress (issue 16 item 6): on a terminal a bar with stages done / total, elapsed time and an
//! ETA; without one (CI, Slurm logs) a plain `progress:` line on stderr at the start and then every
//! `BVHLAB_PROGRESS_SECONDS` seconds (default 10). The units are the experiment's plan nodes
//! (stages, deduplicated: what `computed` + `cached` count at the end); the ETA weighs the stages
//! still to compute by the plan's per-node estimates (`estimate.rs`), calibrated by the time the
//! computed ones took on this machine.
use crate::error::Result;
use crate::experiment::Experiment;
use crate::run::{Counts, Runner};
use crate::ResultRow;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle};
use std::io::IsTerminal;
use std::path::Path;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub struct SweepResult {
    pub rows: Vec<ResultRow>,
    pub counts: Counts,
    pub seconds: f64,
}

/// How a long run shows its progress on stderr.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgressMode {
    /// A redrawn bar (stderr is a terminal).
    Bar,
    /// Plain `progress:` lines, one at the start and one every `BVHLAB_PROGRESS_SECONDS` (10 s).
    Lines,
    /// Nothing.
    Hidden,
}

impl ProgressMode {
    /// `Bar` when stderr is a terminal, else `Lines`.
    pub fn stderr() -> Self {
        if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        }
    }
}

/// Seconds between two plain progress lines: `BVHLAB_PROGRESS_SECONDS` when a positive number
/// (the tests shorten it), else 10.
pub fn progress_interval() -> Duration {
    std::env::var("BVHLAB_PROGRESS_SECONDS")
        .ok()
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s > 0.0)
        .map(Duration::from_secs_f64)
        .unwrap_or(Duration::from_secs(10))
}

/// `12.3 s`, `4 min 05 s`, `2 h 03 min`.
pub fn format_seconds(s: f64) -> String {
    let s = s.max(0.0);
    if s < 60.0 {
        format!("{s:.1} s")
    } else if s < 3600.0 {
        let m = (s / 60.0).floor();
        format!("{m:.0} min {:02.0} s", (s - 60.0 * m).floor())
    } else {
        let h = (s / 3600.0).floor();
        format!("{h:.0} h {:02.0} min", ((s - 3600.0 * h) / 60.0).floor())
    }
}

struct State {
    label: String,
    total: u64,
    done: u64,
    /// Estimated seconds of the stages to compute (cached ones count 0), and of those done.
    est_total: f64,
    est_done: f64,
    t0: Instant,
    last_advance: Instant,
    msg: String,
}

impl State {
    /// Seconds left: the estimate of the stages still to compute, scaled by how long the computed
    /// ones took against their estimate, counting down since the last finished chain.
    fn eta(&self) -> f64 {
        let remaining = (self.est_total - self.est_done).max(0.0);
        if remaining <= 0.0 {
            return 0.0;
        }
        if self.est_done > 0.0 {
            let at = self.last_advance.duration_since(self.t0).as_secs_f64();
            let rate = at / self.est_done;
            (remaining * rate - self.last_advance.elapsed().as_secs_f64()).max(0.0)
        } else {
            (remaining - self.t0.elapsed().as_secs_f64()).max(0.0)
        }
    }

    fn line(&self) -> String {
        let pct = if self.total > 0 {
            100 * self.done / self.total
        } else {
            100
        };
        let mut s = format!(
            "progress: {}: {}/{} stages ({pct} %), {} elapsed, ETA {}",
            self.label,
            self.done,
            self.total,
            format_seconds(self.t0.elapsed().as_secs_f64()),
            format_seconds(self.eta())
        );
        if !self.msg.is_empty() {
            s.push_str(&format!(" (at {})", self.msg));
        }
        s
    }
}

/// Progress of a run over `total` stages (see the module doc). Dropping it stops the line ticker.
pub struct Progress {
    state: Arc<Mutex<State>>,
    bar: ProgressBar,
    ticker: Option<(mpsc::Sender<()>, std::thread::JoinHandle<()>)>,
}

impl Progress {
    /// Starts showing progress: `total` stages of which `missing` are to compute, estimated at
    /// `est_total` seconds. In `Lines` mode prints the first line now.
    pub fn start(mode: ProgressMode, label: &str, total: u64, missing: u64, est_total: f64) -> Self {
        let now = Instant::now();
        let state = Arc::new(Mutex::new(State {
            label: label.to_string(),
            total,
            done: 0,
            est_total,
            est_done: 0.0,
            t0: now,
            last_advance: now,
            msg: String::new(),
        }));
        let mut ticker = None;
        let bar = match mode {
            ProgressMode::Bar => {
                let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
                let st = state.clone();
                let eta = move |_: &ProgressState, w: &mut dyn std::fmt::Write| {
                    let e = st.lock().map(|s| s.eta()).unwrap_or(0.0);
                    let _ = w.write_str(&format_seconds(e));
                };
                if let Ok(style) = ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:30}] {pos}/{len} stages, ETA {eta_est} {msg}",
                ) {
                    b.set_style(style.with_key("eta_est", eta).progress_chars("=> "));
                }
                b.enable_steady_tick(Duration::from_millis(500));
                b
            }
            ProgressMode::Lines => {
                eprintln!(
                    "progress: {label}: {total} stages, {missing} to compute (estimated {}), \
                     {} cached",
                    format_seconds(est_total),
                    total.saturating_sub(missing)
                );
                let (tx, rx) = mpsc::channel::<()>();
                let st = state.clone();
                let every = progress_interval();
                let h = std::thread::spawn(move || loop {
                    match rx.recv_timeout(every) {
                        Err(RecvTimeoutError::Timeout) => {
                            if let Ok(s) = st.lock() {
                                eprintln!("{}", s.line());
                            }
                        }
                        _ => break,
                    }
                });
                ticker = Some((tx, h));
                ProgressBar::hidden()
            }
            ProgressMode::Hidden => ProgressBar::hidden(),
        };
        Progress { state, bar, ticker }
    }

    /// What is running now (shown after the counts).
    pub fn set_message(&self, msg: String) {
        if let Ok(mut s) = self.state.lock() {
            s.msg.clone_from(&msg);
        }
        self.bar.set_message(msg);
    }

    /// `stages` more stages are done, estimated at `est_seconds` (0 for cached ones).
    pub fn advance(&self, stages: u64, est_seconds: f64) {
        if let Ok(mut s) = self.state.lock() {
            s.done += stages;
            s.est_done += est_seconds;
            s.last_advance = Instant::now();
        }
        self.bar.inc(stages);
    }

    fn stop_ticker(&mut self) {
        if let Some((tx, h)) = self.ticker.take() {
            drop(tx);
            let _ = h.join();
        }
    }

    /// Clears the bar and stops the lines.
    pub fn finish(mut self) {
        self.stop_ticker();
        self.bar.finish_and_clear();
    }

    /// Leaves the bar as it is (on an error) and stops the lines.
    pub fn abandon(mut self) {
        self.stop_ticker();
        self.bar.abandon();
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.stop_ticker();
    }
}

/// The sweep's closing line in words, e.g.
/// `quick: 445 stages, 12 computed, 433 from cache, 3.1 s; report reports/quick/index.html`.
pub fn closing_line(label: &str, counts: &Counts, seconds: f64, report: Option<&Path>) -> String {
    let mut s = format!(
        "{label}: {} stages, {} computed, {} from cache, {}",
        counts.computed + counts.cached,
        counts.computed,
        counts.cached,
        format_seconds(seconds)
    );
    if let Some(r) = report {
        s.push_str(&format!("; report {}", r.display()));
    }
    s
}

/// Per chain, the plan nodes it is the first to use (it runs them) and their estimated seconds
/// (stages already cached count 0); with the total and the number to compute. None when the plan
/// cannot be made (the sweep itself then reports the error).
fn chain_units(exp: &Experiment, runner: &mut Runner) -> Option<(Vec<(u64, f64)>, u64, u64, f64)> {
    let p = crate::plan::plan(exp, runner).ok()?;
    let mut seen = vec![false; p.nodes.len()];
    let mut units = Vec::with_capacity(p.chain_nodes.len());
    for ns in &p.chain_nodes {
        let (mut n, mut est) = (0u64, 0.0f64);
        for &i in ns {
            if !std::mem::replace(&mut seen[i], true) {
                n += 1;
                if !p.nodes[i].cached {
                    est += p.nodes[i].est_seconds;
                }
            }
        }
        units.push((n, est));
    }
    let missing = p.missing().count() as u64;
    let est_total = p.missing().map(|n| n.est_seconds).sum();
    Some((units, p.nodes.len() as u64, missing, est_total))
}

/// Runs every chain, showing progress on stderr as `progress` says.
pub fn sweep(exp: &Experiment, runner: &mut Runner, progress: ProgressMode) -> Result<SweepResult> {
    let t0 = Instant::now();
    let before = runner.counts.clone();
    let chains = exp.chains();
    let units = match progress {
        ProgressMode::Hidden => None,
        _ => chain_units(exp, runner).filter(|u| u.0.len() == chains.len()),
    };
    let bar = match &units {
        Some((_, total, missing, est)) => Progress::start(progress, &exp.name, *total, *missing, *est),
        None => Progress::start(ProgressMode::Hidden, &exp.name, 0, 0, 0.0),
    };
    let mut rows = Vec::with_capacity(chains.len());
    let mut last_scene: Option<&str> = None;
    for (ci, c) in chains.iter().enumerate() {
        if last_scene.is_some_and(|s| s != c.scene) {
            runner.forget();
        }
        last_scene = Some(&c.scene);
        bar.set_message(format!(
            "{} {}{}{}{}",
            crate::stages::scene_name(&c.scene),
            c.build,
            c.encode
                .as_ref()
                .map(|e| format!(" {e}"))
                .unwrap_or_default(),
            c.layout
                .as_ref()
                .map(|l| format!(" @{l}"))
                .unwrap_or_default(),
            c.rays
                .map(|r| format!(" {}", r.canonical()))
                .unwrap_or_default()
        ));
        let row = runner.run_chain(c, &exp.name);
        let row = match row {
            Ok(r) => r,
            Err(e) => {
                bar.abandon();
                return Err(e);
            }
        };
        rows.push(row);
        if let Some((u, ..)) = &units {
            bar.advance(u[ci].0, u[ci].1);
        }
    }
    bar.finish();
    runner.forget();
    Ok(SweepResult {
        rows,
        counts: counts_since(&runner.counts, &before),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// What a runner counted since `before` (a snapshot of its counts).
pub fn counts_since(now: &Counts, before: &Counts) -> Counts {
    let mut counts = now.clone();
    counts.computed -= before.computed;
    counts.cached -= before.cached;
    for (k, v) in counts.per_stage.iter_mut() {
        let b = before.per_stage.get(k).copied().unwrap_or_default();
        v.computed -= b.computed;
        v.cached -= b.cached;
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_in_words() {
        assert_eq!(format_seconds(3.14), "3.1 s");
        assert_eq!(format_seconds(-1.0), "0.0 s");
        assert_eq!(format_seconds(65.0), "1 min 05 s");
        assert_eq!(format_seconds(7384.0), "2 h 03 min");
    }

    #[test]
    fn closing_line_in_words() {
        let counts = Counts {
            computed: 12,
            cached: 433,
            ..Counts::default()
        };
        assert_eq!(
            closing_line("quick", &counts, 3.1, Some(Path::new("reports/quick/index.html"))),
            "quick: 445 stages, 12 computed, 433 from cache, 3.1 s; report reports/quick/index.html"
        );
    }
}
