//! Timed runs of at least [`MIN_RUN_SECONDS`]: a stage whose call is shorter repeats it within one run
//! and divides the run's time by the calls, as benchmark harnesses (criterion) do.
//!
//! Why: with `repeat` single calls, a millisecond build or trace is timed at the scale of the
//! scheduler's and the timer's jitter. On the `quick` experiment (2026-11-28, one call per run,
//! repeat 3) 171 of 290 rows had a timing spread ((slowest - fastest) / median) above 0.25, all of
//! them calls of 0.2-30 ms. Every timed quantity stays the median of `repeat` runs; a run is now
//! at least 10 ms of calls, timed call by call (dropping and checking results stay outside).
use crate::error::Result;
use crate::run::secs;
use std::time::Instant;

/// The shortest timed run: calls shorter than this are repeated within a run.
pub const MIN_RUN_SECONDS: f64 = 0.01;

/// [`MIN_RUN_SECONDS`], or `BVHLAB_MIN_RUN_SECONDS` from the environment (0: one call per run).
/// Like the thread count, not part of any cache key: it changes how a time is taken, not what is
/// computed.
pub fn min_run_seconds() -> f64 {
    static V: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *V.get_or_init(|| {
        std::env::var("BVHLAB_MIN_RUN_SECONDS")
            .ok()
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|v| v.is_finite() && *v >= 0.0)
            .unwrap_or(MIN_RUN_SECONDS)
    })
}
/// At most this many calls per run (a call of 10 us or less is timed over 1000 calls).
pub const MAX_CALLS: u32 = 1000;

/// The runs of one timed quantity. The first [`Batch::run`] calibrates: when its single call took
/// less than [`MIN_RUN_SECONDS`], calls continue untimed for that long (a warm-up) and the run is
/// redone with enough calls to fill it; every later run makes the same number of calls.
#[derive(Clone, Debug)]
pub struct Batch {
    calls: u32,
    calibrated: bool,
    min_run: f64,
}

impl Default for Batch {
    fn default() -> Self {
        Batch::new()
    }
}

impl Batch {
    pub fn new() -> Batch {
        Batch::with_min_run(min_run_seconds())
    }

    /// Runs of at least `min_run` seconds.
    pub fn with_min_run(min_run: f64) -> Batch {
        Batch { calls: 1, calibrated: false, min_run }
    }

    /// One call per run, always (a time-capped optimizer: its calls stop on the clock, so more of
    /// them would only multiply the cap).
    pub fn single() -> Batch {
        Batch { calls: 1, calibrated: true, min_run: 0.0 }
    }

    /// Calls per run (after the first run: its calibration).
    pub fn calls(&self) -> u32 {
        self.calls
    }

    /// One timed run: `f` called [`Batch::calls`] times, the last result returned with the seconds
    /// per call: the sum of the calls' wall times, or where every call reports its own time (a peer
    /// library timing its own call) the sum of those.
    pub fn run<T>(&mut self, f: impl FnMut() -> Result<(T, Option<f64>)>) -> Result<(T, f64)> {
        self.run_checked(f, |_| Ok(()))
    }

    /// [`Batch::run`] with `check` on every call's result (the warm-up's too), outside the timed
    /// calls as is dropping each result before the next call (so the peak heap is one call's).
    pub fn run_checked<T>(
        &mut self,
        mut f: impl FnMut() -> Result<(T, Option<f64>)>,
        mut check: impl FnMut(&T) -> Result<()>,
    ) -> Result<(T, f64)> {
        loop {
            let k = self.calls.max(1);
            let mut total = 0.0;
            let mut last = None;
            for _ in 0..k {
                drop(last.take());
                let t = Instant::now();
                let (out, own) = f()?;
                let wall = secs(t);
                total += own.unwrap_or(wall);
                check(&out)?;
                last = Some(out);
            }
            let per_call = total / k as f64;
            let Some(mut out) = last else { unreachable!("k >= 1 calls made") };
            if !self.calibrated {
                self.calibrated = true;
                let min_run = self.min_run;
                if per_call < min_run {
                    // A warm-up of calls for MIN_RUN_SECONDS (the first runs after a pause were
                    // up to 3x slower on the quick sweep: caches, the rayon workers waking up).
                    let (mut warm, mut n) = (total, 1u32);
                    while warm < min_run && n < MAX_CALLS {
                        drop(out);
                        let t = Instant::now();
                        let (o, own) = f()?;
                        warm += own.unwrap_or_else(|| secs(t));
                        n += 1;
                        check(&o)?;
                        out = o;
                    }
                    drop(out);
                    // NaN or 0 (a clock that did not advance) asks for the most calls.
                    let want = (min_run / (warm / n as f64)).ceil();
                    self.calls = if want.is_finite() { (want as u32).clamp(2, MAX_CALLS) } else { MAX_CALLS };
                    continue;
                }
            }
            return Ok((out, per_call));
        }
    }
}

