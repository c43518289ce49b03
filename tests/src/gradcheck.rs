//! Finite-difference gradient checks, robust to a few kinks (the
//! tiny-cuda-nn convention: all but a small fraction of the components must
//! agree).
//!
//! Errors are symmetric relative errors `e = |a − n| / max(|a|, |n|, floor)`
//! between an analytic component `a` and a numeric one `n`: scale-free for
//! large components and an absolute error `|a − n| / floor` for components
//! both near zero, where relative errors are meaningless.

/// Central differences `∂f/∂x_i ≈ (f(x + h_i e_i) − f(x − h_i e_i)) / (2 h_i)`
/// with `h_i = h · max(1, |x_i|)` (the step actually taken, after rounding
/// `x_i ± h_i`, is used in the quotient).
#[must_use]
pub fn central_difference(f: impl Fn(&[f64]) -> f64, x: &[f64], h: f64) -> Vec<f64> {
    let mut probe = x.to_vec();
    (0..x.len())
        .map(|i| {
            let step = h * x[i].abs().max(1.0);
            let (hi, lo) = (x[i] + step, x[i] - step);
            probe[i] = hi;
            let f_hi = f(&probe);
            probe[i] = lo;
            let f_lo = f(&probe);
            probe[i] = x[i];
            (f_hi - f_lo) / (hi - lo)
        })
        .collect()
}

/// Symmetric relative error `|a − n| / max(|a|, |n|, floor)`; infinite if
/// either value is not finite.
#[must_use]
pub fn symmetric_relative_error(analytic: f64, numeric: f64, floor: f64) -> f64 {
    if !(analytic.is_finite() && numeric.is_finite()) {
        return f64::INFINITY;
    }
    (analytic - numeric).abs() / analytic.abs().max(numeric.abs()).max(floor)
}

/// Passes if all but the worst `⌊ignore_fraction · errors.len()⌋` errors are
/// `≤ tol` (a NaN error always counts as failing); otherwise panics listing
/// the worst offenders by index.
///
/// # Panics
/// When the check fails.
pub fn assert_gradients(name: &str, errors: &[f64], tol: f64, ignore_fraction: f64) {
    let labels: Vec<String> = (0..errors.len()).map(|i| format!("#{i}")).collect();
    if let Err(msg) = check(name, errors, &labels, None, tol, ignore_fraction) {
        panic!("{msg}");
    }
}

/// One compared component.
#[derive(Clone, Debug)]
pub struct GradientEntry {
    /// Where it came from (sample, parameter).
    pub label: String,
    /// Analytic value.
    pub analytic: f64,
    /// Finite-difference value.
    pub numeric: f64,
    /// Symmetric relative error.
    pub error: f64,
}

/// Accumulates compared components over many points, then checks them all at
/// once with [`GradientErrors::assert`].
#[derive(Clone, Debug)]
pub struct GradientErrors {
    /// Floor of the denominator of the relative error.
    pub floor: f64,
    /// Every compared component.
    pub entries: Vec<GradientEntry>,
}

impl GradientErrors {
    /// Empty accumulator with the given floor.
    #[must_use]
    pub fn new(floor: f64) -> Self {
        Self {
            floor,
            entries: Vec::new(),
        }
    }

    /// Records one component.
    pub fn push(&mut self, label: impl Into<String>, analytic: f64, numeric: f64) {
        self.entries.push(GradientEntry {
            label: label.into(),
            analytic,
            numeric,
            error: symmetric_relative_error(analytic, numeric, self.floor),
        });
    }

    /// Records a whole gradient; component `i` is labelled `"{label}[i]"`.
    pub fn push_all(&mut self, label: &str, analytic: &[f64], numeric: &[f64]) {
        assert_eq!(analytic.len(), numeric.len(), "{label}: length mismatch");
        for (i, (a, n)) in analytic.iter().zip(numeric).enumerate() {
            self.push(format!("{label}[{i}]"), *a, *n);
        }
    }

    /// The errors recorded so far.
    #[must_use]
    pub fn errors(&self) -> Vec<f64> {
        self.entries.iter().map(|e| e.error).collect()
    }

    /// The verdict of [`GradientErrors::assert`] without panicking: `Err` with
    /// the report (the number of failing components, the worst by label and
    /// value) when more than `⌊ignore_fraction · n⌋` errors exceed `tol`.
    ///
    /// # Errors
    /// When the check fails.
    pub fn check(&self, name: &str, tol: f64, ignore_fraction: f64) -> Result<(), String> {
        let labels: Vec<String> = self.entries.iter().map(|e| e.label.clone()).collect();
        check(
            name,
            &self.errors(),
            &labels,
            Some(&self.entries),
            tol,
            ignore_fraction,
        )
    }

    /// Like [`assert_gradients`], naming the offenders by label and value.
    ///
    /// # Panics
    /// When the check fails.
    pub fn assert(&self, name: &str, tol: f64, ignore_fraction: f64) {
        if let Err(msg) = self.check(name, tol, ignore_fraction) {
            panic!("{msg}");
        }
    }

    /// A copy with a planted defect: entry `i`'s analytic value multiplied by
    /// `factor(i, entry)` (1 leaves it alone), its error recomputed. The
    /// negative controls take a gradient that passes and check that the same
    /// tolerance rejects it with a known defect (one parameter's derivative off
    /// by a few per cent, or of the wrong sign).
    #[must_use]
    pub fn with_defect(&self, factor: impl Fn(usize, &GradientEntry) -> f64) -> Self {
        let mut out = Self::new(self.floor);
        for (i, e) in self.entries.iter().enumerate() {
            out.push(e.label.clone(), e.analytic * factor(i, e), e.numeric);
        }
        out
    }

