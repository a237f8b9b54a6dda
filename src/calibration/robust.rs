//! The robust default fit: a few bad rows (a beam break, a wrong nest, a typo)
//! must not spoil a calibration, and no threshold in mm may be needed to say
//! which rows are bad.
//!
//! Three stages, each a continuation of the fit before it:
//!
//! 1. least squares, as the paper;
//! 2. if some row lies beyond `reject_sigmas` robust standard deviations, a
//!    Huber fit with threshold `huber_sigmas`·σ̂, so that the gross rows no
//!    longer pull the others (least squares smears one 50 mm error over all
//!    residuals);
//! 3. the rows beyond `reject_sigmas`·σ̂ of that fit are excluded and least
//!    squares is fitted on the rest: the result and its standard errors are then
//!    exactly those of the clean rows.
//!
//! σ̂ is estimated from the data: the median of the rows' (scaled) residual norms
//! divided by the median of a χ distribution with 3 degrees of freedom, which is
//! the per-axis standard deviation for isotropic Gaussian errors. Being a median
//! it ignores up to half the rows being bad, and being estimated per model it
//! grows with a kinematic model's systematic load errors, so those are not taken
//! for outliers. Clean data stop after stage 1 at no extra cost.
//!
//! A 6-D row (position and orientation, spec §8) is one row: its scaled norm
//! is that of its six scaled residuals, compared with the median of χ with 6
//! degrees of freedom for σ̂, and it is down-weighted or excluded whole.

use nalgebra::Vector3;

/// Median of the χ distribution with 3 degrees of freedom (√ of the χ²₃ median
/// 2.365974): `median(‖r‖) = 1.538172·σ` for `r ~ N(0, σ²I₃)`.
pub const CHI3_MEDIAN: f64 = 1.538_172;

/// Median of the χ distribution with 6 degrees of freedom (√ of the χ²₆ median
/// 5.348121): a 6-D row's scaled norm.
pub const CHI6_MEDIAN: f64 = 2.312_600;

/// Settings of the robust fit, in robust standard deviations σ̂.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobustOptions {
    /// Huber threshold of stage 2 (3: about 3 % of clean rows are down-weighted a little).
    pub huber_sigmas: f64,
    /// Rows beyond this are excluded (7: a clean Gaussian row is beyond it with
    /// probability 1e-10).
    pub reject_sigmas: f64,
    /// The fit fails rather than exclude more than this fraction of the rows.
    pub max_excluded_fraction: f64,
}

impl Default for RobustOptions {
    fn default() -> Self {
        RobustOptions {
            huber_sigmas: 3.0,
            reject_sigmas: 7.0,
            max_excluded_fraction: 0.2,
        }
    }
}

/// The robust per-axis standard deviation of rows' scaled residuals: median
/// norm / [`CHI3_MEDIAN`], over the rows whose scale is not zero.
pub fn robust_sigma(residuals_mm: &[Vector3<f64>], row_scale: Option<&[Vector3<f64>]>) -> f64 {
    let mut norms: Vec<f64> = residuals_mm
        .iter()
        .enumerate()
        .filter_map(|(k, r)| match row_scale {
            None => Some(r.norm()),
            Some(scales) if scales[k].iter().any(|s| *s != 0.0) => {
                Some(r.component_mul(&scales[k]).norm())
            }
            Some(_) => None,
        })
        .collect();
    median(&mut norms) / CHI3_MEDIAN
}

/// [`robust_sigma`] over rows some of which are 6-D: the median of each
/// included row's scaled norm over the χ median of its degrees of freedom
/// (`(norm, six_d)` per included row).
pub fn robust_sigma_of_rows(rows: impl Iterator<Item = (f64, bool)>) -> f64 {
    let mut normalised: Vec<f64> = rows
        .map(|(norm, six_d)| norm / if six_d { CHI6_MEDIAN } else { CHI3_MEDIAN })
        .collect();
    median(&mut normalised)
}

/// Median of finite values (NaN sorts last); 0 for none.
fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    let mid = values.len() / 2;
    if values.len() % 2 == 1 {
        values[mid]
    } else {
        0.5 * (values[mid - 1] + values[mid])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn chi3_median_matches_scipy() {
        // scipy.stats.chi(3).median() = 1.5381722...
        assert!((CHI3_MEDIAN - 1.538_172_2).abs() < 1e-6);
    }

    #[test]
    fn chi6_median_matches_scipy_and_six_d_rows_give_their_sigma() {
        // scipy.stats.chi(6).median() = 2.3126004...
        assert!((CHI6_MEDIAN - 2.312_600_4).abs() < 1e-6);
        let mut rng = StdRng::seed_from_u64(5);
        let noise = Normal::new(0.0, 0.03).unwrap();
        // Half the rows 6-D, half 3-D, all with per-axis σ 0.03.
        let rows: Vec<(f64, bool)> = (0..20_000)
            .map(|k| {
                let six_d = k % 2 == 0;
                let axes = if six_d { 6 } else { 3 };
                let norm = (0..axes)
                    .map(|_| {
                        let x: f64 = noise.sample(&mut rng);
                        x * x
                    })
                    .sum::<f64>()
                    .sqrt();
                (norm, six_d)
            })
            .collect();
        let sigma = robust_sigma_of_rows(rows.iter().copied());
        assert!((sigma - 0.03).abs() < 0.0006, "{sigma}");
        // Taking every row for a 3-D one overstates σ by χ₆/χ₃ on the 6-D half.
        let naive = robust_sigma_of_rows(rows.iter().map(|(n, _)| (*n, false)));
        assert!(naive > 0.036, "{naive}");
    }

    #[test]
    fn robust_sigma_recovers_the_noise_and_ignores_gross_rows() {
        let mut rng = StdRng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.02).unwrap();
        let mut residuals: Vec<Vector3<f64>> = (0..20_000)
            .map(|_| Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        let clean = robust_sigma(&residuals, None);
        assert!((clean - 0.02).abs() < 0.0005, "{clean}");
        for r in residuals.iter_mut().step_by(10) {
            *r += Vector3::new(15.0, -3.0, 7.0);
        }
        let spoiled = robust_sigma(&residuals, None);
        assert!((spoiled - 0.02).abs() < 0.004, "{spoiled}");
    }

    #[test]
    fn excluded_rows_do_not_count_and_scales_standardise() {
        let residuals = vec![
            Vector3::new(0.1, 0.0, 0.0),
            Vector3::new(0.2, 0.0, 0.0),
            Vector3::new(90.0, 0.0, 0.0),
        ];
        let scales = vec![
            Vector3::repeat(10.0),
            Vector3::repeat(10.0),
            Vector3::zeros(),
        ];
        // Norms 1 and 2 remain: median 1.5.
        let sigma = robust_sigma(&residuals, Some(&scales));
        assert!((sigma - 1.5 / CHI3_MEDIAN).abs() < 1e-12);
    }
}
