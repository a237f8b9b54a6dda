//! The acceptance gate of a nightly re-calibration: is a newly identified
//! parameter set (the candidate) worth putting in service instead of the one in
//! service? Pure decisions on numbers; the `gate` stage gathers them and
//! [`crate::publish`] installs the winner.
//!
//! The candidate is published when it is *significantly and usefully better* on
//! the hold-out rows (paired t-test below `alpha` and a mean improvement of at least
//! `min_improvement_mm`: with thousands of rows a 1 µm gain is significant but not
//! worth a change of calibration), or when the in-service set has *drifted*: the
//! candidate moves some reference pose's predicted position by more than
//! `drift_threshold_mm`. A candidate significantly worse on the hold-out is
//! refused, whatever the drift: something is wrong with the night's data or fit,
//! and a person should look.

use crate::stats::{self, TestResult};

/// Thresholds of the gate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rules {
    /// Significance level of the two-sided paired t-test on hold-out errors.
    pub alpha: f64,
    /// Smallest mean hold-out improvement worth publishing (mm).
    pub min_improvement_mm: f64,
    /// Largest predicted position change over the reference poses the in-service
    /// set may differ from the candidate by before it counts as drifted (mm).
    pub drift_threshold_mm: f64,
}

/// What the gate decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// The in-service set stays.
    Kept,
    /// The candidate replaces it.
    Published,
    /// The candidate should have replaced it but is worse on the hold-out: alert.
    Refused,
}

impl Decision {
    pub fn as_str(self) -> &'static str {
        match self {
            Decision::Kept => "kept",
            Decision::Published => "published",
            Decision::Refused => "refused",
        }
    }

    pub fn parse(text: &str) -> Option<Decision> {
        [Decision::Kept, Decision::Published, Decision::Refused]
            .into_iter()
            .find(|d| d.as_str() == text)
    }
}

/// In-service and candidate errors on the same hold-out rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Holdout {
    pub rows: usize,
    pub in_service_mean_mm: f64,
    pub candidate_mean_mm: f64,
    /// Paired t-test of in-service minus candidate error norms; `None` when every
    /// difference is equal (the same set twice).
    pub paired_t: Option<TestResult>,
}

impl Holdout {
    /// Compares the error norms of the two sets on the same rows (at least 2).
    pub fn compare(
        in_service_mm: &[f64],
        candidate_mm: &[f64],
    ) -> Result<Holdout, stats::StatsError> {
        let in_service = stats::summary(in_service_mm)?;
        let candidate = stats::summary(candidate_mm)?;
        let paired_t = match stats::paired_t(in_service_mm, candidate_mm) {
            Ok(t) => Some(t),
            Err(stats::StatsError::ZeroVariance { .. }) => None,
            Err(e) => return Err(e),
        };
        Ok(Holdout {
            rows: in_service.n,
            in_service_mean_mm: in_service.mean,
            candidate_mean_mm: candidate.mean,
            paired_t,
        })
    }

    /// Mean error the candidate removes (negative: it adds error).
    pub fn improvement_mm(&self) -> f64 {
        self.in_service_mean_mm - self.candidate_mean_mm
    }

    fn p_value(&self) -> f64 {
        self.paired_t.map_or(1.0, |t| t.p_value)
    }
}

/// The day the in-service set's error rose, found as the best single split of
/// its errors in time.
#[derive(Debug, Clone, PartialEq)]
pub struct ChangePoint {
    /// First day (days since 1970-01-01) after the split.
    pub day: i64,
    pub mean_before_mm: f64,
    pub mean_after_mm: f64,
    /// Welch's t-test of the errors after against before.
    pub welch_t: TestResult,
}

/// The split of `errors_mm` (one per row, with its day, in any order) into days
/// before and from some day that minimises the within-segment squared deviation
/// (least-squares single change point, the first step of binary segmentation).
/// Reported only when the error rose, significantly at `alpha` and by at least
/// `min_rise_mm`; `None` with fewer than two days or two rows per side.
pub fn change_point(
    days: &[i64],
    errors_mm: &[f64],
    alpha: f64,
    min_rise_mm: f64,
) -> Option<ChangePoint> {
    let mut by_day: Vec<(i64, f64)> = days
        .iter()
        .copied()
        .zip(errors_mm.iter().copied())
        .collect();
    by_day.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let n = by_day.len();
    let total: f64 = by_day.iter().map(|(_, e)| e).sum();
    let total_sq: f64 = by_day.iter().map(|(_, e)| e * e).sum();
    let mut best: Option<(f64, usize)> = None;
    let (mut left_sum, mut left_sq) = (0.0, 0.0);
    for k in 1..n {
        left_sum += by_day[k - 1].1;
        left_sq += by_day[k - 1].1 * by_day[k - 1].1;
        if by_day[k].0 == by_day[k - 1].0 || k < 2 || n - k < 2 {
            continue;
        }
        let right_sum = total - left_sum;
        let right_sq = total_sq - left_sq;
        let sse = left_sq - left_sum * left_sum / k as f64 + right_sq
            - right_sum * right_sum / (n - k) as f64;
        if best.is_none_or(|(b, _)| sse < b) {
            best = Some((sse, k));
        }
    }
    let (_, split) = best?;
    let before: Vec<f64> = by_day[..split].iter().map(|(_, e)| *e).collect();
    let after: Vec<f64> = by_day[split..].iter().map(|(_, e)| *e).collect();
    let welch_t = stats::welch_t(&after, &before).ok()?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let point = ChangePoint {
        day: by_day[split].0,
        mean_before_mm: mean(&before),
        mean_after_mm: mean(&after),
        welch_t,
    };
    (point.welch_t.p_value < alpha && point.mean_after_mm - point.mean_before_mm >= min_rise_mm)
        .then_some(point)
}

