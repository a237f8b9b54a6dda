//! Parameters the data cannot determine (spec §8, status `held`).
//!
//! The rank analysis ([`super::rank`]) drops parameters that are dependent in
//! exact arithmetic. A parameter can pass it and still be meaningless: nearly
//! collinear with others (the UR10's `dtheta5`/`da6`, correlation +1.000), or
//! so poorly seen that its standard error is larger than any physical error of
//! its kind (`dtheta5 = -13.5° ± 10.6`). Put in service, such a value moves the
//! tool by millimetres outside the measured rows. This module decides, from a
//! fit's covariance alone, which free parameters to hold at their start
//! (nominal) value; the caller fits again without them.
//!
//! Two tests, in this order, each removing one parameter at a time and
//! conditioning the covariance on it (the Schur complement: what the next fit's
//! covariance will be, to first order), so that holding one member of a
//! collinear pair clears the other:
//!
//! 1. **Near-dependence**: the variance inflation factor of an estimate,
//!    `VIF_i = Σ_ii·(Σ⁻¹)_ii = 1/(1 − R_i²)`, with `R_i` its multiple correlation
//!    with all other estimates. Beyond `max_variance_inflation` the parameter
//!    whose standard error is largest against its kind's bound goes first.
//! 2. **Standard error** beyond its kind's bound (mm, deg, deg/(N·m)).
//!
//! Frames (world, tool translation) are never held: registration determines
//! them, and no nominal value of theirs means anything for a tracker placed
//! anywhere.

use nalgebra::DMatrix;

use crate::robot::ParamId;
use crate::robot::params::ParamKind;

/// Bounds of [`parameters_to_hold`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HoldOptions {
    /// Largest standard error of a length (mm).
    pub max_std_error_mm: f64,
    /// Largest standard error of an angle (deg).
    pub max_std_error_deg: f64,
    /// Largest standard error of a compliance (deg/(N·m)).
    pub max_std_error_compliance: f64,
    /// Largest variance inflation factor `1/(1 − R²)`; 1e4 is |R| ≈ 0.99995.
    pub max_variance_inflation: f64,
}

impl Default for HoldOptions {
    fn default() -> Self {
        HoldOptions {
            max_std_error_mm: 0.5,
            max_std_error_deg: 0.05,
            max_std_error_compliance: 0.01,
            max_variance_inflation: 1e4,
        }
    }
}

impl HoldOptions {
    /// The standard-error bound of `id`'s kind and its unit; `None` for frames.
    pub fn bound(&self, id: ParamId) -> Option<(f64, &'static str)> {
        match id.kind() {
            ParamKind::WorldTranslation(_)
            | ParamKind::WorldRotation(_)
            | ParamKind::ToolTranslation { .. } => None,
            ParamKind::A(_) | ParamKind::D(_) => Some((self.max_std_error_mm, "mm")),
            ParamKind::ToolRotation(_)
            | ParamKind::Theta(_)
            | ParamKind::Alpha(_)
            | ParamKind::Backlash(_)
            | ParamKind::Harmonic { .. } => Some((self.max_std_error_deg, "deg")),
            ParamKind::Compliance(_) => Some((self.max_std_error_compliance, "deg/(N·m)")),
            ParamKind::Track(term) => match term.unit() {
                "deg" => Some((self.max_std_error_deg, "deg")),
                _ => Some((self.max_std_error_mm, "mm")),
            },
            // The positioner's base is a frame, like the world's.
            ParamKind::Positioner(term) => match (term.axis(), term.unit()) {
                (None, _) => None,
                (Some(_), "deg") => Some((self.max_std_error_deg, "deg")),
                (Some(_), _) => Some((self.max_std_error_mm, "mm")),
            },
        }
    }
}

/// A parameter to hold and why (the parameters table's `reason`).
#[derive(Debug, Clone, PartialEq)]
pub struct Hold {
    pub id: ParamId,
    pub reason: String,
}

