//! Closed-form registration of the world (tracker) frame and the tool
//! translations (`../shared/spec/model.md` §7, "Unknown frames"). Pure maths.
//!
//! **Why closed form.** The identification is a local fit: it converges only from
//! a start near the answer. A real tracker stands wherever it was put, so the
//! robot file's `[world]` may be absent or metres and tens of degrees off, and
//! an SMR nest's translation may be unknown. Registering the nominal model's
//! positions onto the measured ones needs no starting guess at all, so a robot
//! file without a `[world]`, with a far-off one or with a good one starts the fit
//! from the same point and calibrates the same.
//!
//! **Why alternation.** Measured = `R·(F_k·t_j + f_k) + p` is non-linear only
//! through the rotation `R`. With the tool translations `t_j` fixed it is the
//! absolute-orientation problem, whose least-squares optimum is closed form
//! ([`umeyama`]); with `R` fixed it is linear in `(t_0 … t_{T−1}, p)`. Solving
//! the two blocks exactly in turn is a block-coordinate descent: the cost never
//! increases and it converges to a stationary point. It needs no start for the
//! tools (zero does) when the rows span a range of flange orientations: the tool
//! translations (~100 mm) move the points little next to the flange positions'
//! spread (~1 m), so the first rotation is already close. If the orientations
//! barely vary, a tool translation cannot be told from the world translation;
//! [`register_world_and_tools`] then refuses with
//! [`RegistrationError::ToolNotObservable`] rather than return an arbitrary split,
//! and the caller can keep known tool translations and call [`umeyama`] alone.

use std::f64::consts::PI;

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::robot::Frame;
use crate::robot::frame::rot_x;

/// Alternation rounds at most.
pub const MAX_ITERATIONS: usize = 100;
/// The alternation stops when the RMS residual changes by less than this (mm).
pub const RMS_CHANGE_TOLERANCE_MM: f64 = 1e-12;
/// Smallest `σ_min / σ_max` of the linear tool-and-translation system accepted.
/// For one target it is about 0.7 × the rms spread (rad) of the flange
/// orientations about their least-varied axis, so 1e-3 rejects spreads below
/// about 0.08° (calibration campaigns span tens of degrees: ratios ~0.5).
pub const TOOL_OBSERVABILITY_TOLERANCE: f64 = 1e-3;
/// Points whose cross-covariance has a second singular value below this
/// fraction of the first are collinear: the rotation about their line is free.
const COLLINEAR_TOLERANCE: f64 = 1e-10;
/// `cos β` below which eq. (3)'s angles are in gimbal lock (β = ±90°).
const GIMBAL_LOCK_COS: f64 = 1e-13;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    #[error("registration needs at least 3 points, got {0}")]
    TooFewPoints(usize),
    #[error("{what}: expected {expected} entries, got {found}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        found: usize,
    },
    #[error("{what} {index} is not finite")]
    NonFinite { what: &'static str, index: usize },
    #[error("weight {0} is negative")]
    NegativeWeight(usize),
    #[error(
        "the points are collinear or coincident (or carry no weight): the rotation is not determined"
    )]
    Degenerate,
    #[error("row {row} names target {target}, but there are {targets} targets")]
    TargetOutOfRange {
        row: usize,
        target: usize,
        targets: usize,
    },
    #[error(
        "the tool translation of target {target} is not observable: the flange orientations of its rows barely vary \
         (relative singular value {ratio:.1e} < {TOOL_OBSERVABILITY_TOLERANCE:.0e}); give it a known translation"
    )]
    ToolNotObservable { target: usize, ratio: f64 },
}

/// World frame and tool translations from [`register_world_and_tools`].
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    /// World ← base rotation: `point_world = rotation · point_base + translation_mm`.
    pub rotation: Matrix3<f64>,
    pub translation_mm: Vector3<f64>,
    /// Flange-frame translation of each target, mm.
    pub tool_translations_mm: Vec<Vector3<f64>>,
    /// `sqrt(Σ w‖r‖² / Σ w)` of the residuals at the result, mm.
    pub rms_mm: f64,
    /// Alternation rounds run.
    pub iterations: usize,
    /// Whether the RMS settled within [`MAX_ITERATIONS`].
    pub converged: bool,
    /// With orientations registered ([`tool_rotation`]): the RMS angle (deg)
    /// between measured and registered tool orientations; `None` without.
    pub orientation_rms_deg: Option<f64>,
    /// With a positioner's nests registered too (issue #30): their RMS, mm.
    pub positioner_rms_mm: Option<f64>,
}

impl Registration {
    pub fn world_from_base(&self) -> Frame {
        Frame {
            rotation: self.rotation,
            origin_mm: self.translation_mm,
        }
    }
}