    /// Prints how the errors sit against `tol`: the number above it, the
    /// median, the 99th percentile and the worst (the measurement a
    /// tolerance's derivation quotes).
    pub fn report(&self, name: &str, tol: f64) {
        let (above, worst) = self.summary(tol);
        println!(
            "{name}: {above} of {} components above {tol:e} (median {:.1e}, 99th percentile \
             {:.1e}, worst {worst:.2e})",
            self.entries.len(),
            self.quantile(0.5),
            self.quantile(0.99),
        );
    }

    /// A negative control: the check `check(tol, ignore_fraction)` must
    /// reject these components with `defect` planted ([`Self::with_defect`]);
    /// reports the planted errors.
    ///
    /// # Panics
    /// When the planted defect passes.
    pub fn assert_rejects_defect(
        &self,
        name: &str,
        defect: &str,
        (tol, ignore_fraction): (f64, f64),
        factor: impl Fn(usize, &GradientEntry) -> f64,
    ) {
        let planted = self.with_defect(factor);
        let name = format!("{name} with {defect}");
        planted.report(&name, tol);
        assert!(
            planted.check(&name, tol, ignore_fraction).is_err(),
            "{name}: the planted defect passed the gradient check"
        );
    }

    /// The `q`-quantile (`0 ≤ q ≤ 1`, nearest rank) of the errors, NaN counted
    /// as infinite; 0 when empty.
    #[must_use]
    pub fn quantile(&self, q: f64) -> f64 {
        let mut e: Vec<f64> = self
            .errors()
            .into_iter()
            .map(|e| if e.is_nan() { f64::INFINITY } else { e })
            .collect();
        if e.is_empty() {
            return 0.0;
        }
        e.sort_by(f64::total_cmp);
        let rank = ((q * e.len() as f64).ceil() as usize).clamp(1, e.len());
        e[rank - 1]
    }

    /// `(number above tol, largest error)`, for reporting.
    #[must_use]
    pub fn summary(&self, tol: f64) -> (usize, f64) {
        let errors = self.errors();
        let above = errors.iter().filter(|e| e.is_nan() || **e > tol).count();
        let worst =
            errors.iter().copied().fold(
                0.0,
                |m: f64, e| {
                    if e.is_nan() {
                        f64::INFINITY
                    } else {
                        m.max(e)
                    }
                },
            );
        (above, worst)
    }
}

fn check(
    name: &str,
    errors: &[f64],
    labels: &[String],
    entries: Option<&[GradientEntry]>,
    tol: f64,
    ignore_fraction: f64,
) -> Result<(), String> {
    let allowed = (ignore_fraction * errors.len() as f64).floor() as usize;
    // NaN sorts as the worst.
    let key = |e: f64| if e.is_nan() { f64::INFINITY } else { e };
    let mut order: Vec<usize> = (0..errors.len()).collect();
    order.sort_by(|&a, &b| key(errors[b]).total_cmp(&key(errors[a])));
    let failing = order
        .iter()
        .filter(|&&i| errors[i].is_nan() || errors[i] > tol)
        .count();
    if failing <= allowed {
        return Ok(());
    }
    let mut msg = format!(
        "{name}: {failing} of {} gradient components exceed the symmetric relative error {tol:e} \
         (at most {allowed} may); worst:\n",
        errors.len()
    );
    for &i in order.iter().take(20) {
        match entries {
            Some(e) => msg.push_str(&format!(
                "  {}: error {:.3e}, analytic {:e}, numeric {:e}\n",
                labels[i], errors[i], e[i].analytic, e[i].numeric
            )),
            None => msg.push_str(&format!("  {}: error {:.3e}\n", labels[i], errors[i])),
        }
    }
    Err(msg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn central_difference_of_a_polynomial() {
        let f = |x: &[f64]| x[0] * x[0] * x[1] + 3.0 * x[1];
        let g = central_difference(f, &[2.0, -5.0], 1e-6);
        assert!(
            (g[0] - -20.0).abs() < 1e-6 && (g[1] - 7.0).abs() < 1e-6,
            "{g:?}"
        );
    }

    #[test]
    fn ignore_fraction_rounds_down() {
        let mut errors = vec![0.0; 199];
        errors.push(1.0);
        assert_gradients("one of 200 at 1 %", &errors, 1e-2, 0.01);
        let r =
            std::panic::catch_unwind(|| assert_gradients("one of 99", &errors[101..], 1e-2, 0.01));
        assert!(r.is_err());
        let r = std::panic::catch_unwind(|| assert_gradients("NaN", &[f64::NAN], 1e-2, 0.0));
        assert!(r.is_err());
    }

    #[test]
    fn a_planted_defect_is_reported() {
        let mut e = GradientErrors::new(1e-3);
        for i in 0..400 {
            let g = f64::from(i) * 0.01 - 2.005;
            e.push(format!("#{i}"), g * (1.0 + 1e-6), g);
        }
        assert!(e.check("clean", 1e-2, 0.01).is_ok());
        assert!(e.quantile(1.0) < 1e-5 && e.quantile(0.0) < 1e-5);
        // One component in eight 5 % off: 50 of 400 fail, 4 may.
        let bad = e.with_defect(|i, _| if i % 8 == 0 { 1.05 } else { 1.0 });
        let msg = bad.check("defect", 1e-2, 0.01).unwrap_err();
        assert!(msg.starts_with("defect: 50 of 400"), "{msg}");
    }
}
