//! Pass scheduling: how many passes (one sample per pixel over the whole image) a render runs,
//! and the progress bar. Which passes train, and how, is the strategy's question (the guided
//! strategy asks the library's [`guiding::TrainingSchedule`]); the strategy tells the schedule
//! when training has ended ([`Schedule::training_ended`]) so the prediction below can leave
//! the training passes out.
//!
//! * **spp budget** (`RenderOptions::time_budget == None`): exactly `spp` passes.
//! * **time budget**: passes run while the budget lasts. A new pass starts only if the time
//!   used so far plus the predicted pass time fits into the budget (so the render ends at or
//!   slightly before the budget, not one pass after it); the first pass always runs. The
//!   prediction is the mean pass time since training ended (the mean over all passes before
//!   that): training passes also pay for the training itself, which would inflate the
//!   prediction by `training time / passes` (about 15 ms a pass on the door at 20 s) and end
//!   a guided render earlier than `pt-nee` for no reason.
//!
//! The progress bar (indicatif, on stderr) counts passes (spp budget) or elapsed milliseconds
//! (time budget); it is hidden when `RenderOptions::progress` is off or stderr is not a terminal.

use crate::render::options::RenderOptions;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// Upper bound on the passes of a time-budget render (the per-pixel sums are exact far beyond).
pub const MAX_PASSES: u32 = 1 << 20;

/// One pass to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pass {
    /// Pass index = sample index of every pixel (seeds the per-path RNG).
    pub index: u32,
    /// Wall time since the render started, when this pass starts.
    pub elapsed: Duration,
}

/// Decides the passes of one render; see the [module docs](self).
pub struct Schedule {
    start: Instant,
    spp: u32,
    budget: Option<Duration>,
    done: u32,
    training_over: bool,
    /// Elapsed time and pass index when the first pass without training started.
    steady_since: Option<(Duration, u32)>,
    bar: Option<ProgressBar>,
}

/// Predicted duration of the next pass after `index` passes in `elapsed`: the mean since
/// `steady_since` (the start of the first pass without training) once a pass has finished
/// after it, the mean of all passes otherwise. `index ≥ 1`.
fn predicted_pass(
    elapsed: Duration,
    index: u32,
    steady_since: Option<(Duration, u32)>,
) -> Duration {
    match steady_since {
        Some((t0, i0)) if index > i0 && elapsed >= t0 => (elapsed - t0) / (index - i0),
        _ => elapsed / index.max(1),
    }
}

impl Schedule {
    /// Schedule for `opts` (spp or time budget).
    pub fn new(opts: &RenderOptions) -> Self {
        let budget = opts.time_budget;
        let bar = (opts.progress && std::io::stderr().is_terminal()).then(|| {
            let (len, template) = match budget {
                Some(b) => (
                    b.as_millis().max(1) as u64,
                    "{elapsed_precise} [{bar:40}] {percent:>3}% of the time budget {msg}",
                ),
                None => (
                    u64::from(opts.spp.max(1)),
                    "{elapsed_precise} [{bar:40}] {pos}/{len} passes (eta {eta}) {msg}",
                ),
            };
            let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
            if let Ok(style) = ProgressStyle::with_template(template) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar
        });
        Self {
            start: Instant::now(),
            spp: opts.spp.max(1),
            budget,
            done: 0,
            training_over: false,
            steady_since: None,
            bar,
        }
    }

    /// The next pass, or `None` when the budget is used up. Call once per pass, after the
    /// previous pass finished.
    pub fn next_pass(&mut self) -> Option<Pass> {
        let elapsed = self.start.elapsed();
        if let Some(bar) = &self.bar {
            match self.budget {
                Some(_) => bar.set_position(elapsed.as_millis() as u64),
                None => bar.set_position(u64::from(self.done)),
            }
        }
        let index = self.done;
        match self.budget {
            None if index >= self.spp => return None,
            Some(_) if index >= MAX_PASSES => return None,
            Some(budget)
                if index > 0
                    && elapsed + predicted_pass(elapsed, index, self.steady_since) > budget =>
            {
                return None
            }
            _ => {}
        }
        self.done += 1;
        Some(Pass { index, elapsed })
    }

    /// Whether `pass` (just handed out) trains: the first one that does not ends training
    /// for the prediction of the pass time.
    pub fn training_ended(&mut self, pass: &Pass, trains: bool) {
        if trains && self.training_over {
            // Training resumed (after the guided strategy's early look): the passes since are
            // no steady state.
            self.training_over = false;
            self.steady_since = None;
        }
        if !trains {
            self.training_over = true;
            if self.steady_since.is_none() {
                self.steady_since = Some((pass.elapsed, pass.index));
            }
        }
        if let Some(bar) = &self.bar {
            bar.set_message(if trains && !self.training_over {
                "(training)"
            } else {
                ""
            });
        }
    }

    /// Passes handed out so far.
    pub fn passes(&self) -> u32 {
        self.done
    }

    /// Wall time since the schedule was created.
    pub fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    /// Removes the progress bar.
    pub fn finish(self) {
        if let Some(bar) = self.bar {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spp_schedule_counts_passes() {
        let opts = RenderOptions {
            spp: 10,
            ..RenderOptions::default()
        };
        let mut s = Schedule::new(&opts);
        let passes: Vec<Pass> = std::iter::from_fn(|| s.next_pass()).collect();
        assert_eq!(passes.len(), 10);
        assert_eq!(passes[9].index, 9);
    }

    /// The prediction leaves the training passes out once a pass without training finished:
    /// 4 training passes of 0.5 s and 2 passes of 0.1 s predict 0.1 s, not 0.37 s.
    #[test]
    fn predicted_pass_leaves_training_passes_out() {
        let ms = Duration::from_millis;
        // Before training ended, and at the start of the first untrained pass: the overall mean.
        assert_eq!(predicted_pass(ms(2000), 4, None), ms(500));
        assert_eq!(predicted_pass(ms(2000), 4, Some((ms(2000), 4))), ms(500));
        // Then the mean of the untrained passes only.
        assert_eq!(predicted_pass(ms(2200), 6, Some((ms(2000), 4))), ms(100));
        // An unguided render (steady from pass 0) is the plain mean.
        assert_eq!(predicted_pass(ms(900), 9, Some((ms(0), 0))), ms(100));
    }

    #[test]
    fn zero_time_budget_runs_one_pass() {
        let opts = RenderOptions {
            time_budget: Some(Duration::ZERO),
            ..RenderOptions::default()
        };
        let mut s = Schedule::new(&opts);
        s.next_pass().expect("first pass always runs");
        std::thread::sleep(Duration::from_millis(1));
        assert_eq!(s.next_pass(), None);
    }
}
