//! Which parameters the data can identify: rank analysis of the scaled
//! identification Jacobian (paper §III.D).
//!
//! Columns are scaled to unit norm (so units do not matter) and taken in a fixed
//! priority order — world frame, tool translation, then joint offsets, twists,
//! lengths, offsets along z, compliances, tool angles last — each kept when its
//! component orthogonal to the kept ones exceeds `tolerance` (sequential QR
//! without pivoting, i.e. Gram–Schmidt, reorthogonalised). The order decides
//! *which* member of a dependent group is held at nominal; it reproduces the
//! spec's choice (dtheta1 goes with gamma_w, dd3 with dd2, ...). With 6-D rows
//! (measured orientations, spec §8) the tool angles come right after the tool
//! translation instead: a probe's mounting is a frame, so of the exactly
//! dependent dtheta6 and tool rotation it is dtheta6 that is held, and the
//! calibrated arm does not turn the next tool by the probe's mounting angle.
//! A column with no
//! effect at all (norm below `tolerance` times the largest) is unidentifiable on
//! its own and combined with nothing: scaling its rounding noise to unit norm
//! would make it look like a mix of everything. The numerical rank is
//! cross-checked with the SVD of the same matrix at the same tolerance.
//!
//! All of this works on the `m × m` triangular factor `R` of the Jacobian, built
//! in one chunked pass over the rows ([`stream::jacobian_factor`], or in
//! `calibrate` the fit's first pass, [`fit_identifiable`](super::fit::fit_identifiable)): since
//! `J = Q·R` with orthonormal `Q`, column norms, inner products, least-squares
//! fits of one column on others and singular values are the same for `R` as for
//! `J`, so the result is the dense analysis's without holding `J`.

use faer::{Mat, MatRef};

use super::{dense, stream};
use crate::robot::params::{MAX_HARMONIC_ORDER, ParamKind};
use crate::robot::{ConfWrench, ParamId, ParamValues, Robot};

/// Result of a rank analysis.
#[derive(Debug, Clone, PartialEq)]
pub struct RankAnalysis {
    /// Identifiable parameters, in the spec's order.
    pub independent: Vec<ParamId>,
    /// Each dependent parameter with the identifiable ones it is combined with
    /// (none for a parameter with no effect at all on the rows).
    pub dependent: Vec<(ParamId, Vec<ParamId>)>,
    /// Singular values of the column-scaled Jacobian, descending.
    pub singular_values: Vec<f64>,
    /// Number of singular values above `tolerance · σ_max`.
    pub svd_rank: usize,
    pub tolerance: f64,
}

/// Priority of a parameter when choosing which of a dependent group to keep;
/// `tool_rotation_first` for rows with measured orientations (module doc).
///
/// A positioner's base (issue #30) comes right after the tool translations:
/// the world frame, the arm's first joint and the positioner's base share
/// one freedom (moving the robot's base frame moves the positioner's with
/// it), and with the base kept the arm's first-joint terms are held as the
/// spec holds them for the arm alone.
fn priority(id: ParamId, tool_rotation_first: bool) -> (usize, usize) {
    const AFTER_JOINT_TERMS: usize = 80 + 2 * crate::robot::MAX_JOINTS * MAX_HARMONIC_ORDER;
    if let ParamKind::Positioner(term) = id.kind()
        && term.axis().is_none()
    {
        return (8, 1 + term.slot());
    }
    let rank = match id.kind() {
        ParamKind::ToolRotation(i) if tool_rotation_first => 9 + i,
        ParamKind::WorldTranslation(i) => i,
        ParamKind::WorldRotation(i) => 3 + i,
        ParamKind::ToolTranslation { axis, .. } => 6 + axis,
        ParamKind::Theta(i) => 10 + i,
        ParamKind::Alpha(i) => 20 + i,
        ParamKind::A(i) => 30 + i,
        ParamKind::D(i) => 40 + i,
        ParamKind::Compliance(i) => 50 + i,
        ParamKind::ToolRotation(i) => 60 + i,
        ParamKind::Backlash(i) => 70 + i,
        ParamKind::Harmonic {
            joint,
            order,
            cosine,
        } => 80 + 2 * (joint * MAX_HARMONIC_ORDER + order - 1) + usize::from(cosine),
        // After every joint term (80 + 2·7·3).
        ParamKind::Track(term) => AFTER_JOINT_TERMS + term.slot(),
        // The axes' errors after the track's.
        ParamKind::Positioner(term) => {
            AFTER_JOINT_TERMS + crate::robot::track::TRACK_TERM_COUNT + term.slot()
        }
    };
    (rank, 0)
}

