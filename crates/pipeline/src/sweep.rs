//! Sweep: every chain of an experiment through one runner, scene by scene.
use crate::error::Result;
use crate::experiment::Experiment;
use crate::run::{Counts, Runner};
use crate::ResultRow;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::time::Instant;

pub struct SweepResult {
    pub rows: Vec<ResultRow>,
    pub counts: Counts,
    pub seconds: f64,
}

/// Runs every chain; `progress` draws a bar on stderr (callers pass whether stderr is a terminal).
pub fn sweep(exp: &Experiment, runner: &mut Runner, progress: bool) -> Result<SweepResult> {
    let t0 = Instant::now();
    let before = runner.counts.clone();
    let chains = exp.chains();
    let bar = if progress {
        let b =
            ProgressBar::with_draw_target(Some(chains.len() as u64), ProgressDrawTarget::stderr());
        if let Ok(style) =
            ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg}")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b
    } else {
        ProgressBar::hidden()
    };
    let mut rows = Vec::with_capacity(chains.len());
    let mut last_scene: Option<&str> = None;
    for c in &chains {
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
        bar.inc(1);
    }
    bar.finish_and_clear();
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
