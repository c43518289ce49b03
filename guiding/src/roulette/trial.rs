//! Does the weight window pay? The [`GuideTrial`] of whole passes, run for the window instead of
//! the guide: passes with the window against passes without it (the renderer's own roulette,
//! or none), compared by their **efficiency** (relMSE per pass × seconds per pass) on the
//! renderer's image.
//!
//! ADRRS weighs neither cost nor variance: it keeps every path's expected contribution near
//! the pixel's value. Where next-event estimation already makes the pixels precise (the
//! Cornell box: 20 s, 256 px, 2 seeds), the `1/m` weights of its roulette survivors add more
//! variance than the saved vertices remove, and the window in every pass made `pt-nee`'s
//! relMSE 1.25× worse; where most paths carry nothing (a room lit through a door) it is 0.6×.
//! The efficiency-aware rule ([`super::WeightWindow::efficiency_continuations`]) was meant to
//! see this from its estimates and did not (1.14× on the Cornell box). So the renderer asks
//! the image: once the grid has learned, it runs passes with and without the window until the
//! interval of their cost ratio says which is cheaper.
//!
//! The passes follow an ABBA order (with, without, without, with, …): both arms have the same
//! number of passes after every second pass (the trial looks there) and a linear drift of the
//! machine's speed falls on both alike. A renderer that runs the guide's own trial in the same
//! passes (it alternates guided and unguided passes, ABAB, before its first look) then gives
//! each arm of either trial as many passes of each arm of the other: neither trial's arms
//! differ in the other's estimator. Every pass is unbiased, so every pass stays in the image.
//!
//! Rules (each with the untrimmed point estimate on the same side of 1,
//! [`TrialOptions::robust_to_trim`]): the window stays when the whole interval of the cost ratio
//! `R = V_on t_on / (V_off t_off)` lies below 1 ([`Verdict::Pays`]) and goes when it lies above;
//! a first look (2 + 2 passes if the interval already excludes 1, else `K + K`) that straddles 1
//! continues the trial with the looks and α-spending of the guide's trial
//! ([`TrialOptions::continuation`]), the arm with the cheaper point estimate running two passes
//! of three, until a verdict or the render's end. Deviation from the guide's trial, whose 2 : 1
//! order is periodic: which pass of three goes to the other arm is drawn from a hash of the
//! pass count, so that the continuation cannot fall in step with a guide trial's period and
//! give one window arm more guided passes than the other. The grid must not learn from the
//! trial's passes for the comparison to be fair to both arms (host-demo's learns before it).
//! Where the window always ran, a trial that never decided (veach-mis, whose fireflies keep
//! both arms' intervals wide: `R` in [0.2, 8] after 420 + 420 passes) keeps the losing arm in
//! a third of the passes instead of all of them.

use crate::evidence::Verdict;
use crate::trial::{GuideTrial, TrialArm, TrialOptions, TrialVerdict};
use crate::GuidingError;

/// The window's efficiency trial of the [module docs](self).
#[derive(Clone, Debug)]
pub struct WindowTrial {
    trial: GuideTrial,
    /// Passes recorded so far (both arms).
    passes: u32,
}

impl WindowTrial {
    /// A trial over images of `width × height` pixels (row-major), weighted by `image`: the
    /// renderer's estimate of the image before the trial (see [`GuideTrial::new`]).
    ///
    /// # Errors
    /// As [`GuideTrial::new`].
    pub fn new(
        width: usize,
        height: usize,
        image: &[[f32; 3]],
        options: TrialOptions,
    ) -> Result<Self, GuidingError> {
        Ok(Self {
            trial: GuideTrial::new(width, height, image, options)?,
            passes: 0,
        })
    }

    /// Whether the next pass runs with the window: the ABBA order until the first look, the
    /// cheaper-looking arm in two passes of three (the third drawn by a hash of the pass
    /// count) while the trial continues, then the verdict ([`Self::window_pays`]).
    #[must_use]
    pub fn next_pass_uses_window(&self) -> bool {
        if let Some(v) = self.trial.verdict() {
            return Self::window_pays(&v);
        }
        if self.trial.first_look().is_none() {
            return matches!(self.passes % 4, 0 | 3);
        }
        // Without a look since the first (none yet), the window counts as the dearer arm.
        let window_favoured = self.trial.latest().is_some_and(|v| v.cost_ratio < 1.0);
        let other_arm = third_of(self.passes);
        window_favoured != other_arm
    }