/// Least-squares rigid transform (Umeyama 1991 without scale; Kabsch with the
/// reflection fix): `(R, t)` minimising `Σ w_k ‖target_k − (R·source_k + t)‖²`,
/// `R` a proper rotation. Weights default to 1 and must be finite and ≥ 0.
pub fn umeyama(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    weights: Option<&[f64]>,
) -> Result<(Matrix3<f64>, Vector3<f64>), RegistrationError> {
    let n = source.len();
    check_len("target", n, target.len())?;
    let w = checked_weights(weights, n)?;
    if n < 3 {
        return Err(RegistrationError::TooFewPoints(n));
    }
    check_finite("source point", source)?;
    check_finite("target point", target)?;
    let total: f64 = w.iter().sum();
    if total <= 0.0 {
        return Err(RegistrationError::Degenerate);
    }
    let mean = |points: &[Vector3<f64>]| {
        points
            .iter()
            .zip(&w)
            .fold(Vector3::zeros(), |acc, (x, wk)| acc + x * *wk)
            / total
    };
    let (source_mean, target_mean) = (mean(source), mean(target));
    let mut cov = Matrix3::zeros();
    for ((s, t), wk) in source.iter().zip(target).zip(&w) {
        cov += (t - target_mean) * (s - source_mean).transpose() * *wk;
    }
    // Sorted: σ0 ≥ σ1 ≥ σ2 ≥ 0.
    let svd = cov.svd(true, true);
    let sigma = svd.singular_values;
    if sigma[1].is_nan() || sigma[1] <= COLLINEAR_TOLERANCE * sigma[0] {
        return Err(RegistrationError::Degenerate);
    }
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = u * s * v_t;
    Ok((rotation, target_mean - rotation * source_mean))
}

/// World frame and per-target tool translations from flange frames and measured
/// SMR positions: the least-squares `R, p, t_j` of
/// `measured_k = R·(F_k·t_{target(k)} + f_k) + p`, with `F_k, f_k` the rotation and
/// origin of `flange_in_base[k]` (mm) and `t_j` in the flange frame.
///
/// Alternates (a) [`umeyama`] of the predicted SMR positions `F_k·t + f_k` onto
/// the measured ones → `R, p`, and (b) with `R` fixed, the linear least squares in
/// `(t_j, p)` by SVD, until the RMS changes by less than
/// [`RMS_CHANGE_TOLERANCE_MM`] or [`MAX_ITERATIONS`] rounds. This block-coordinate
/// descent never increases the cost (see the module doc) and converges from zero
/// initial tool translations when the rows span a range of flange orientations.
/// Written as `Rᵀ·m_k − f_k = F_k·t_j + Rᵀ·p`, step (b)'s matrix does not depend
/// on `R`, so it is factorised once (SVD, memory `O(n·T)`), and its singular values
/// decide observability: [`RegistrationError::ToolNotObservable`] if
/// `σ_min/σ_max <` [`TOOL_OBSERVABILITY_TOLERANCE`] (orientations barely varying,
/// all about one axis, or a target without weighted rows).
pub fn register_world_and_tools(
    flange_in_base: &[Frame],
    measured_in_world: &[Vector3<f64>],
    target_of_row: &[usize],
    targets: usize,
    initial_tool_translations: &[Vector3<f64>],
    weights: Option<&[f64]>,
) -> Result<Registration, RegistrationError> {
    register(
        flange_in_base,
        measured_in_world,
        target_of_row,
        targets,
        initial_tool_translations,
        weights,
        MAX_ITERATIONS,
    )
}

fn register(
    flange_in_base: &[Frame],
    measured: &[Vector3<f64>],
    target_of_row: &[usize],
    targets: usize,
    initial_tools: &[Vector3<f64>],
    weights: Option<&[f64]>,
    max_iterations: usize,
) -> Result<Registration, RegistrationError> {
    let n = flange_in_base.len();
    check_len("measured positions", n, measured.len())?;
    check_len("target of row", n, target_of_row.len())?;
    check_len("initial tool translations", targets, initial_tools.len())?;
    let w = checked_weights(weights, n)?;
    if n < 3 {
        return Err(RegistrationError::TooFewPoints(n));
    }
    for (row, frame) in flange_in_base.iter().enumerate() {
        if !(frame.rotation.iter().all(|x| x.is_finite())
            && frame.origin_mm.iter().all(|x| x.is_finite()))
        {
            return Err(RegistrationError::NonFinite {
                what: "flange frame",
                index: row,
            });
        }
    }
    check_finite("measured position", measured)?;
    check_finite("initial tool translation", initial_tools)?;
    if let Some((row, &target)) = target_of_row
        .iter()
        .enumerate()
        .find(|(_, j)| **j >= targets)
    {
        return Err(RegistrationError::TargetOutOfRange {
            row,
            target,
            targets,
        });
    }

    let root_w: Vec<f64> = w.iter().map(|x| x.sqrt()).collect();
    let solve = tool_system(flange_in_base, target_of_row, targets, &root_w)?;
    let total: f64 = w.iter().sum();
    let rms = |rotation: &Matrix3<f64>, translation: &Vector3<f64>, tools: &[Vector3<f64>]| {
        let sum: f64 = (0..n)
            .map(|k| {
                let predicted = rotation
                    * flange_in_base[k].transform_point(&tools[target_of_row[k]])
                    + translation;
                w[k] * (measured[k] - predicted).norm_squared()
            })
            .sum();
        (sum / total).sqrt()
    };
    let mut tools = initial_tools.to_vec();
    let (mut rotation, mut translation) = (Matrix3::identity(), Vector3::zeros());
    let mut current = f64::INFINITY;
    let mut converged = false;
    let mut iterations = 0;
    while !converged && iterations < max_iterations {
        iterations += 1;
        // (a) Rotation (and translation) with the tools fixed.
        let predicted: Vec<Vector3<f64>> = (0..n)
            .map(|k| flange_in_base[k].transform_point(&tools[target_of_row[k]]))
            .collect();
        (rotation, _) = umeyama(&predicted, measured, Some(&w))?;
        // (b) Tools and translation with the rotation fixed:
        // Rᵀ·m_k − f_k = F_k·t_j + Rᵀ·p, the same residual rotated by Rᵀ.
        let rhs = DVector::from_iterator(
            3 * n,
            (0..n).flat_map(|k| {
                let y =
                    (rotation.transpose() * measured[k] - flange_in_base[k].origin_mm) * root_w[k];
                [y.x, y.y, y.z]
            }),
        );
        let x = &solve * rhs;
        for (j, tool) in tools.iter_mut().enumerate() {
            *tool = x.fixed_rows::<3>(3 * j).into_owned();
        }
        translation = rotation * x.fixed_rows::<3>(3 * targets).into_owned();
        let now = rms(&rotation, &translation, &tools);
        converged = (now - current).abs() < RMS_CHANGE_TOLERANCE_MM;
        current = now;
    }
    Ok(Registration {
        rotation,
        translation_mm: translation,
        tool_translations_mm: tools,
        rms_mm: current,
        iterations,
        converged,
        orientation_rms_deg: None,
        positioner_rms_mm: None,
    })
}