/// The free parameters (`free`, in the order of the row-major `covariance`,
/// the parameters' units) the data cannot determine, in the order they were
/// chosen. Empty when every estimate is within its bounds.
pub fn parameters_to_hold(
    free: &[ParamId],
    covariance: &[f64],
    options: &HoldOptions,
    name_of: impl Fn(ParamId) -> String,
) -> Vec<Hold> {
    let m = free.len();
    if m == 0 || covariance.len() != m * m {
        return Vec::new();
    }
    let mut kept: Vec<usize> = (0..m).collect();
    let mut sigma = DMatrix::from_row_slice(m, m, covariance);
    let mut holds = Vec::new();
    // Each round holds one parameter; at most every bounded one.
    while kept.len() > 1 {
        let std: Vec<f64> = (0..kept.len())
            .map(|i| sigma[(i, i)].max(0.0).sqrt())
            .collect();
        // Standard error against the kind's bound: which member of a collinear
        // group is the less determined (frames, unbounded, never go).
        let excess = |i: usize| {
            options
                .bound(free[kept[i]])
                .map(|(bound, _)| std[i] / bound)
        };
        let inflation = variance_inflation(&sigma);
        let near_dependent = (0..kept.len())
            .filter(|i| excess(*i).is_some())
            .filter(|i| inflation[*i] > options.max_variance_inflation)
            .max_by(|a, b| {
                excess(*a)
                    .unwrap_or(0.0)
                    .total_cmp(&excess(*b).unwrap_or(0.0))
            });
        let chosen = match near_dependent {
            Some(i) => {
                let partner = (0..kept.len()).filter(|j| *j != i).max_by(|a, b| {
                    correlation(&sigma, i, *a)
                        .abs()
                        .total_cmp(&correlation(&sigma, i, *b).abs())
                });
                let reason = match partner {
                    Some(j) => format!(
                        "near-dependent on {} (corr {:+.3}, variance inflation {:.1e} > {:.0e})",
                        name_of(free[kept[j]]),
                        correlation(&sigma, i, j),
                        inflation[i],
                        options.max_variance_inflation
                    ),
                    None => format!("variance inflation {:.1e}", inflation[i]),
                };
                Some((i, reason))
            }
            None => (0..kept.len())
                .filter(|i| excess(*i).is_some_and(|e| e > 1.0))
                .max_by(|a, b| {
                    excess(*a)
                        .unwrap_or(0.0)
                        .total_cmp(&excess(*b).unwrap_or(0.0))
                })
                .map(|i| {
                    let (bound, unit) = options.bound(free[kept[i]]).unwrap_or((0.0, ""));
                    (
                        i,
                        format!("std error {} {unit} > {bound}", significant(std[i])),
                    )
                }),
        };
        let Some((i, reason)) = chosen else {
            break;
        };
        holds.push(Hold {
            id: free[kept[i]],
            reason,
        });
        sigma = condition_on(&sigma, i);
        kept.remove(i);
    }
    holds
}

/// `1/(1 − R_i²)` of each estimate: `Σ_ii·(Σ⁻¹)_ii` (∞ where Σ is singular).
fn variance_inflation(sigma: &DMatrix<f64>) -> Vec<f64> {
    let n = sigma.nrows();
    // Correlation form first: the units of the parameters differ by orders of
    // magnitude, the correlation matrix's entries do not.
    let scale: Vec<f64> = (0..n)
        .map(|i| 1.0 / sigma[(i, i)].max(0.0).sqrt())
        .collect();
    let corr = DMatrix::from_fn(n, n, |i, j| sigma[(i, j)] * scale[i] * scale[j]);
    match corr.clone().cholesky() {
        Some(cholesky) => {
            let inverse = cholesky.inverse();
            (0..n).map(|i| inverse[(i, i)]).collect()
        }
        None => vec![f64::INFINITY; n],
    }
}

fn correlation(sigma: &DMatrix<f64>, i: usize, j: usize) -> f64 {
    let denominator = (sigma[(i, i)] * sigma[(j, j)]).sqrt();
    if denominator > 0.0 {
        sigma[(i, j)] / denominator
    } else {
        0.0
    }
}

/// The covariance of the other estimates with estimate `p` held exactly:
/// `Σ_rr − Σ_rp·Σ_pr / Σ_pp`, without row and column `p`.
fn condition_on(sigma: &DMatrix<f64>, p: usize) -> DMatrix<f64> {
    let n = sigma.nrows();
    let rest: Vec<usize> = (0..n).filter(|i| *i != p).collect();
    let pp = sigma[(p, p)];
    DMatrix::from_fn(n - 1, n - 1, |a, b| {
        let (i, j) = (rest[a], rest[b]);
        if pp > 0.0 {
            sigma[(i, j)] - sigma[(i, p)] * sigma[(p, j)] / pp
        } else {
            sigma[(i, j)]
        }
    })
}

