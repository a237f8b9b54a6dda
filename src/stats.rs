//! Validation statistics for comparing calibration models.
//!
//! The position error norms (mm) of several calibration models are evaluated on
//! the same validation rows. This module summarises such samples and tests
//! whether two models differ, using the conventions of numpy/scipy so that the
//! numbers in a report can be cross-checked against a Python notebook:
//!
//! - [`summary`]: mean, sample standard deviation, median, RMS, 95th percentile
//!   (numpy's default linear interpolation) and maximum;
//! - [`paired_t`], [`wilcoxon_signed_rank`]: paired tests on the same rows
//!   (`scipy.stats.ttest_rel`, `scipy.stats.wilcoxon`);
//! - [`welch_t`], [`student_t`]: tests on independent samples
//!   (`scipy.stats.ttest_ind` with `equal_var=False` / `True`).
//!
//! All p-values are two-sided. Degenerate inputs (empty or too short samples,
//! non-finite values, unequal paired lengths, zero variance, all-zero paired
//! differences) are reported as a [`StatsError`] rather than as NaN or infinity.

use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// Largest sample size for which scipy's `method="auto"` uses the exact
/// null distribution of the signed-rank statistic (no ties and no zeros).
const WILCOXON_EXACT_MAX_N: usize = 50;

/// Largest sample size for which scipy's `method="auto"` runs an exhaustive
/// sign-flip permutation test when there are ties or zero differences
/// (`2^13` sign patterns fit in scipy's default 9999 resamples).
const WILCOXON_PERMUTATION_MAX_N: usize = 13;

/// Quantile reported as `p95` by [`summary`].
const P95: f64 = 0.95;

/// Why a statistic could not be computed; each message names the problem.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StatsError {
    /// A sample without values has no statistics.
    #[error("sample `{sample}` is empty")]
    Empty {
        /// Name of the offending sample (`values`, `a` or `b`).
        sample: &'static str,
    },
    /// The statistic needs more values than were given (e.g. a sample
    /// standard deviation needs two).
    #[error("sample `{sample}` has {got} value(s), but at least {needed} are needed")]
    TooFewValues {
        /// Name of the offending sample.
        sample: &'static str,
        /// Minimum number of values.
        needed: usize,
        /// Number of values given.
        got: usize,
    },
    /// Paired tests compare the same validation rows, so both samples must
    /// have one value per row.
    #[error("paired samples have unequal lengths: `a` has {a} values, `b` has {b}")]
    UnequalLengths {
        /// Length of `a`.
        a: usize,
        /// Length of `b`.
        b: usize,
    },
    /// NaN or infinity would silently poison every statistic.
    #[error("sample `{sample}` has a non-finite value (NaN or infinity) at index {index}")]
    NonFinite {
        /// Name of the offending sample (`a - b` for paired differences that
        /// overflowed).
        sample: &'static str,
        /// Position of the first non-finite value.
        index: usize,
    },
    /// The t statistic divides by the standard error, which is zero here;
    /// scipy would return NaN or infinity.
    #[error("zero variance in {what}: the t statistic is undefined")]
    ZeroVariance {
        /// What has zero variance.
        what: &'static str,
    },
    /// After dropping zero differences (scipy's `zero_method="wilcox"`)
    /// nothing is left to rank.
    #[error("all paired differences are zero: the Wilcoxon signed-rank test is undefined")]
    AllDifferencesZero,
    /// The degrees of freedom are not usable by the t distribution (e.g. the
    /// Welch–Satterthwaite formula underflowed for extremely small variances).
    #[error("invalid t distribution: {reason}")]
    Distribution {
        /// Message of the distribution library.
        reason: String,
    },
}

/// Descriptive statistics of a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// Number of values.
    pub n: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Sample standard deviation (divisor `n - 1`, numpy `ddof=1`).
    pub std: f64,
    /// Median (mean of the two middle values for even `n`).
    pub median: f64,
    /// Root mean square, the usual headline number for calibration accuracy.
    pub rms: f64,
    /// 95th percentile with numpy's default linear interpolation.
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