    /// Whether a verdict keeps the window: its whole interval lies below 1 (a verdict at a
    /// first look without continuation may straddle: the window goes).
    #[must_use]
    pub fn window_pays(verdict: &TrialVerdict) -> bool {
        verdict.evidence == Verdict::Pays
    }

    /// Whether the trial still runs (the next pass is a trial pass).
    #[must_use]
    pub fn running(&self) -> bool {
        self.trial.verdict().is_none()
    }

    /// Adds one trial pass: whether it ran with the window (it must be what
    /// [`Self::next_pass_uses_window`] said), its pixel values and its seconds.
    ///
    /// # Errors
    /// [`GuidingError::InvalidConfig`] once the trial has a verdict, or for a pass of the other
    /// arm than the order's; else as [`GuideTrial::record`]. Nothing is added then.
    pub fn record(
        &mut self,
        with_window: bool,
        pixels: &[[f32; 3]],
        seconds: f64,
    ) -> Result<(), GuidingError> {
        if !self.running() {
            return Err(GuidingError::InvalidConfig(
                "the window's trial has a verdict: no more passes".into(),
            ));
        }
        if with_window != self.next_pass_uses_window() {
            return Err(GuidingError::InvalidConfig(format!(
                "trial pass {} of the window's trial runs {} the window",
                self.passes,
                if with_window { "without" } else { "with" }
            )));
        }
        let arm = if with_window {
            TrialArm::Guided
        } else {
            TrialArm::Unguided
        };
        self.trial.record(arm, pixels, seconds)?;
        self.passes += 1;
        Ok(())
    }

    /// Trial passes recorded (both arms).
    #[must_use]
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// The verdict, once there is one ([`Self::window_pays`] says what it decided; its
    /// `keep_guide` is the guide's rule, not the window's). Its "guided" fields are the arm
    /// with the window, its "unguided" fields the arm without.
    #[must_use]
    pub fn verdict(&self) -> Option<TrialVerdict> {
        self.trial.verdict()
    }

    /// An estimate from all passes so far, for a render that ends before the first look
    /// ([`GuideTrial::current`]).
    #[must_use]
    pub fn current(&self) -> Option<TrialVerdict> {
        self.trial.current()
    }
}

