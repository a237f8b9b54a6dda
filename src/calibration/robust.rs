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

use nalgebra::Vector3;

/// Median of the χ distribution with 3 degrees of freedom (√ of the χ²₃ median
/// 2.365974): `median(‖r‖) = 1.538172·σ` for `r ~ N(0, σ²I₃)`.
pub const CHI3_MEDIAN: f64 = 1.538_172;

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