/// Outcome of a two-sided hypothesis test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestResult {
    /// Test statistic as scipy reports it.
    pub statistic: f64,
    /// Degrees of freedom of the t distribution; `None` for rank tests.
    pub dof: Option<f64>,
    /// Two-sided p-value.
    pub p_value: f64,
}

/// Descriptive statistics of `values`, matching numpy (`mean`, `std(ddof=1)`,
/// `median`, `percentile(.., 95)`, `max`).
///
/// Needs at least two finite values, because the sample standard deviation
/// of a single value is undefined.
pub fn summary(values: &[f64]) -> Result<Summary, StatsError> {
    check_sample("values", values, 2)?;
    let n = values.len();
    let mean = mean(values);
    let std = sample_variance(values, mean).sqrt();
    let rms = (values.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();

    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = if n % 2 == 1 {
        sorted[n / 2]
    } else {
        (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0
    };
    let max = sorted[n - 1];

    Ok(Summary {
        n,
        mean,
        std,
        median,
        rms,
        p95: percentile_linear(&sorted, P95),
        max,
    })
}

/// Percentile `q` (in `[0, 1]`) of `values` with numpy's default linear
/// interpolation (`numpy.percentile(values, 100 * q)`), as `p95` of
/// [`summary`]; the report's verdict uses it for the 99.7th percentile, the
/// distribution-free counterpart of the "3σ" figure vendors quote.
pub fn percentile(values: &[f64], q: f64) -> Result<f64, StatsError> {
    check_sample("values", values, 1)?;
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    Ok(percentile_linear(&sorted, q.clamp(0.0, 1.0)))
}

/// Paired t-test on the row-wise differences `a - b`, like
/// `scipy.stats.ttest_rel(a, b)`; `dof = n - 1`.
///
/// Fails with [`StatsError::ZeroVariance`] when all differences are equal.
pub fn paired_t(a: &[f64], b: &[f64]) -> Result<TestResult, StatsError> {
    let d = paired_differences(a, b, 2)?;
    let n = d.len() as f64;
    let mean = mean(&d);
    let var = sample_variance(&d, mean);
    if var == 0.0 {
        return Err(StatsError::ZeroVariance {
            what: "the paired differences (all differences are equal)",
        });
    }
    two_sided_t(mean / (var / n).sqrt(), n - 1.0)
}

/// Welch's t-test for independent samples with unequal variances, like
/// `scipy.stats.ttest_ind(a, b, equal_var=False)`; `dof` is the
/// Welch–Satterthwaite approximation.
pub fn welch_t(a: &[f64], b: &[f64]) -> Result<TestResult, StatsError> {
    let (ma, va, na) = moments("a", a)?;
    let (mb, vb, nb) = moments("b", b)?;
    let (sa, sb) = (va / na, vb / nb);
    let se2 = sa + sb;
    if se2 == 0.0 {
        return Err(StatsError::ZeroVariance {
            what: "both samples (each sample is constant)",
        });
    }
    let dof = se2 * se2 / (sa * sa / (na - 1.0) + sb * sb / (nb - 1.0));
    two_sided_t((ma - mb) / se2.sqrt(), dof)
}

/// Student's t-test for independent samples with a pooled variance, like
/// `scipy.stats.ttest_ind(a, b, equal_var=True)`; `dof = n_a + n_b - 2`.
pub fn student_t(a: &[f64], b: &[f64]) -> Result<TestResult, StatsError> {
    let (ma, va, na) = moments("a", a)?;
    let (mb, vb, nb) = moments("b", b)?;
    let dof = na + nb - 2.0;
    let pooled = ((na - 1.0) * va + (nb - 1.0) * vb) / dof;
    if pooled == 0.0 {
        return Err(StatsError::ZeroVariance {
            what: "the pooled samples (each sample is constant)",
        });
    }
    two_sided_t((ma - mb) / (pooled * (1.0 / na + 1.0 / nb)).sqrt(), dof)
}

/// Wilcoxon signed-rank test on the differences `a - b`, like
/// `scipy.stats.wilcoxon(a, b)` with its defaults in scipy 1.17
/// (`zero_method="wilcox"`, `correction=False`, `method="auto"`).
///
/// Zero differences are dropped and tied magnitudes get average ranks. The
/// statistic is `min(W+, W-)`. With `n` the number of rows (zeros included),
/// the p-value is taken, as scipy's `method="auto"` does:
/// - `n <= 50`, no ties and no zeros: exact null distribution;
/// - `n <= 13` with ties or zeros: exhaustive sign-flip permutation test, i.e.
///   the exact distribution of the tie-averaged rank sum;
/// - otherwise: normal approximation with tie correction and without
///   continuity correction.
pub fn wilcoxon_signed_rank(a: &[f64], b: &[f64]) -> Result<TestResult, StatsError> {
    let d = paired_differences(a, b, 1)?;
    let n = d.len();
    let nonzero: Vec<f64> = d.into_iter().filter(|&x| x != 0.0).collect();
    let has_zeros = nonzero.len() < n;
    if nonzero.is_empty() {
        return Err(StatsError::AllDifferencesZero);
    }
    let (ranks2, tie_sizes) = doubled_average_ranks(&nonzero);
    let has_ties = tie_sizes.iter().any(|&t| t > 1);

    let m = nonzero.len();
    let total2 = m * (m + 1);
    let plus2: usize = nonzero
        .iter()
        .zip(&ranks2)
        .filter(|(x, _)| **x > 0.0)
        .map(|(_, r)| r)
        .sum();
    let minus2 = total2 - plus2;
    let statistic = plus2.min(minus2) as f64 / 2.0;

    let exact =
        n <= WILCOXON_PERMUTATION_MAX_N || (n <= WILCOXON_EXACT_MAX_N && !has_ties && !has_zeros);
    let p_value = if exact {
        exact_signed_rank_p(&ranks2, plus2)
    } else {
        let m = m as f64;
        let ties: f64 = tie_sizes
            .iter()
            .map(|&t| {
                let t = t as f64;
                t * t * t - t
            })
            .sum();
        let mean = m * (m + 1.0) / 4.0;
        let se = ((m * (m + 1.0) * (2.0 * m + 1.0) - ties / 2.0) / 24.0).sqrt();
        let z = (plus2 as f64 / 2.0 - mean) / se;
        2.0 * Normal::standard().sf(z.abs())
    };

    Ok(TestResult {
        statistic,
        dof: None,
        p_value: p_value.min(1.0),
    })
}

/// Rejects empty samples, non-finite values and samples shorter than `needed`.
fn check_sample(sample: &'static str, values: &[f64], needed: usize) -> Result<(), StatsError> {
    if values.is_empty() {
        return Err(StatsError::Empty { sample });
    }
    if let Some(index) = values.iter().position(|v| !v.is_finite()) {
        return Err(StatsError::NonFinite { sample, index });
    }
    if values.len() < needed {
        return Err(StatsError::TooFewValues {
            sample,
            needed,
            got: values.len(),
        });
    }
    Ok(())
}

/// Validated row-wise differences `a - b` of two paired samples.
fn paired_differences(a: &[f64], b: &[f64], needed: usize) -> Result<Vec<f64>, StatsError> {
    check_sample("a", a, needed)?;
    check_sample("b", b, needed)?;
    if a.len() != b.len() {
        return Err(StatsError::UnequalLengths {
            a: a.len(),
            b: b.len(),
        });
    }
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    if let Some(index) = d.iter().position(|v| !v.is_finite()) {
        return Err(StatsError::NonFinite {
            sample: "a - b",
            index,
        });
    }
    Ok(d)
}

/// Mean, sample variance and length (as `f64`) of a validated sample with at
/// least two values, for the independent-sample t-tests.
fn moments(sample: &'static str, values: &[f64]) -> Result<(f64, f64, f64), StatsError> {
    check_sample(sample, values, 2)?;
    let mean = mean(values);
    Ok((mean, sample_variance(values, mean), values.len() as f64))
}

/// Arithmetic mean of a non-empty sample.
fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

/// Sample variance (divisor `n - 1`) of a sample with at least two values.
///
/// Exactly zero for a constant sample, so that the zero-variance checks do
/// not depend on rounding in the mean.
fn sample_variance(values: &[f64], mean: f64) -> f64 {
    match values.split_first() {
        Some((first, rest)) if rest.iter().any(|v| v != first) => {
            values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / (values.len() - 1) as f64
        }
        _ => 0.0,
    }
}

/// Percentile `q` (in `[0, 1]`) of a sorted, non-empty sample with numpy's
/// default `method="linear"`, including numpy's two-sided interpolation
/// formula (`_lerp`) so that results agree to the last bits.
fn percentile_linear(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q;
    let lo = h.floor();
    let t = h - lo;
    let i = lo as usize;
    let a = sorted[i];
    let b = sorted[(i + 1).min(sorted.len() - 1)];
    let diff = b - a;
    if t >= 0.5 {
        b - diff * (1.0 - t)
    } else {
        a + diff * t
    }
}

/// Two-sided p-value of a t statistic with `dof` degrees of freedom.
fn two_sided_t(statistic: f64, dof: f64) -> Result<TestResult, StatsError> {
    let dist = StudentsT::new(0.0, 1.0, dof).map_err(|e| StatsError::Distribution {
        reason: format!("{e} (degrees of freedom {dof})"),
    })?;
    Ok(TestResult {
        statistic,
        dof: Some(dof),
        p_value: 2.0 * dist.sf(statistic.abs()),
    })
}

/// Average ranks of `|values|`, doubled so that tied (half-integer) ranks
/// stay integers, in input order; plus the size of every tie group (1 for
/// untied values), as `scipy.stats.rankdata(method="average")` ranks them.
fn doubled_average_ranks(values: &[f64]) -> (Vec<usize>, Vec<usize>) {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&i, &j| values[i].abs().total_cmp(&values[j].abs()));
    let mut ranks2 = vec![0; values.len()];
    let mut tie_sizes = Vec::new();
    let mut start = 0;
    while start < order.len() {
        let magnitude = values[order[start]].abs();
        let end = start
            + order[start..]
                .iter()
                .take_while(|&&i| values[i].abs() == magnitude)
                .count();
        // Positions start..end hold ranks start+1..=end; twice their mean:
        for &i in &order[start..end] {
            ranks2[i] = start + 1 + end;
        }
        tie_sizes.push(end - start);
        start = end;
    }
    (ranks2, tie_sizes)
}

/// Exact two-sided p-value of the doubled rank sum `plus2` of the positive
/// differences, under the null that each sign is `+` or `-` with probability
/// 1/2: `2 * min(P(T <= plus2), P(T >= plus2))`, capped at 1 by the caller.
///
/// The distribution is counted by dynamic programming over the doubled ranks.
/// Only called with at most [`WILCOXON_EXACT_MAX_N`] ranks, so the counts
/// (at most `2^50`) fit in `u64` and convert to `f64` exactly.
fn exact_signed_rank_p(ranks2: &[usize], plus2: usize) -> f64 {
    let total2: usize = ranks2.iter().sum();
    let mut counts = vec![0u64; total2 + 1];
    counts[0] = 1;
    let mut reach = 0;
    for &r in ranks2 {
        reach += r;
        for s in (r..=reach).rev() {
            counts[s] += counts[s - r];
        }
    }
    let le: u64 = counts[..=plus2].iter().sum();
    let ge: u64 = counts[plus2..].iter().sum();
    let patterns = (ranks2.len() as f64).exp2();
    2.0 * le.min(ge) as f64 / patterns
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tolerance for statistics and degrees of freedom (relative).
    const STAT_TOL: f64 = 1e-10;
    /// Tolerance for p-values (relative).
    const P_TOL: f64 = 1e-8;

    fn assert_close(what: &str, actual: f64, expected: f64, rel_tol: f64) {
        let scale = expected.abs().max(f64::MIN_POSITIVE);
        assert!(
            (actual - expected).abs() <= rel_tol * scale,
            "{what}: got {actual:e}, expected {expected:e} (rel tol {rel_tol:e})"
        );
    }

    #[test]
    fn percentile_matches_numpy() {
        // numpy.percentile(PT_A, 99.7), numpy.percentile(PT_A, 95).
        assert_close("p99.7", percentile(&PT_A, 0.997).unwrap(), P997_A, STAT_TOL);
        assert_close("p95", percentile(&PT_A, 0.95).unwrap(), P95_A, STAT_TOL);
        assert_eq!(percentile(&[2.5], 0.997), Ok(2.5));
        assert_eq!(
            percentile(&[], 0.5),
            Err(StatsError::Empty { sample: "values" })
        );
    }

    fn assert_test(r: TestResult, statistic: f64, dof: Option<f64>, p_value: f64) {
        assert_close("statistic", r.statistic, statistic, STAT_TOL);
        match (r.dof, dof) {
            (Some(got), Some(want)) => assert_close("dof", got, want, STAT_TOL),
            (got, want) => assert_eq!(got, want, "dof"),
        }
        assert_close("p-value", r.p_value, p_value, P_TOL);
    }

    // Twelve validation rows, error norms (mm) of two models.
    const PT_A: [f64; 12] = [
        0.42, 0.456, 0.387, 0.313, 0.365, 0.301, 0.427, 0.581, 0.361, 0.346, 0.479, 0.463,
    ];
    const PT_B: [f64; 12] = [
        0.364, 0.462, 0.339, 0.221, 0.396, 0.278, 0.491, 0.608, 0.422, 0.31, 0.505, 0.397,
    ];
    /// numpy.percentile(PT_A, 99.7) and numpy.percentile(PT_A, 95).
    const P997_A: f64 = 0.577634;
    const P95_A: f64 = 0.5248999999999999;
    // Independent samples of different size and spread.
    const X: [f64; 10] = [
        0.358, 0.341, 0.224, 0.323, 0.348, 0.356, 0.273, 0.326, 0.301, 0.31,
    ];
    const Y: [f64; 14] = [
        0.559, 0.297, 0.405, 0.534, 0.328, 0.394, 0.425, 0.419, 0.238, 0.421, 0.6, 0.193, 0.53,
        0.427,
    ];
    // n = 15, differences without ties or zeros: exact path.
    const WA: [f64; 15] = [
        0.436, 0.7, 0.576, 0.38, 0.507, 0.558, 0.481, 0.568, 0.493, 0.567, 0.644, 0.432, 0.52,
        0.454, 0.513,
    ];
    const WB: [f64; 15] = [
        0.501, 0.716, 0.562, 0.278, 0.385, 0.634, 0.515, 0.486, 0.622, 0.574, 0.622, 0.301, 0.435,
        0.45, 0.512,
    ];
    // n = 20 on a 1/64 mm grid (exact binary differences): 13 tied
    // magnitudes and one zero difference, so n > 13 takes the normal path.
    const TA: [f64; 20] = [
        0.46875, 0.65625, 0.453125, 0.46875, 0.53125, 0.484375, 0.484375, 0.390625, 0.5, 0.453125,
        0.609375, 0.5625, 0.5, 0.5625, 0.46875, 0.609375, 0.5, 0.5625, 0.375, 0.53125,
    ];
    const TB: [f64; 20] = [
        0.53125, 0.734375, 0.453125, 0.5, 0.5, 0.359375, 0.5, 0.40625, 0.46875, 0.40625, 0.59375,
        0.546875, 0.4375, 0.515625, 0.5, 0.59375, 0.484375, 0.59375, 0.34375, 0.546875,
    ];
    // n = 10 on a 1/64 mm grid; differences (x 64) are
    // [-3, 4, 0, 4, 2, -2, 5, 6, 2, 1]: ties and a zero with n <= 13, so scipy
    // runs an exhaustive permutation test.
    const SA: [f64; 10] = [
        0.59375, 0.515625, 0.515625, 0.4375, 0.484375, 0.296875, 0.390625, 0.53125, 0.28125,
        0.578125,
    ];
    const SB: [f64; 10] = [
        0.640625, 0.453125, 0.515625, 0.375, 0.453125, 0.328125, 0.3125, 0.4375, 0.25, 0.5625,
    ];

    /// Deterministic paired rows, reproduced in Python as
    /// `a = np.array([0.3 + ((i*37 + 11) % 101)/250 for i in range(n)])`,
    /// `b = np.array([0.28 + ((i*53 + 5) % 103)/260 for i in range(n)])`.
    /// For n = 50 and n = 60 the differences have no ties and no zeros.
    fn formula_rows(n: usize) -> (Vec<f64>, Vec<f64>) {
        (0..n)
            .map(|i| {
                (
                    0.3 + ((i * 37 + 11) % 101) as f64 / 250.0,
                    0.28 + ((i * 53 + 5) % 103) as f64 / 260.0,
                )
            })
            .unzip()
    }

    fn assert_summary(s: Summary, n: usize, expected: [f64; 6]) {
        assert_eq!(s.n, n);
        let [mean, std, median, rms, p95, max] = expected;
        assert_close("mean", s.mean, mean, STAT_TOL);
        assert_close("std", s.std, std, STAT_TOL);
        assert_close("median", s.median, median, STAT_TOL);
        assert_close("rms", s.rms, rms, STAT_TOL);
        assert_close("p95", s.p95, p95, STAT_TOL);
        assert_close("max", s.max, max, STAT_TOL);
    }

    #[test]
    fn summary_matches_numpy() {
        // v = np.array(...); [np.mean(v), np.std(v, ddof=1), np.median(v),
        //  np.sqrt(np.mean(v**2)), np.percentile(v, 95), np.max(v)]
        // (numpy 2.4.6). p95 virtual index: 10.45 (PT_A), 8.55 (X, the
        // t >= 0.5 branch of numpy's lerp), 13.3 (WA, odd n).
        let expected_pt_a = [
            0.40825,
            0.07955572660948824,
            0.40349999999999997,
            0.4152947748286751,
            0.5248999999999999,
            0.581,
        ];
        assert_summary(summary(&PT_A).expect("summary"), 12, expected_pt_a);
        let expected_x = [
            0.316,
            0.041814404748177915,
            0.3245,
            0.3184801406681428,
            0.3571,
            0.358,
        ];
        assert_summary(summary(&X).expect("summary"), 10, expected_x);
        let expected_wa = [
            0.5219333333333334,
            0.08368176680279936,
            0.513,
            0.5281573629137437,
            0.6607999999999999,
            0.7,
        ];
        assert_summary(summary(&WA).expect("summary"), 15, expected_wa);
        let expected_y = [
            0.41214285714285703,
            0.11934942695415725,
            0.42,
            0.42788850350128765,
            0.57335,
            0.6,
        ];
        assert_summary(summary(&Y).expect("summary"), 14, expected_y);
    }

    #[test]
    fn summary_rejects_degenerate_input() {
        assert_eq!(summary(&[]), Err(StatsError::Empty { sample: "values" }));
        assert_eq!(
            summary(&[0.1, f64::NAN, 0.3]),
            Err(StatsError::NonFinite {
                sample: "values",
                index: 1
            })
        );
        assert_eq!(
            summary(&[0.1, f64::INFINITY]),
            Err(StatsError::NonFinite {
                sample: "values",
                index: 1
            })
        );
        assert_eq!(
            summary(&[0.1]),
            Err(StatsError::TooFewValues {
                sample: "values",
                needed: 2,
                got: 1
            })
        );
        let constant = summary(&[0.1, 0.1, 0.1]).expect("summary");
        assert_eq!(constant.std, 0.0);
    }

    #[test]
    fn paired_t_matches_scipy() {
        // scipy 1.17.1: stats.ttest_rel(PT_A, PT_B)
        // -> statistic 0.5922115370489812, pvalue 0.5656828996295586, df 11
        assert_test(
            paired_t(&PT_A, &PT_B).expect("paired_t"),
            0.5922115370489812,
            Some(11.0),
            0.5656828996295586,
        );
        // Swapping the samples flips the sign only.
        assert_test(
            paired_t(&PT_B, &PT_A).expect("paired_t"),
            -0.5922115370489812,
            Some(11.0),
            0.5656828996295586,
        );
        // a, b = formula_rows(60); stats.ttest_rel(a, b)
        // -> statistic 1.5222772368294606, pvalue 0.13328169202121268, df 59
        let (a, b) = formula_rows(60);
        assert_test(
            paired_t(&a, &b).expect("paired_t"),
            1.5222772368294606,
            Some(59.0),
            0.13328169202121268,
        );
    }

    #[test]
    fn paired_t_rejects_degenerate_input() {
        assert_eq!(
            paired_t(&PT_A, &PT_B[..11]),
            Err(StatsError::UnequalLengths { a: 12, b: 11 })
        );
        assert_eq!(
            paired_t(&[0.1], &[0.2]),
            Err(StatsError::TooFewValues {
                sample: "a",
                needed: 2,
                got: 1
            })
        );
        assert_eq!(
            paired_t(&[0.1, 0.2], &[]),
            Err(StatsError::Empty { sample: "b" })
        );
        assert_eq!(
            paired_t(&[0.1, 0.2], &[0.1, f64::NAN]),
            Err(StatsError::NonFinite {
                sample: "b",
                index: 1
            })
        );
        assert_eq!(
            paired_t(&[f64::MAX, 0.2], &[-f64::MAX, 0.1]),
            Err(StatsError::NonFinite {
                sample: "a - b",
                index: 0
            })
        );
        // Equal differences: scipy returns statistic inf (or nan when all are
        // zero); here it is a typed error.
        let zero_variance = Err(StatsError::ZeroVariance {
            what: "the paired differences (all differences are equal)",
        });
        assert_eq!(paired_t(&[0.5, 0.6, 0.7], &[0.4, 0.5, 0.6]), zero_variance);
        assert_eq!(paired_t(&PT_A, &PT_A), zero_variance);
    }

    #[test]
    fn welch_t_matches_scipy() {
        // stats.ttest_ind(X, Y, equal_var=False)
        // -> statistic -2.7843604090610277, pvalue 0.01265552222016797,
        //    df 17.12156102946878
        assert_test(
            welch_t(&X, &Y).expect("welch_t"),
            -2.7843604090610277,
            Some(17.12156102946878),
            0.01265552222016797,
        );
        // stats.ttest_ind(Y, X, equal_var=False)
        // -> statistic 2.7843604090610277, same pvalue and df
        assert_test(
            welch_t(&Y, &X).expect("welch_t"),
            2.7843604090610277,
            Some(17.12156102946878),
            0.01265552222016797,
        );
        // One constant sample is fine:
        // stats.ttest_ind([0.5]*4, [0.4, 0.6, 0.7], equal_var=False)
        // -> statistic -0.7559289460184544, pvalue 0.5285954792089683, df 2.0
        assert_test(
            welch_t(&[0.5; 4], &[0.4, 0.6, 0.7]).expect("welch_t"),
            -0.7559289460184544,
            Some(2.0),
            0.5285954792089683,
        );
    }

    #[test]
    fn student_t_matches_scipy() {
        // stats.ttest_ind(X, Y, equal_var=True)
        // -> statistic -2.4298761144104253, pvalue 0.023718451324673134, df 22
        assert_test(
            student_t(&X, &Y).expect("student_t"),
            -2.4298761144104253,
            Some(22.0),
            0.023718451324673134,
        );
        // stats.ttest_ind(Y, X, equal_var=True)
        // -> statistic 2.4298761144104253, same pvalue and df
        assert_test(
            student_t(&Y, &X).expect("student_t"),
            2.4298761144104253,
            Some(22.0),
            0.023718451324673134,
        );
    }

    #[test]
    fn independent_t_tests_reject_degenerate_input() {
        for test in [welch_t, student_t] {
            assert_eq!(
                test(&[0.1], &X),
                Err(StatsError::TooFewValues {
                    sample: "a",
                    needed: 2,
                    got: 1
                })
            );
            assert_eq!(test(&X, &[]), Err(StatsError::Empty { sample: "b" }));
            assert_eq!(
                test(&X, &[0.1, f64::NEG_INFINITY]),
                Err(StatsError::NonFinite {
                    sample: "b",
                    index: 1
                })
            );
            assert!(matches!(
                test(&[0.3, 0.3], &[0.2, 0.2, 0.2]),
                Err(StatsError::ZeroVariance { .. })
            ));
        }
    }

    #[test]
    fn wilcoxon_exact_without_ties_matches_scipy() {
        // stats.wilcoxon(WA, WB) -> statistic 46.0, pvalue 0.45428466796875
        // (exact; method="asymptotic" would give 0.42652824883677154)
        assert_test(
            wilcoxon_signed_rank(&WA, &WB).expect("wilcoxon"),
            46.0,
            None,
            0.45428466796875,
        );
        // stats.wilcoxon(WB, WA) -> statistic 46.0, pvalue 0.45428466796875
        assert_test(
            wilcoxon_signed_rank(&WB, &WA).expect("wilcoxon"),
            46.0,
            None,
            0.45428466796875,
        );
        // Boundary n = 50, still exact: a, b = formula_rows(50);
        // stats.wilcoxon(a, b) -> statistic 479.0, pvalue 0.12799334338745183
        // (method="asymptotic" would give 0.1260056723617116)
        let (a, b) = formula_rows(50);
        assert_test(
            wilcoxon_signed_rank(&a, &b).expect("wilcoxon"),
            479.0,
            None,
            0.12799334338745183,
        );
    }

    #[test]
    fn wilcoxon_small_sample_with_ties_and_zero_matches_scipy_permutation() {
        // stats.wilcoxon(SA, SB) -> statistic 8.0, pvalue 0.09375
        // (scipy 1.17 runs stats.permutation_test over all 2**10 sign flips;
        // method="asymptotic" would give 0.08445614245713748)
        assert_test(
            wilcoxon_signed_rank(&SA, &SB).expect("wilcoxon"),
            8.0,
            None,
            0.09375,
        );
        // stats.wilcoxon(SB, SA) -> statistic 8.0, pvalue 0.09375
        assert_test(
            wilcoxon_signed_rank(&SB, &SA).expect("wilcoxon"),
            8.0,
            None,
            0.09375,
        );
    }

    #[test]
    fn wilcoxon_normal_approximation_matches_scipy() {
        // Ties and a zero with n = 20 > 13:
        // stats.wilcoxon(TA, TB) -> statistic 78.0, pvalue 0.4897861287770253
        // (identical to method="asymptotic")
        assert_test(
            wilcoxon_signed_rank(&TA, &TB).expect("wilcoxon"),
            78.0,
            None,
            0.4897861287770253,
        );
        // stats.wilcoxon(TB, TA) -> statistic 78.0, pvalue 0.4897861287770253
        assert_test(
            wilcoxon_signed_rank(&TB, &TA).expect("wilcoxon"),
            78.0,
            None,
            0.4897861287770253,
        );
        // n = 60 > 50, no ties: a, b = formula_rows(60);
        // stats.wilcoxon(a, b) -> statistic 712.0, pvalue 0.1350696885833801
        let (a, b) = formula_rows(60);
        assert_test(
            wilcoxon_signed_rank(&a, &b).expect("wilcoxon"),
            712.0,
            None,
            0.1350696885833801,
        );
    }

    #[test]
    fn wilcoxon_rejects_degenerate_input() {
        assert_eq!(
            wilcoxon_signed_rank(&[0.5, 0.6], &[0.5, 0.6]),
            Err(StatsError::AllDifferencesZero)
        );
        assert_eq!(
            wilcoxon_signed_rank(&WA, &WB[..14]),
            Err(StatsError::UnequalLengths { a: 15, b: 14 })
        );
        assert_eq!(
            wilcoxon_signed_rank(&[], &[]),
            Err(StatsError::Empty { sample: "a" })
        );
        assert_eq!(
            wilcoxon_signed_rank(&[0.1, f64::NAN], &[0.2, 0.3]),
            Err(StatsError::NonFinite {
                sample: "a",
                index: 1
            })
        );
    }
}