/// Three significant digits, as a reason is read.
fn significant(value: f64) -> String {
    if value == 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    let digits = (2 - value.abs().log10().floor() as i32).max(0) as usize;
    format!("{value:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(name: &str) -> ParamId {
        ParamId::from_name(name).unwrap()
    }

    /// Covariance of estimates with standard errors `std` and correlations `rho`.
    fn covariance(std: &[f64], rho: &[(usize, usize, f64)]) -> Vec<f64> {
        let n = std.len();
        let mut c = vec![0.0; n * n];
        for i in 0..n {
            c[i * n + i] = std[i] * std[i];
        }
        for &(i, j, r) in rho {
            c[i * n + j] = r * std[i] * std[j];
            c[j * n + i] = r * std[i] * std[j];
        }
        c
    }

    #[test]
    fn well_determined_estimates_are_kept() {
        let free = [id("x_w"), id("dtheta2"), id("da3"), id("k2")];
        let c = covariance(&[0.1, 0.002, 0.05, 1e-5], &[(1, 2, 0.9)]);
        let holds = parameters_to_hold(&free, &c, &HoldOptions::default(), |p| p.name().into());
        assert!(holds.is_empty(), "{holds:?}");
    }

    /// A collinear pair loses the member worse determined for its kind; the
    /// other, conditioned on it, is then well determined and stays.
    #[test]
    fn one_member_of_a_near_dependent_pair_is_held() {
        let free = [id("x_w"), id("dtheta5"), id("da6"), id("da2")];
        let c = covariance(&[0.1, 10.6, 0.3, 0.02], &[(1, 2, 0.99999)]);
        let holds = parameters_to_hold(&free, &c, &HoldOptions::default(), |p| p.name().into());
        assert_eq!(holds.len(), 1, "{holds:?}");
        assert_eq!(holds[0].id, id("dtheta5"));
        assert!(
            holds[0]
                .reason
                .starts_with("near-dependent on da6 (corr +1.000"),
            "{}",
            holds[0].reason
        );
    }

    #[test]
    fn a_loose_estimate_is_held_with_its_standard_error() {
        let free = [id("dd5"), id("dalpha6"), id("da2")];
        let c = covariance(&[43.6, 0.01, 0.02], &[]);
        let holds = parameters_to_hold(&free, &c, &HoldOptions::default(), |p| p.name().into());
        assert_eq!(holds.len(), 1, "{holds:?}");
        assert_eq!(holds[0].id, id("dd5"));
        assert_eq!(holds[0].reason, "std error 43.6 mm > 0.5");
    }

    /// Frames are determined by registration and never held, however loose.
    #[test]
    fn frames_are_never_held() {
        let free = [id("x_w"), id("y_t")];
        let c = covariance(&[50.0, 40.0], &[(0, 1, 0.999999)]);
        assert!(
            parameters_to_hold(&free, &c, &HoldOptions::default(), |p| p.name().into()).is_empty()
        );
    }

    /// `fixtures/tools/held_check.py`: numpy's VIF (Σ_ii·(Σ⁻¹)_ii) and the
    /// covariance of a refit without the held column, for a design with a
    /// near-collinear pair (dtheta5, da6) as on the UR10.
    #[test]
    fn variance_inflation_and_conditioning_match_numpy() {
        let covariance = [
            0.033093296514034955,
            0.037395108892815186,
            -0.057628956467341334,
            0.006687449977359499,
            0.03739510889236428,
            4201.936286920559,
            -4198.495970572332,
            2.0076312003249166,
            -0.05762895646712745,
            -4198.495970572333,
            4195.11497598412,
            -2.026642254651629,
            0.00668744997735936,
            2.007631200325337,
            -2.0266422546520486,
            0.03710186571610459,
        ];
        let numpy_vif = [
            1.2823652399152576,
            115815.86890965099,
            115870.22929470359,
            1.2985653000671018,
        ];
        let numpy_conditioned = [
            0.03309296371646888,
            -0.020264464651196846,
            0.006669583074525646,
            -0.020264464651196846,
            0.05650501654929075,
            -0.020654793300381426,
            0.006669583074525646,
            -0.020654793300381426,
            0.03614264530882117,
        ];
        let sigma = DMatrix::from_row_slice(4, 4, &covariance);
        for (got, want) in variance_inflation(&sigma).iter().zip(numpy_vif) {
            assert!((got / want - 1.0).abs() < 1e-6, "{got} vs {want}");
        }
        let conditioned = condition_on(&sigma, 1);
        for (got, want) in conditioned.transpose().iter().zip(numpy_conditioned) {
            assert!(
                (got - want).abs() < 1e-9 * want.abs().max(1e-3),
                "{got} vs {want}"
            );
        }
        let free = [id("x_w"), id("dtheta5"), id("da6"), id("da2")];
        let holds = parameters_to_hold(&free, &covariance, &HoldOptions::default(), |p| {
            p.name().into()
        });
        assert_eq!(holds.len(), 1, "{holds:?}");
        assert_eq!(holds[0].id, id("dtheta5"));
        assert!(
            holds[0]
                .reason
                .starts_with("near-dependent on da6 (corr -1.000"),
            "{}",
            holds[0].reason
        );
    }

    /// The conditioning is the exact covariance of the reduced linear problem:
    /// hand-computed for a 2×2 case.
    #[test]
    fn conditioning_is_the_schur_complement() {
        let sigma = DMatrix::from_row_slice(2, 2, &[4.0, 2.0, 2.0, 9.0]);
        let reduced = condition_on(&sigma, 0);
        assert!((reduced[(0, 0)] - (9.0 - 2.0 * 2.0 / 4.0)).abs() < 1e-15);
        let vif = variance_inflation(&sigma);
        // ρ = 2/(2·3) = 1/3, VIF = 1/(1 − 1/9) = 9/8.
        assert!((vif[0] - 9.0 / 8.0).abs() < 1e-12 && (vif[1] - 9.0 / 8.0).abs() < 1e-12);
    }
}