/// Whether pass `n` of a continuing trial goes to the less-favoured arm: one pass in three,
/// which one drawn by a hash of `n` ([`guiding_core::rng::mix64`]), so that the order has no
/// period.
fn third_of(n: u32) -> bool {
    guiding_core::rng::mix64(u64::from(n)) % 3 == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pass of `n × n` pixels of value 1 plus Gaussian noise of standard deviation `sd`
    /// (Box–Muller over a fixed-seed LCG).
    fn noisy_pass(n: usize, sd: f32, state: &mut u64) -> Vec<[f32; 3]> {
        let mut uniform = || {
            *state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((*state >> 40) as f32 + 0.5) / (1u64 << 24) as f32
        };
        (0..n * n)
            .map(|_| {
                let (u1, u2) = (uniform(), uniform());
                let g = (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos();
                [1.0 + sd * g; 3]
            })
            .collect()
    }

    /// Runs a trial whose window passes have noise `sd_on` and take `t_on` seconds, the others
    /// `sd_off` and `t_off`, for at most `max_passes`; returns it.
    fn run(sd_on: f32, t_on: f64, sd_off: f32, t_off: f64, max_passes: u32) -> WindowTrial {
        let n = 64;
        let image = vec![[1.0f32; 3]; n * n];
        let mut trial = WindowTrial::new(n, n, &image, TrialOptions::default()).unwrap();
        let mut state = 7u64;
        for _ in 0..max_passes {
            if !trial.running() {
                break;
            }
            let on = trial.next_pass_uses_window();
            let (sd, t) = if on { (sd_on, t_on) } else { (sd_off, t_off) };
            trial.record(on, &noisy_pass(n, sd, &mut state), t).unwrap();
        }
        trial
    }

    #[test]
    fn the_passes_follow_the_abba_order() {
        let n = 8;
        let image = vec![[1.0f32; 3]; n * n];
        let mut trial = WindowTrial::new(n, n, &image, TrialOptions::default()).unwrap();
        let mut order = Vec::new();
        let mut state = 1u64;
        for _ in 0..8 {
            let on = trial.next_pass_uses_window();
            order.push(on);
            // Identical arms: no verdict, the order goes on.
            trial
                .record(on, &noisy_pass(n, 0.5, &mut state), 1.0)
                .unwrap();
        }
        let abba = [true, false, false, true];
        assert_eq!(order, [abba, abba].concat());
        // A pass of the other arm is refused and not counted.
        let wrong = !trial.next_pass_uses_window();
        assert!(trial.record(wrong, &image, 1.0).is_err());
        assert_eq!(trial.passes(), 8);
    }

    /// Noise variance 4× at equal time: the window's cost ratio is 4 (or 1/4), far outside
    /// any interval of 64 × 64 pixels.
    #[test]
    fn a_window_that_costs_is_switched_off_and_one_that_pays_is_kept() {
        let mut dear = run(0.2, 1.0, 0.1, 1.0, 64);
        let v = dear.verdict().expect("a clear case decides");
        assert!(!WindowTrial::window_pays(&v) && v.ratio_low > 1.0, "{v:?}");
        assert_eq!(
            (v.guided_passes, v.unguided_passes),
            (2, 2),
            "early verdict"
        );
        assert!(!dear.next_pass_uses_window());
        assert!(dear.record(false, &[[1.0; 3]; 64 * 64], 1.0).is_err());

        let cheap = run(0.1, 1.0, 0.2, 1.0, 64);
        let v = cheap.verdict().expect("a clear case decides");
        assert!(WindowTrial::window_pays(&v) && v.ratio_high < 1.0, "{v:?}");
        assert!(cheap.next_pass_uses_window());
    }

    /// Time counts: the same variance at twice the seconds per pass is twice the cost.
    #[test]
    fn seconds_per_pass_count() {
        let slow = run(0.1, 2.0, 0.1, 1.0, 64);
        let v = slow.verdict().expect("a clear case decides");
        assert!(!WindowTrial::window_pays(&v), "{v:?}");
        assert!((v.cost_ratio - 2.0).abs() < 0.2, "{v:?}");
    }

    /// Equal arms: the interval straddles 1 at the first look (4 + 4 passes) and the trial
    /// goes on, the cheaper-looking arm in about two passes of three, in no fixed period.
    #[test]
    fn an_undecided_trial_continues_two_passes_to_one() {
        let n = 32;
        let image = vec![[1.0f32; 3]; n * n];
        let mut trial = WindowTrial::new(n, n, &image, TrialOptions::default()).unwrap();
        let mut state = 3u64;
        let mut order = Vec::new();
        for _ in 0..8 + 300 {
            let on = trial.next_pass_uses_window();
            order.push(on);
            trial
                .record(on, &noisy_pass(n, 0.1, &mut state), 1.0)
                .unwrap();
        }
        assert!(trial.running(), "{:?}", trial.verdict());
        let first = trial.trial.first_look().unwrap();
        assert_eq!(first.evidence, Verdict::Undecided, "{first:?}");
        let favoured = trial.trial.latest().unwrap().cost_ratio < 1.0;
        // After the first look's 8 passes and the next look's (due at 8 per arm, then 16):
        // count the favourite's share over the passes since the last look changed it.
        let later = &order[200..];
        let share = later.iter().filter(|&&on| on == favoured).count() as f64 / later.len() as f64;
        // 108 passes, each the other arm with probability 1/3: share 2/3 ± 3 σ (σ = 0.045).
        assert!((share - 2.0 / 3.0).abs() < 0.14, "{share}");
        // No period: the other arm's passes are not every third one.
        let others: Vec<usize> = (0..later.len()).filter(|&i| later[i] != favoured).collect();
        assert!(others.windows(2).any(|w| w[1] - w[0] != 3), "{others:?}");
    }
}