/// The flange → tool rotation `T` that best explains measured tool
/// orientations (spec §8) given the world rotation: the least-squares
/// `argmin Σ w_k‖W·F_k·T − R_k‖²_F` over rotations (the chordal mean of the
/// `T_k = F_kᵀ·Wᵀ·R_k`, closed form: the rotation nearest `Σ w_k·T_k`, by SVD with
/// the reflection fix). `F_k` are the flange rotations in the base frame, `R_k`
/// the measured world ← tool rotations, `W` world ← base. Also the weighted
/// RMS angle (deg) between `W·F_k·T` and `R_k`.
pub fn tool_rotation(
    flange_in_base: &[Matrix3<f64>],
    measured_world_from_tool: &[Matrix3<f64>],
    world_from_base: &Matrix3<f64>,
    weights: &[f64],
) -> Result<(Matrix3<f64>, f64), RegistrationError> {
    let n = flange_in_base.len();
    check_len("measured orientations", n, measured_world_from_tool.len())?;
    let w = checked_weights(Some(weights), n)?;
    if n == 0 {
        return Err(RegistrationError::TooFewPoints(0));
    }
    for (index, r) in measured_world_from_tool.iter().enumerate() {
        if !r.iter().all(|x| x.is_finite()) {
            return Err(RegistrationError::NonFinite {
                what: "measured orientation",
                index,
            });
        }
    }
    let each: Vec<Matrix3<f64>> = flange_in_base
        .iter()
        .zip(measured_world_from_tool)
        .map(|(f, r)| f.transpose() * world_from_base.transpose() * r)
        .collect();
    let sum: Matrix3<f64> = each.iter().zip(&w).map(|(t, wk)| t * *wk).sum();
    let total: f64 = w.iter().sum();
    if total.is_nan() || total <= 0.0 {
        return Err(RegistrationError::Degenerate);
    }
    let svd = sum.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = u * s * v_t;
    let squared: f64 = each
        .iter()
        .zip(&w)
        .map(|(t, wk)| {
            wk * crate::robot::frame::rotation_vector(&(rotation.transpose() * t)).norm_squared()
        })
        .sum();
    Ok((rotation, (squared / total).sqrt().to_degrees()))
}

/// Pseudo-inverse of step (b)'s weighted `(3n) × (3T+3)` matrix: row block `k` is
/// `√w_k·[… F_k (column block target(k)) … I]`, unknowns `(t_0 … t_{T−1}, Rᵀ·p)`.
/// It holds no `R`, so it serves every round; its singular values decide whether
/// the tools are observable.
fn tool_system(
    flange_in_base: &[Frame],
    target_of_row: &[usize],
    targets: usize,
    root_w: &[f64],
) -> Result<DMatrix<f64>, RegistrationError> {
    let (n, columns) = (flange_in_base.len(), 3 * targets + 3);
    let mut a = DMatrix::zeros(3 * n, columns);
    for k in 0..n {
        let j = target_of_row[k];
        a.fixed_view_mut::<3, 3>(3 * k, 3 * j)
            .copy_from(&(flange_in_base[k].rotation * root_w[k]));
        a.fixed_view_mut::<3, 3>(3 * k, 3 * targets)
            .copy_from(&(Matrix3::identity() * root_w[k]));
    }
    if 3 * n < columns {
        // Fewer equations than unknowns: blame the target with the fewest rows.
        let target = (0..targets)
            .min_by_key(|j| target_of_row.iter().filter(|t| *t == j).count())
            .unwrap_or(0);
        return Err(RegistrationError::ToolNotObservable { target, ratio: 0.0 });
    }
    let svd = a.svd(true, true);
    let sigma = &svd.singular_values;
    let (largest, smallest) = (sigma[0], sigma[columns - 1]);
    let ratio = if largest > 0.0 {
        smallest / largest
    } else {
        0.0
    };
    if ratio.is_nan() || ratio < TOOL_OBSERVABILITY_TOLERANCE {
        // The target whose block dominates the least-determined direction.
        let v = svd
            .v_t
            .as_ref()
            .expect("requested")
            .row(columns - 1)
            .into_owned();
        let target = (0..targets)
            .max_by(|&a, &b| {
                let norm = |j: usize| v.columns(3 * j, 3).norm();
                norm(a).total_cmp(&norm(b))
            })
            .unwrap_or(0);
        return Err(RegistrationError::ToolNotObservable { target, ratio });
    }
    Ok(svd.pseudo_inverse(0.0).expect("U and Vᵀ were computed"))
}