/// Rank analysis of `candidates` over `rows` at parameter values `at`.
///
/// Cost: one parallel pass over the rows in chunks of `chunk_rows`
/// ([`stream::CHUNK_ROWS`] unless testing), then `m × m` work.
pub fn analyse(
    robot: &Robot,
    at: &ParamValues,
    rows: &[ConfWrench],
    candidates: &[ParamId],
    tolerance: f64,
    chunk_rows: usize,
) -> RankAnalysis {
    let ordered = priority_order(candidates, false);
    let factor = stream::jacobian_factor(robot, at, rows, &ordered, chunk_rows);
    analyse_factor(factor.as_ref(), &ordered, tolerance)
}

/// The candidates in the order the analysis takes them (`tool_rotation_first`:
/// rows with measured orientations).
pub(crate) fn priority_order(candidates: &[ParamId], tool_rotation_first: bool) -> Vec<ParamId> {
    let mut ordered: Vec<ParamId> = candidates.to_vec();
    ordered.sort_by_key(|id| priority(*id, tool_rotation_first));
    ordered
}

/// The analysis from a triangular factor `R` of the Jacobian whose columns are
/// `ordered` (from [`priority_order`]): `RᵀR = JᵀJ`, any number of rows.
pub(crate) fn analyse_factor(
    factor: MatRef<'_, f64>,
    ordered: &[ParamId],
    tolerance: f64,
) -> RankAnalysis {
    let m = ordered.len();
    let norms: Vec<f64> = (0..m).map(|c| factor.col(c).norm_l2()).collect();
    let max_norm = norms.iter().cloned().fold(0.0, f64::max);
    // Unit columns; a column without effect stays zero, so its rounding noise
    // counts neither in the partners' fits nor in the SVD rank.
    let has_effect = |c: usize| norms[c] > tolerance * max_norm;
    let unit = Mat::<f64>::from_fn(factor.nrows(), m, |r, c| {
        if has_effect(c) {
            factor[(r, c)] / norms[c]
        } else {
            0.0
        }
    });

    let mut basis: Vec<Vec<f64>> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    let mut dropped: Vec<usize> = Vec::new();
    let mut without_effect: Vec<usize> = Vec::new();
    for c in 0..m {
        if !has_effect(c) {
            without_effect.push(c);
            continue;
        }
        let mut residual: Vec<f64> = unit.col(c).iter().copied().collect();
        for _ in 0..2 {
            for q in &basis {
                let dot: f64 = q.iter().zip(&residual).map(|(a, b)| a * b).sum();
                for (x, qi) in residual.iter_mut().zip(q) {
                    *x -= dot * qi;
                }
            }
        }
        let norm = residual.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > tolerance {
            residual.iter_mut().for_each(|x| *x /= norm);
            basis.push(residual);
            kept.push(c);
        } else {
            dropped.push(c);
        }
    }

    // Which kept columns each dropped one is a combination of (one least-squares
    // solve, every dropped column a right-hand side).
    let rows = unit.nrows();
    let kept_matrix = Mat::<f64>::from_fn(rows, kept.len(), |r, j| unit[(r, kept[j])]);
    let dropped_matrix = Mat::<f64>::from_fn(rows, dropped.len(), |r, d| unit[(r, dropped[d])]);
    let coefficients = if kept.is_empty() || dropped.is_empty() {
        Mat::<f64>::zeros(0, dropped.len())
    } else {
        dense::lstsq(kept_matrix.as_ref(), dropped_matrix.as_ref())
    };
    let mut dependent: Vec<(ParamId, Vec<ParamId>)> = dropped
        .iter()
        .enumerate()
        .map(|(d, &c)| {
            let mut partners: Vec<ParamId> = (0..kept.len())
                .filter(|&j| coefficients[(j, d)].abs() > 1e-3)
                .map(|j| ordered[kept[j]])
                .collect();
            partners.sort();
            (ordered[c], partners)
        })
        .chain(without_effect.iter().map(|&c| (ordered[c], Vec::new())))
        .collect();
    dependent.sort_by_key(|(id, _)| *id);

    let mut singular_values = dense::svd(unit.as_ref(), false)
        .map(|(values, _)| values)
        .unwrap_or_default();
    singular_values.sort_by(|a, b| b.total_cmp(a));
    let sigma_max = singular_values.first().copied().unwrap_or(0.0);
    let svd_rank = singular_values
        .iter()
        .filter(|s| **s > tolerance * sigma_max)
        .count();
    let mut independent: Vec<ParamId> = kept.iter().map(|&c| ordered[c]).collect();
    independent.sort();
    RankAnalysis {
        independent,
        dependent,
        singular_values,
        svd_rank,
        tolerance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q, random_wrench};
    use crate::robot::{ParamId, Selection};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    #[test]
    fn finds_the_spec_s_32_identifiable_parameters() {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        let mut rng = StdRng::seed_from_u64(4);
        let rows: Vec<ConfWrench> = (0..60)
            .map(|_| ConfWrench {
                q_deg: random_q(&robot, &mut rng),
                wrench: random_wrench(&mut rng),
                target: 0,
                approach: [0; 7],
                track_mm: 0.0,
                positioner_deg: None,
            })
            .collect();
        let all: Vec<ParamId> = ParamId::all().collect();
        let analysis = analyse(&robot, &nominal, &rows, &all, 1e-6, stream::CHUNK_ROWS);
        let names: Vec<&str> = analysis.independent.iter().map(|p| p.name()).collect();
        assert_eq!(
            analysis.independent,
            Selection::spec_identifiable().ids(),
            "{names:?}"
        );
        assert_eq!(analysis.svd_rank, 32);
        let partners = |name: &str| -> Vec<&str> {
            let id = ParamId::from_name(name).unwrap();
            analysis
                .dependent
                .iter()
                .find(|(d, _)| *d == id)
                .unwrap()
                .1
                .iter()
                .map(|p| p.name())
                .collect()
        };
        assert_eq!(partners("dd3"), vec!["dd2"]);
        assert!(
            partners("dtheta1").contains(&"gamma_w"),
            "{:?}",
            partners("dtheta1")
        );
    }

    #[test]
    fn compliances_are_unidentifiable_without_load_variation_on_joint_1() {
        let robot = irb1600();
        let nominal = ParamValues::nominal(robot.spec());
        let mut rng = StdRng::seed_from_u64(5);
        // No external wrench: joint 1 carries no torque (gravity is along its axis).
        let rows: Vec<ConfWrench> = (0..60)
            .map(|_| ConfWrench {
                q_deg: random_q(&robot, &mut rng),
                wrench: crate::robot::Wrench::zero(),
                target: 0,
                approach: [0; 7],
                track_mm: 0.0,
                positioner_deg: None,
            })
            .collect();
        let all: Vec<ParamId> = ParamId::all().collect();
        let analysis = analyse(&robot, &nominal, &rows, &all, 1e-6, stream::CHUNK_ROWS);
        let k1 = ParamId::from_name("k1").unwrap();
        // k1 has no effect at all: unidentifiable, and combined with nothing (it
        // was reported with about 30 "partners" fitted to its rounding noise).
        let (_, partners) = analysis.dependent.iter().find(|(d, _)| *d == k1).unwrap();
        assert!(partners.is_empty(), "{partners:?}");
        // Every other dependent parameter still names what it combines with.
        let dd3 = ParamId::from_name("dd3").unwrap();
        let (_, partners) = analysis.dependent.iter().find(|(d, _)| *d == dd3).unwrap();
        assert_eq!(partners, &vec![ParamId::from_name("dd2").unwrap()]);
    }

    #[test]
    fn a_zero_column_is_unidentifiable_with_no_partners() {
        let names = ["x_w", "y_w", "z_w", "k1"];
        let ordered: Vec<ParamId> = names
            .iter()
            .map(|n| ParamId::from_name(n).unwrap())
            .collect();
        // Columns: x_w, y_w, their sum (z_w: dependent on both), and k1 at
        // rounding level (no effect).
        let j = Mat::<f64>::from_fn(9, 4, |r, c| {
            let x = (r as f64 + 1.0).sin();
            let y = (2.0 * r as f64 + 0.5).cos();
            match c {
                0 => x,
                1 => y,
                2 => x + y,
                _ => 1e-17 * (r as f64).cos(),
            }
        });
        let factor = dense::triangular_factor(j);
        let analysis = analyse_factor(factor.as_ref(), &ordered, 1e-6);
        assert_eq!(analysis.independent, ordered[..2].to_vec());
        assert_eq!(
            analysis.dependent,
            vec![
                (ordered[2], vec![ordered[0], ordered[1]]),
                (ordered[3], Vec::new())
            ]
        );
        assert_eq!(analysis.svd_rank, 2);
    }
}