/// The determinism check of a timed stage: every call's result (a digest of it, or a copy)
/// against the first call's.
#[derive(Debug)]
pub struct SameAsFirst<H> {
    first: Option<H>,
    calls: u32,
}

impl<H: PartialEq> Default for SameAsFirst<H> {
    fn default() -> Self {
        SameAsFirst { first: None, calls: 0 }
    }
}

impl<H: PartialEq> SameAsFirst<H> {
    /// Keeps the first `h`; a later one that differs is the error `differs(call)` (calls from 1).
    pub fn check(&mut self, h: H, differs: impl FnOnce(u32) -> crate::error::Error) -> Result<()> {
        self.calls += 1;
        match &self.first {
            None => self.first = Some(h),
            Some(f) if *f != h => return Err(differs(self.calls)),
            _ => {}
        }
        Ok(())
    }

    /// The first call's value (None: no call).
    pub fn into_first(self) -> Option<H> {
        self.first
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A call reporting its own time of `s` seconds, counted.
    fn call(n: &mut u32, s: f64) -> Result<(u32, Option<f64>)> {
        *n += 1;
        Ok((*n, Some(s)))
    }

    #[test]
    fn short_calls_are_batched_after_a_warm_up() {
        let (mut b, mut n) = (Batch::with_min_run(MIN_RUN_SECONDS), 0);
        let (last, per) = b.run(|| call(&mut n, 0.001)).unwrap();
        // Warm-up calls for 10 ms, then 10 calls of 1 ms fill the 10 ms run.
        assert_eq!(b.calls(), 10);
        assert_eq!((n, last), (20, 20));
        assert!((per - 0.001).abs() < 1e-12, "{per}");
        let (last, _) = b.run(|| call(&mut n, 0.001)).unwrap();
        assert_eq!((n, last), (30, 30), "later runs make the same calls, no warm-up");
    }

    #[test]
    fn long_calls_stay_single_and_the_first_run_counts() {
        let (mut b, mut n) = (Batch::with_min_run(MIN_RUN_SECONDS), 0);
        let (_, per) = b.run(|| call(&mut n, 0.5)).unwrap();
        assert_eq!((b.calls(), n), (1, 1));
        assert_eq!(per, 0.5);
    }

    #[test]
    fn the_batch_is_bounded_and_single_stays_single() {
        let (mut b, mut n) = (Batch::with_min_run(MIN_RUN_SECONDS), 0);
        b.run(|| call(&mut n, 0.0)).unwrap();
        assert_eq!(b.calls(), MAX_CALLS);
        let (mut s, mut m) = (Batch::single(), 0);
        s.run(|| call(&mut m, 1e-6)).unwrap();
        assert_eq!((s.calls(), m), (1, 1));
    }

    #[test]
    fn every_call_is_checked() {
        let (mut b, mut n, mut seen) = (Batch::with_min_run(MIN_RUN_SECONDS), 0, Vec::new());
        b.run_checked(|| call(&mut n, 0.004), |&v| {
            seen.push(v);
            Ok(())
        })
        .unwrap();
        // Warm-up: 3 calls (12 ms); then 3 calls of 4 ms fill the run.
        assert_eq!(seen, [1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn same_as_first_names_the_call_that_differs() {
        let mut d = SameAsFirst::default();
        let e = |c: u32| crate::error::Error::internal(format!("call {c}"));
        assert!(d.check(7, e).is_ok() && d.check(7, e).is_ok());
        assert_eq!(d.check(8, e).unwrap_err().message(), "call 3");
        assert_eq!(d.into_first(), Some(7));
    }

    #[test]
    fn an_error_ends_the_run() {
        let mut b = Batch::with_min_run(MIN_RUN_SECONDS);
        let mut n = 0;
        let r = b.run(|| -> Result<((), Option<f64>)> {
            n += 1;
            if n == 3 {
                return Err(crate::error::Error::internal("third call fails"));
            }
            Ok(((), Some(0.004)))
        });
        assert!(r.is_err());
        assert_eq!(n, 3);
    }
}