/// The spec's six world parameters `[x_w, y_w, z_w (mm), alpha_w, beta_w, gamma_w
/// (deg)]` of the world ← base transform `point_world = rotation·point_base +
/// translation_mm` (eq. (3): `Rot(x,α)·Rot(y,β)·Rot(z,γ)·Trans(x_w, y_w, z_w)`, so the
/// translation parameters are `Rᵀ·p`). `rotation` must be a rotation matrix.
///
/// Of the two Euler solutions and their 360° wraps, the angles nearest
/// `nominal_angles_deg` are returned (an IRB's α_w = −180° stays −180.3, not
/// 179.7). In gimbal lock (β = ±90°) only α + γ (or γ − α) is determined; the
/// split nearest the nominal angles is returned.
pub fn world_params_from_frame(
    rotation: &Matrix3<f64>,
    translation_mm: &Vector3<f64>,
    nominal_angles_deg: [f64; 3],
) -> [f64; 6] {
    let angles = xyz_euler_nearest(rotation, nominal_angles_deg);
    let t = rotation.transpose() * translation_mm;
    [t.x, t.y, t.z, angles[0], angles[1], angles[2]]
}

/// `[α, β, γ]` (deg) with `rotation = Rot(x,α)·Rot(y,β)·Rot(z,γ)`, nearest `nominal_deg`.
pub fn xyz_euler_nearest(rotation: &Matrix3<f64>, nominal_deg: [f64; 3]) -> [f64; 3] {
    let r = rotation;
    let nominal = nominal_deg.map(f64::to_radians);
    let candidates = if r[(1, 2)].hypot(r[(2, 2)]) > GIMBAL_LOCK_COS {
        let alpha = (-r[(1, 2)]).atan2(r[(2, 2)]);
        // The second solution: α + π, π − β, γ + π.
        vec![
            euler_given_alpha(r, alpha),
            euler_given_alpha(r, alpha + PI),
        ]
    } else {
        // Row 1 of R is (sin s, cos s, 0) with s = α + γ (β = +90°) or γ − α (β = −90°).
        let s = r[(1, 0)].atan2(r[(1, 1)]);
        let alpha = if r[(0, 2)] > 0.0 {
            nominal[0] + wrap_pi(s - nominal[0] - nominal[2]) / 2.0
        } else {
            nominal[0] - wrap_pi(s - nominal[2] + nominal[0]) / 2.0
        };
        vec![euler_given_alpha(r, alpha)]
    };
    candidates
        .into_iter()
        .map(|angles| {
            std::array::from_fn(|i| {
                let a = angles[i].to_degrees();
                a + 360.0 * ((nominal_deg[i] - a) / 360.0).round()
            })
        })
        .min_by(|a: &[f64; 3], b: &[f64; 3]| {
            let distance =
                |x: &[f64; 3]| (0..3).map(|i| (x[i] - nominal_deg[i]).powi(2)).sum::<f64>();
            distance(a).total_cmp(&distance(b))
        })
        .expect("at least one candidate")
}

/// β and γ (rad) once α is chosen: `Rot(x,α)ᵀ·R = Rot(y,β)·Rot(z,γ)` read off its
/// third column and second row. With α from `atan2(−R₁₂, R₂₂)` the product's
/// (1,2) entry vanishes to rounding, so `Rot(x,α)·Rot(y,β)·Rot(z,γ)` rebuilds `R`
/// to rounding however ill-determined α is near gimbal lock.
fn euler_given_alpha(r: &Matrix3<f64>, alpha: f64) -> [f64; 3] {
    let m = rot_x(alpha).transpose() * r;
    [
        alpha,
        m[(0, 2)].atan2(m[(2, 2)]),
        m[(1, 0)].atan2(m[(1, 1)]),
    ]
}

/// Angle wrapped into (−π, π].
fn wrap_pi(angle: f64) -> f64 {
    angle - 2.0 * PI * ((angle - PI) / (2.0 * PI)).ceil()
}

fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), RegistrationError> {
    if expected == found {
        Ok(())
    } else {
        Err(RegistrationError::LengthMismatch {
            what,
            expected,
            found,
        })
    }
}

fn check_finite(what: &'static str, points: &[Vector3<f64>]) -> Result<(), RegistrationError> {
    match points.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
        Some(index) => Err(RegistrationError::NonFinite { what, index }),
        None => Ok(()),
    }
}