/// The decision and its reasons, one sentence each.
pub fn decide(
    holdout: &Holdout,
    max_position_change_mm: f64,
    rules: &Rules,
) -> (Decision, Vec<String>) {
    let improvement = holdout.improvement_mm();
    let p = holdout.p_value();
    let significant = p < rules.alpha;
    let test = match holdout.paired_t {
        Some(t) => format!("paired t = {:.2}, p = {:.2e}", t.statistic, t.p_value),
        None => "every row has the same error with both sets".into(),
    };
    let holdout_line = format!(
        "hold-out ({} rows): in-service mean error {:.3} mm, candidate {:.3} mm ({test})",
        holdout.rows, holdout.in_service_mean_mm, holdout.candidate_mean_mm
    );
    let better = significant && improvement >= rules.min_improvement_mm;
    let worse = significant && improvement < 0.0;
    let drifted = max_position_change_mm > rules.drift_threshold_mm;
    let drift_line = format!(
        "the candidate moves the reference poses by up to {max_position_change_mm:.3} mm ({} the drift threshold {} mm)",
        if drifted { "beyond" } else { "within" },
        rules.drift_threshold_mm
    );
    let mut reasons = vec![holdout_line];
    let decision = if worse {
        reasons.push(format!(
            "the candidate is significantly worse on the hold-out (by {:.3} mm): refused; check the night's data and fit",
            -improvement
        ));
        Decision::Refused
    } else if better || drifted {
        if better {
            reasons.push(format!(
                "the candidate is significantly better, by {improvement:.3} mm (at least {} mm needed)",
                rules.min_improvement_mm
            ));
        }
        reasons.push(if drifted {
            format!("the in-service set has drifted: {drift_line}")
        } else {
            drift_line
        });
        Decision::Published
    } else {
        reasons.push(if significant {
            format!(
                "the improvement of {improvement:.3} mm is significant but below {} mm",
                rules.min_improvement_mm
            )
        } else {
            format!("no significant difference at alpha = {}", rules.alpha)
        });
        reasons.push(drift_line);
        Decision::Kept
    };
    (decision, reasons)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    const RULES: Rules = Rules {
        alpha: 0.01,
        min_improvement_mm: 0.02,
        drift_threshold_mm: 0.15,
    };

    fn errors(seed: u64, mean: f64, n: usize) -> Vec<f64> {
        let noise = Normal::new(0.0, 0.02).unwrap();
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n).map(|_| mean + noise.sample(&mut rng)).collect()
    }

    #[test]
    fn publishes_a_better_candidate_keeps_an_equal_one_and_refuses_a_worse_one() {
        let old = errors(1, 0.30, 50);
        let better: Vec<f64> = errors(2, 0.10, 50);
        let same: Vec<f64> = old
            .iter()
            .zip(errors(3, 0.0, 50))
            .map(|(a, d)| a + d * 0.01)
            .collect();
        let worse: Vec<f64> = errors(4, 0.50, 50);
        let cases = [
            (&better, 0.05, Decision::Published),
            (&same, 0.05, Decision::Kept),
            (&worse, 0.05, Decision::Refused),
            (&same, 0.40, Decision::Published),
            (&worse, 0.40, Decision::Refused),
        ];
        for (candidate, change, expected) in cases {
            let holdout = Holdout::compare(&old, candidate).unwrap();
            let (decision, reasons) = decide(&holdout, change, &RULES);
            assert_eq!(decision, expected, "{reasons:?}");
        }
    }

    #[test]
    fn a_significant_but_tiny_gain_is_not_published() {
        let old = errors(5, 0.30, 5000);
        let candidate: Vec<f64> = old.iter().map(|e| e - 0.005).collect::<Vec<_>>();
        let mut candidate = candidate;
        candidate[0] += 1e-4; // not all differences equal
        let holdout = Holdout::compare(&old, &candidate).unwrap();
        assert!(holdout.paired_t.unwrap().p_value < 1e-6);
        let (decision, reasons) = decide(&holdout, 0.01, &RULES);
        assert_eq!(decision, Decision::Kept);
        assert!(reasons[1].contains("below 0.02 mm"), "{reasons:?}");
    }

    #[test]
    fn identical_sets_are_kept_without_a_test() {
        let old = errors(6, 0.2, 30);
        let holdout = Holdout::compare(&old, &old).unwrap();
        assert_eq!(holdout.paired_t, None);
        assert_eq!(decide(&holdout, 0.0, &RULES).0, Decision::Kept);
    }

    #[test]
    fn change_point_finds_the_step_day_and_ignores_noise() {
        let days: Vec<i64> = (0..20).flat_map(|d| std::iter::repeat_n(d, 30)).collect();
        let mut rng = StdRng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.05).unwrap();
        let stepped: Vec<f64> = days
            .iter()
            .map(|&d| if d >= 13 { 0.5 } else { 0.2 } + noise.sample(&mut rng))
            .collect();
        let point = change_point(&days, &stepped, 0.01, 0.02).unwrap();
        assert_eq!(point.day, 13);
        assert!((point.mean_after_mm - 0.5).abs() < 0.02);
        assert!((point.mean_before_mm - 0.2).abs() < 0.02);

        let flat: Vec<f64> = days.iter().map(|_| 0.2 + noise.sample(&mut rng)).collect();
        assert_eq!(change_point(&days, &flat, 0.01, 0.02), None);
        // A fall in error is not a drift.
        let fell: Vec<f64> = stepped.iter().map(|e| 0.7 - e).collect();
        assert_eq!(change_point(&days, &fell, 0.01, 0.02), None);
    }
}