/// The weights, 1 each if none, checked finite and non-negative.
fn checked_weights(weights: Option<&[f64]>, n: usize) -> Result<Vec<f64>, RegistrationError> {
    let Some(w) = weights else {
        return Ok(vec![1.0; n]);
    };
    check_len("weights", n, w.len())?;
    for (index, x) in w.iter().enumerate() {
        if !x.is_finite() {
            return Err(RegistrationError::NonFinite {
                what: "weight",
                index,
            });
        }
        if *x < 0.0 {
            return Err(RegistrationError::NegativeWeight(index));
        }
    }
    Ok(w.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q};
    use crate::robot::{PARAM_COUNT, ParamValues, Robot, Wrench};
    use nalgebra::{Quaternion, Rotation3, Unit, UnitQuaternion};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, Normal, StandardNormal};

    fn axis_angle(axis: [f64; 3], angle_deg: f64) -> Matrix3<f64> {
        *Rotation3::from_axis_angle(
            &Unit::new_normalize(Vector3::from(axis)),
            angle_deg.to_radians(),
        )
        .matrix()
    }

    fn random_rotation(rng: &mut StdRng) -> Matrix3<f64> {
        let mut g = || -> f64 { StandardNormal.sample(rng) };
        let q = Quaternion::new(g(), g(), g(), g());
        *UnitQuaternion::from_quaternion(q)
            .to_rotation_matrix()
            .matrix()
    }

    fn random_point(rng: &mut StdRng, half_width_mm: f64) -> Vector3<f64> {
        Vector3::from_fn(|_, _| rng.random_range(-half_width_mm..half_width_mm))
    }

    fn cost(
        source: &[Vector3<f64>],
        target: &[Vector3<f64>],
        w: &[f64],
        r: &Matrix3<f64>,
        t: &Vector3<f64>,
    ) -> f64 {
        (0..source.len())
            .map(|k| w[k] * (target[k] - (r * source[k] + t)).norm_squared())
            .sum()
    }

    #[test]
    fn umeyama_recovers_a_known_transform_exactly() {
        let mut rng = StdRng::seed_from_u64(11);
        for _ in 0..20 {
            let (r, t) = (random_rotation(&mut rng), random_point(&mut rng, 3000.0));
            let source: Vec<_> = (0..10).map(|_| random_point(&mut rng, 1000.0)).collect();
            let target: Vec<_> = source.iter().map(|s| r * s + t).collect();
            let (r_got, t_got) = umeyama(&source, &target, None).unwrap();
            assert!((r_got - r).norm() < 1e-12, "{}", (r_got - r).norm());
            assert!(
                (t_got - t).norm() < 1e-12 * 1000.0,
                "{}",
                (t_got - t).norm()
            );
        }
    }

    /// `fixtures/tools/umeyama_check.py`'s point set and its output (numpy SVD and
    /// Horn's quaternion method agree on it).
    #[test]
    fn umeyama_matches_the_numpy_reference() {
        let v = |x: [f64; 3]| Vector3::from(x);
        let source = [
            [812.0, -40.0, 1186.5],
            [605.25, 310.0, 902.75],
            [1020.5, 95.0, 640.0],
            [455.0, -380.5, 1310.25],
            [930.75, -210.0, 1050.0],
            [700.0, 120.25, 480.5],
        ]
        .map(v);
        let target = [
            [1828.7, -1033.2, 1680.5],
            [1694.7, -645.6, 1402.5],
            [2200.4, -778.9, 1284.6],
            [1497.5, -1411.0, 1601.8],
            [2009.3, -1165.1, 1572.8],
            [1958.6, -740.3, 1022.1],
        ]
        .map(v);
        let weights = [1.0, 2.0, 0.5, 1.5, 1.0, 3.0];
        let r_numpy = Matrix3::new(
            0.9241816330307544,
            -0.1278258817253585,
            -0.3599289556700638,
            0.05651582040216753,
            0.9777290965643028,
            -0.20211822227553378,
            0.3777489526297563,
            0.16645226851168674,
            0.9108234576988207,
        );
        let t_numpy = Vector3::new(1499.997606225465, -800.2217108542437, 299.9519562476046);
        let (r, t) = umeyama(&source, &target, Some(&weights)).unwrap();
        assert!((r - r_numpy).norm() < 1e-12, "{}", (r - r_numpy).norm());
        assert!((t - t_numpy).norm() < 1e-9, "{}", (t - t_numpy).norm());
        let c = cost(&source, &target, &weights, &r, &t);
        assert!((c - 0.6554325318597062).abs() < 1e-9, "{c}");
    }

    #[test]
    fn umeyama_with_noise_is_the_least_squares_optimum() {
        let mut rng = StdRng::seed_from_u64(12);
        let noise = Normal::new(0.0, 0.5).unwrap();
        let (r0, t0) = (random_rotation(&mut rng), random_point(&mut rng, 3000.0));
        let source: Vec<_> = (0..30).map(|_| random_point(&mut rng, 1000.0)).collect();
        let target: Vec<_> = source
            .iter()
            .map(|s| r0 * s + t0 + Vector3::from_fn(|_, _| noise.sample(&mut rng)))
            .collect();
        let w: Vec<f64> = (0..30).map(|_| rng.random_range(0.2..3.0)).collect();
        let (r, t) = umeyama(&source, &target, Some(&w)).unwrap();
        let best = cost(&source, &target, &w, &r, &t);
        assert!(best < cost(&source, &target, &w, &r0, &t0));
        for size in [1e-3, 1e-5, 1e-7] {
            for _ in 0..50 {
                let dr = *Rotation3::from_scaled_axis(random_point(&mut rng, size)).matrix();
                let dt = random_point(&mut rng, size * 1000.0);
                let perturbed = cost(&source, &target, &w, &(dr * r), &(t + dt));
                assert!(
                    perturbed >= best * (1.0 - 1e-14),
                    "{size}: {perturbed} < {best}"
                );
            }
        }
    }

    #[test]
    fn umeyama_returns_a_rotation_for_mirrored_points() {
        let mut rng = StdRng::seed_from_u64(13);
        let source: Vec<_> = (0..8).map(|_| random_point(&mut rng, 500.0)).collect();
        let mirror = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let target: Vec<_> = source.iter().map(|s| mirror * s).collect();
        let (r, _) = umeyama(&source, &target, None).unwrap();
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
    }

    #[test]
    fn umeyama_rejects_bad_input() {
        let p = |x: f64, y: f64, z: f64| Vector3::new(x, y, z);
        let three = [p(0.0, 0.0, 0.0), p(100.0, 0.0, 0.0), p(0.0, 100.0, 0.0)];
        assert!(umeyama(&three, &three, None).is_ok());
        assert_eq!(
            umeyama(&three[..2], &three[..2], None),
            Err(RegistrationError::TooFewPoints(2))
        );
        assert!(matches!(
            umeyama(&three, &three[..2], None),
            Err(RegistrationError::LengthMismatch { .. })
        ));
        assert!(matches!(
            umeyama(&three, &three, Some(&[1.0, 1.0])),
            Err(RegistrationError::LengthMismatch { .. })
        ));
        let line = [p(0.0, 0.0, 0.0), p(100.0, 0.0, 0.0), p(250.0, 0.0, 0.0)];
        assert_eq!(
            umeyama(&line, &three, None),
            Err(RegistrationError::Degenerate)
        );
        assert_eq!(
            umeyama(&three, &line, None),
            Err(RegistrationError::Degenerate)
        );
        assert_eq!(
            umeyama(&[three[0]; 3], &three, None),
            Err(RegistrationError::Degenerate)
        );
        assert_eq!(
            umeyama(&three, &three, Some(&[0.0, 0.0, 0.0])),
            Err(RegistrationError::Degenerate)
        );
        let mut bad = three;
        bad[1].y = f64::NAN;
        assert!(matches!(
            umeyama(&three, &bad, None),
            Err(RegistrationError::NonFinite { index: 1, .. })
        ));
        assert!(matches!(
            umeyama(&three, &three, Some(&[1.0, f64::INFINITY, 1.0])),
            Err(RegistrationError::NonFinite { index: 1, .. })
        ));
        assert_eq!(
            umeyama(&three, &three, Some(&[1.0, 1.0, -1.0])),
            Err(RegistrationError::NegativeWeight(2))
        );
    }

    /// A world frame 3 m and 30° (about an oblique axis) off and three targets.
    struct Scene {
        flanges: Vec<Frame>,
        target_of_row: Vec<usize>,
        rotation: Matrix3<f64>,
        translation: Vector3<f64>,
        tools: Vec<Vector3<f64>>,
    }

    impl Scene {
        fn new(flanges: Vec<Frame>) -> Scene {
            Scene {
                target_of_row: (0..flanges.len()).map(|k| k % 3).collect(),
                flanges,
                rotation: axis_angle([1.0, -2.0, 0.7], 30.0),
                translation: Vector3::new(1800.0, -2000.0, 1400.0).normalize() * 3000.0,
                tools: vec![
                    Vector3::new(0.0, 0.0, 93.0),
                    Vector3::new(45.0, -30.0, 60.0),
                    Vector3::new(-35.0, 50.0, 120.0),
                ],
            }
        }

        fn robot(robot: &Robot, rows: usize, rng: &mut StdRng) -> Scene {
            Scene::new(
                (0..rows)
                    .map(|_| robot.nominal_flange_in_base(&random_q(robot, rng)))
                    .collect(),
            )
        }

        fn measured(&self, noise_mm: f64, rng: &mut StdRng) -> Vec<Vector3<f64>> {
            let noise = Normal::new(0.0, noise_mm).unwrap();
            (0..self.flanges.len())
                .map(|k| {
                    let smr = self.flanges[k].transform_point(&self.tools[self.target_of_row[k]]);
                    self.rotation * smr
                        + self.translation
                        + Vector3::from_fn(|_, _| noise.sample(rng))
                })
                .collect()
        }

        fn register(&self, measured: &[Vector3<f64>]) -> Result<Registration, RegistrationError> {
            register_world_and_tools(
                &self.flanges,
                measured,
                &self.target_of_row,
                3,
                &[Vector3::zeros(); 3],
                None,
            )
        }
    }

    #[test]
    fn registration_recovers_a_far_world_frame_and_three_tools_from_zero() {
        let mut rng = StdRng::seed_from_u64(21);
        let flanges = (0..60)
            .map(|_| Frame {
                rotation: random_rotation(&mut rng),
                origin_mm: random_point(&mut rng, 1000.0),
            })
            .collect();
        let scene = Scene::new(flanges);
        let fit = scene.register(&scene.measured(0.0, &mut rng)).unwrap();
        assert!(fit.converged, "{fit:?}");
        assert!((fit.rotation - scene.rotation).norm() < 1e-12, "{fit:?}");
        assert!(
            (fit.translation_mm - scene.translation).norm() < 1e-9,
            "{fit:?}"
        );
        for (got, want) in fit.tool_translations_mm.iter().zip(&scene.tools) {
            assert!((got - want).norm() < 1e-9, "{got} vs {want}");
        }
        assert!(fit.rms_mm < 1e-9, "{fit:?}");
    }

    #[test]
    fn registration_with_noise_is_close_to_the_truth() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(22);
        let scene = Scene::robot(&robot, 300, &mut rng);
        let measured = scene.measured(0.05, &mut rng);
        let fit = scene.register(&measured).unwrap();
        assert!(fit.converged, "{fit:?}");
        let angle = Frame::identity().angle_to(&Frame {
            rotation: fit.rotation * scene.rotation.transpose(),
            origin_mm: Vector3::zeros(),
        });
        assert!(angle < 1e-4, "{angle}");
        assert!(
            (fit.translation_mm - scene.translation).norm() < 0.5,
            "{fit:?}"
        );
        for (got, want) in fit.tool_translations_mm.iter().zip(&scene.tools) {
            assert!((got - want).norm() < 0.5, "{got} vs {want}");
        }
        // sqrt(3)·σ per point, less the 15 fitted unknowns' share.
        assert!(fit.rms_mm > 0.07 && fit.rms_mm < 0.1, "{}", fit.rms_mm);
        // The least-squares answer fits better than the truth.
        let truth_rms = (measured
            .iter()
            .zip(scene.measured(0.0, &mut rng))
            .map(|(m, exact)| (m - exact).norm_squared())
            .sum::<f64>()
            / measured.len() as f64)
            .sqrt();
        assert!(fit.rms_mm < truth_rms);
    }

    #[test]
    fn registration_cost_never_increases() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(23);
        let scene = Scene::robot(&robot, 60, &mut rng);
        let measured = scene.measured(0.5, &mut rng);
        let weights: Vec<f64> = (0..60).map(|_| rng.random_range(0.5..2.0)).collect();
        let mut previous = f64::INFINITY;
        for rounds in 1..=10 {
            let fit = register(
                &scene.flanges,
                &measured,
                &scene.target_of_row,
                3,
                &[Vector3::zeros(); 3],
                Some(&weights),
                rounds,
            )
            .unwrap();
            assert!(
                fit.rms_mm <= previous + 1e-12,
                "{rounds}: {} > {previous}",
                fit.rms_mm
            );
            previous = fit.rms_mm;
        }
    }

    #[test]
    fn registration_refuses_unobservable_tools() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(24);
        let scene = Scene::robot(&robot, 30, &mut rng);
        let measured = scene.measured(0.0, &mut rng);
        let one = vec![0; 30];
        let register_one = |flanges: &[Frame]| {
            register_world_and_tools(flanges, &measured, &one, 1, &[Vector3::zeros()], None)
        };
        // One orientation everywhere.
        let same: Vec<Frame> = scene
            .flanges
            .iter()
            .map(|f| Frame {
                rotation: scene.flanges[0].rotation,
                ..*f
            })
            .collect();
        assert!(matches!(
            register_one(&same),
            Err(RegistrationError::ToolNotObservable { target: 0, .. })
        ));
        // Orientations about one axis only (joint 1 alone): the tool's component
        // along it is the world translation's.
        let about_z: Vec<Frame> = (0..30)
            .map(|k| {
                robot.nominal_flange_in_base(&[
                    k as f64 * 10.0 - 150.0,
                    10.0,
                    20.0,
                    30.0,
                    40.0,
                    50.0,
                    0.0,
                ])
            })
            .collect();
        assert!(matches!(
            register_one(&about_z),
            Err(RegistrationError::ToolNotObservable { target: 0, .. })
        ));
        // Orientations within 0.01° of one another.
        let barely: Vec<Frame> = scene
            .flanges
            .iter()
            .map(|f| Frame {
                rotation: scene.flanges[0].rotation
                    * Rotation3::from_scaled_axis(random_point(&mut rng, 1e-2f64.to_radians()))
                        .matrix(),
                ..*f
            })
            .collect();
        assert!(matches!(
            register_one(&barely),
            Err(RegistrationError::ToolNotObservable { target: 0, .. })
        ));
        assert!(register_one(&scene.flanges).is_ok());
        // A target without rows.
        assert!(matches!(
            register_world_and_tools(
                &scene.flanges,
                &measured,
                &one,
                2,
                &[Vector3::zeros(); 2],
                None
            ),
            Err(RegistrationError::ToolNotObservable { target: 1, .. })
        ));
        // Fewer equations (9) than unknowns (12).
        assert!(matches!(
            register_world_and_tools(
                &scene.flanges[..3],
                &measured[..3],
                &[0, 1, 1],
                3,
                &[Vector3::zeros(); 3],
                None
            ),
            Err(RegistrationError::ToolNotObservable { target: 2, .. })
        ));
        assert!(matches!(
            register_world_and_tools(&scene.flanges, &measured, &one, 0, &[], None),
            Err(RegistrationError::TargetOutOfRange { row: 0, .. })
        ));
    }

    /// The nominal IRB 1600 with the spec's truth world and tool: registration from
    /// nothing gives the six world parameters as eq. (3) defines them.
    #[test]
    fn registration_of_the_robot_gives_its_world_parameters() {
        let robot = irb1600();
        let mut truth = ParamValues::nominal(robot.spec());
        let world = [1327.583, 1363.337, -1475.556, -180.312, 0.494, -0.596];
        truth.0[..6].copy_from_slice(&world);
        truth.0[6..9].copy_from_slice(&[22.193, 50.024, 148.905]);
        let mut rng = StdRng::seed_from_u64(25);
        let qs: Vec<_> = (0..40).map(|_| random_q(&robot, &mut rng)).collect();
        let flanges: Vec<Frame> = qs.iter().map(|q| robot.nominal_flange_in_base(q)).collect();
        let measured: Vec<_> = qs
            .iter()
            .map(|q| robot.predict(&truth, q, &Wrench::zero()).position_mm)
            .collect();
        let fit =
            register_world_and_tools(&flanges, &measured, &[0; 40], 1, &[Vector3::zeros()], None)
                .unwrap();
        let got = world_params_from_frame(&fit.rotation, &fit.translation_mm, [-180.0, 0.0, 0.0]);
        for i in 0..6 {
            assert!((got[i] - world[i]).abs() < 1e-9, "{i}: {got:?}");
        }
        let tool = Vector3::new(22.193, 50.024, 148.905);
        assert!((fit.tool_translations_mm[0] - tool).norm() < 1e-9);
    }

    fn model_world(params: [f64; 6]) -> Frame {
        let mut values = ParamValues([0.0; PARAM_COUNT]);
        values.0[..6].copy_from_slice(&params);
        irb1600().world_from_base(&values)
    }

    #[test]
    fn world_params_round_trip_through_the_model() {
        let mut rng = StdRng::seed_from_u64(31);
        let mut cases: Vec<[f64; 3]> = vec![
            [-180.312, 0.494, -0.596],
            [179.9999, -0.2, 180.0],
            [-180.0, 90.0, 0.0],
            [30.0, 90.0, -45.0],
            [30.0, -90.0, -45.0],
            [-120.0, 90.0 - 1e-7, 60.0],
            [-120.0, -90.0 + 1e-9, 60.0],
            [5.0, 89.99, 170.0],
        ];
        cases.extend((0..200).map(|_| {
            [
                rng.random_range(-180.0..180.0),
                rng.random_range(-90.0..90.0),
                rng.random_range(-180.0..180.0),
            ]
        }));
        for angles in cases {
            let translation = random_point(&mut rng, 3000.0);
            let frame =
                Frame::from_xyz_euler_then_translation(angles.map(f64::to_radians), translation);
            // Nominal near the truth, and far from it.
            for nominal in [angles.map(|a| a + 0.3), [-180.0, 0.0, 0.0]] {
                let params = world_params_from_frame(&frame.rotation, &frame.origin_mm, nominal);
                let rebuilt = model_world(params);
                let scale = frame.origin_mm.norm();
                assert!(
                    (rebuilt.rotation - frame.rotation).norm() < 1e-12,
                    "{angles:?} -> {params:?}"
                );
                assert!(
                    (rebuilt.origin_mm - frame.origin_mm).norm() < 1e-12 * scale,
                    "{angles:?} -> {params:?}"
                );
                for i in 0..3 {
                    assert!((params[i] - translation[i]).abs() < 1e-12 * scale);
                }
                // Away from gimbal lock, a nominal near the truth gives the truth back.
                if nominal[0] != -180.0 && angles[1].abs() < 89.0 {
                    for i in 0..3 {
                        assert!(
                            (params[3 + i] - angles[i]).abs() < 1e-9,
                            "{angles:?} -> {params:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn world_params_take_the_solution_nearest_nominal() {
        let r = Frame::from_xyz_euler_then_translation(
            [-180.312, 0.494, -0.596].map(f64::to_radians),
            Vector3::zeros(),
        )
        .rotation;
        let angles = |nominal| {
            let p = world_params_from_frame(&r, &Vector3::zeros(), nominal);
            [p[3], p[4], p[5]]
        };
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-9);
        assert!(close(angles([-180.0, 0.0, 0.0]), [-180.312, 0.494, -0.596]));
        assert!(close(angles([180.0, 0.0, 0.0]), [179.688, 0.494, -0.596]));
        assert!(close(angles([0.0, 0.0, 0.0]), [179.688, 0.494, -0.596]));
        // The other Euler solution: α + 180, 180 − β, γ + 180.
        assert!(close(
            angles([0.0, 180.0, 180.0]),
            [-0.312, 179.506, 179.404]
        ));
        // Gimbal lock: only α + γ (β = 90) or γ − α (β = −90) is known; the split
        // nearest nominal is taken.
        let locked = |beta: f64, nominal| {
            let r = Frame::from_xyz_euler_then_translation(
                [10.0, beta, 20.0].map(f64::to_radians),
                Vector3::zeros(),
            )
            .rotation;
            let p = world_params_from_frame(&r, &Vector3::zeros(), nominal);
            [p[3], p[4], p[5]]
        };
        assert!(close(locked(90.0, [12.0, 80.0, 15.0]), [13.5, 90.0, 16.5]));
        assert!(close(
            locked(-90.0, [12.0, -80.0, 15.0]),
            [8.5, -90.0, 18.5]
        ));
        assert!(close(
            locked(90.0, [-170.0, 80.0, -150.0]),
            [-175.0, 90.0, -155.0]
        ));
    }
}
