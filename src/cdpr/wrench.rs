//! Structure matrix, wrench feasibility and capacity margin.

use nalgebra::{Matrix5, SMatrix, Vector3, Vector6};

use super::{CABLE_COUNT, CableRobotSpec, CdprError, solver};
use crate::robot::frame::Frame;

/// A cable shorter than this (anchor on its attachment point) has no direction.
const MIN_CABLE_LENGTH_MM: f64 = 1e-6;

/// Singular values below this fraction of the largest count as zero (rank test).
const RANK_TOLERANCE: f64 = 1e-9;

/// A choice of five columns whose hyperplane normal (generalized cross product) is
/// shorter than this fraction of the product of their norms is degenerate: the
/// columns span less than five dimensions.
const DEGENERATE_FACET: f64 = 1e-10;

/// The wrench matrix `A` of the CDPR at a tool pose: `A·t` is the wrench that cable
/// tensions `t` (N) exert ON THE PLATFORM, i.e. on the robot's tool, in TOOL-frame
/// axes, reduced to the TOOL ORIGIN.
///
/// Column `i` is that wrench for unit tension in cable `i`: rows 0–2 the force, the
/// unit vector `u_i` from the attachment point towards the anchor (N per N); rows 3–5
/// the moment `r_i × u_i` with `r_i` the attachment point relative to the tool
/// origin in metres (N·m per N). `tool_in_base` is the tool pose in the robot base
/// frame (`parent_from_child`, rotation orthonormal).
///
/// Never panics: a cable whose anchor coincides with its attachment point (shorter
/// than 1e-6 mm) or has non-finite coordinates, and cables beyond the spec's point
/// lists (an unvalidated spec), get a zero column.
pub fn structure_matrix(spec: &CableRobotSpec, tool_in_base: &Frame) -> SMatrix<f64, 6, 8> {
    let tool_from_base = tool_in_base.inverse();
    let mut a = SMatrix::<f64, 6, CABLE_COUNT>::zeros();
    let cables = spec.anchors_base_mm.iter().zip(&spec.attachments_tool_mm);
    for (i, (anchor, attachment)) in cables.take(CABLE_COUNT).enumerate() {
        let anchor_tool_mm = tool_from_base.transform_point(&Vector3::from(*anchor));
        let attachment_mm = Vector3::from(*attachment);
        let along_mm = anchor_tool_mm - attachment_mm;
        let length_mm = along_mm.norm();
        if length_mm.is_nan() || length_mm <= MIN_CABLE_LENGTH_MM {
            continue;
        }
        let force = along_mm / length_mm;
        let moment = (attachment_mm / 1000.0).cross(&force);
        a.fixed_view_mut::<3, 1>(0, i).copy_from(&force);
        a.fixed_view_mut::<3, 1>(3, i).copy_from(&moment);
    }
    a
}

/// The verdict of [`check_wrench`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feasibility {
    /// Whether tensions within `[min_tension_n, max_tension_n]` produce the wrench
    /// (decided by Clarabel on the tension QP).
    pub feasible: bool,
    /// When feasible, the tension distribution of least Euclidean norm producing the
    /// wrench, N (cable order of the spec); zeros otherwise.
    pub tensions_n: [f64; 8],
    /// Signed distance from the wrench to the boundary of the available wrench set,
    /// in the scaled wrench space where moments are divided by
    /// `moment_scale_mm / 1000` (so the unit is N): positive inside, negative outside.
    /// Inside it is the exact Euclidean distance; outside, its magnitude is the
    /// largest facet violation, a lower bound of the distance.
    pub capacity_margin_n: f64,
}

/// How far outside (N, scaled wrench space) the margin alone decides infeasibility.
const DECISIVE_MARGIN_N: f64 = 1e-3;

/// Whether the CDPR can apply `wrench` to the robot at `tool_in_base`, with a tension
/// distribution and the capacity margin.
///
/// `wrench` = `[fx, fy, fz` (N)`, mx, my, mz` (N·m)`]` to apply ON the robot's tool,
/// in tool axes at the tool origin (the convention of [`structure_matrix`]).
///
/// Feasibility: Clarabel solves `minimise ½‖t‖² s.t. A t = w, t_min ≤ t ≤ t_max`
/// (infeasible QP = infeasible wrench); the returned tensions reproduce the wrench to
/// ~1e-10 N (N·m).
///
/// Capacity margin: hyperplane shifting (Gouttefarde & Krut, ARK 2010; Guay et al.
/// 2014). The available wrench set `{A t : t ∈ [t_min, t_max]⁸}` is a zonotope;
/// each of its facets is parallel to five linearly independent columns of `A`. For
/// every choice of 5 of the 8 columns the unit normal `n` (orthogonal to those five)
/// gives the support value `h(n) = Σᵢ max(nᵀaᵢ t_min, nᵀaᵢ t_max)`, and `h(n) − nᵀw`
/// is the signed distance of `w` to that supporting hyperplane; the margin is the
/// minimum over all 56 choices and both signs of `n`. All of this happens in the
/// scaled wrench space (moment rows of `A` and `w` divided by `moment_scale_mm/1000`),
/// so the margin is in N. Within ~1e-6 N of the boundary the QP verdict and the sign
/// of the margin may disagree.
///
/// Errors: invalid spec, non-finite or non-rigid pose, non-finite wrench, a
/// structure matrix of rank < 6 (the set has no interior), or a Clarabel failure.
///
/// Cost: the pose-dependent part (structure matrix, rank, 56 facets) is built each
/// call; to check many wrenches at one pose build an [`AvailableWrenchSet`] once.
pub fn check_wrench(
    spec: &CableRobotSpec,
    tool_in_base: &Frame,
    wrench: [f64; 6],
) -> Result<Feasibility, CdprError> {
    AvailableWrenchSet::new(spec, tool_in_base)?.check(wrench)
}

/// The available wrench set of the CDPR at one tool pose, prepared for checking
/// many wrenches: the scaled structure matrix and the facets of the zonotope
/// (what [`check_wrench`] would otherwise rebuild for every wrench).
#[derive(Debug, Clone)]
pub struct AvailableWrenchSet {
    /// Structure matrix with moment rows divided by the moment scale (m).
    a_scaled: SMatrix<f64, 6, CABLE_COUNT>,
    /// `(1, 1, 1, s, s, s)` with `s` the moment scale in metres.
    unscale: Vector6<f64>,
    /// Per non-degenerate facet direction: unit normal `n`, `h(n)` and `h(−n)`.
    facets: Vec<(Vector6<f64>, f64, f64)>,
    t_min: f64,
    t_max: f64,
}

impl AvailableWrenchSet {
    /// Validates the spec and the pose and builds the facets (56 generalized cross
    /// products of 6×5 matrices; a few tens of µs).
    ///
    /// Errors: invalid spec, non-finite or non-rigid pose, a structure matrix of
    /// rank < 6 (the set has no interior).
    pub fn new(spec: &CableRobotSpec, tool_in_base: &Frame) -> Result<Self, CdprError> {
        spec.validate()?;
        validate_pose(tool_in_base)?;
        // Scaled wrench space: moments divided by the moment scale in metres (N·m → N).
        let s = spec.moment_scale_mm / 1000.0;
        let unscale = Vector6::new(1.0, 1.0, 1.0, s, s, s);
        let a_scaled = scaled_rows(structure_matrix(spec, tool_in_base), &unscale);
        let rank = numerical_rank(&a_scaled);
        if rank < 6 {
            return Err(CdprError::RankDeficient { rank });
        }
        let (t_min, t_max) = (spec.min_tension_n, spec.max_tension_n);
        let facets = facets(&a_scaled, t_min, t_max);
        // Rank 6 means some five columns are independent, so no facet is only
        // reachable at the edge of the two tolerances; report it as (numerically)
        // rank 5.
        if facets.is_empty() {
            return Err(CdprError::RankDeficient { rank: 5 });
        }
        Ok(AvailableWrenchSet {
            a_scaled,
            unscale,
            facets,
            t_min,
            t_max,
        })
    }

    /// [`check_wrench`] at the prepared pose: the margin from the stored facets (56
    /// dot products), then Clarabel's QP unless the margin already proves the wrench
    /// infeasible.
    ///
    /// Errors: non-finite wrench, or a Clarabel failure.
    pub fn check(&self, wrench: [f64; 6]) -> Result<Feasibility, CdprError> {
        if let Some((index, &value)) = wrench.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(CdprError::InvalidWrench { index, value });
        }
        let w = Vector6::from(wrench).component_div(&self.unscale);
        let capacity_margin_n = self
            .facets
            .iter()
            .map(|(n, h_plus, h_minus)| {
                let nw = n.dot(&w);
                (h_plus - nw).min(h_minus + nw)
            })
            .fold(f64::INFINITY, f64::min);
        // The margin is the exact signed distance to the available wrench set, so a
        // clearly negative one already proves infeasibility (no QP); the QP decides
        // near the boundary and gives the tensions.
        if capacity_margin_n < -DECISIVE_MARGIN_N {
            return Ok(Feasibility {
                feasible: false,
                tensions_n: [0.0; CABLE_COUNT],
                capacity_margin_n,
            });
        }
        let tensions = solver::min_norm_tensions(&self.a_scaled, &w, self.t_min, self.t_max)?;
        Ok(Feasibility {
            feasible: tensions.is_some(),
            tensions_n: tensions.unwrap_or([0.0; CABLE_COUNT]),
            capacity_margin_n,
        })
    }
}

/// Rows of `a` divided by `unscale` (moments in N·m → N).
fn scaled_rows(a: SMatrix<f64, 6, CABLE_COUNT>, unscale: &Vector6<f64>) -> SMatrix<f64, 6, 8> {
    let mut a = a;
    for (r, factor) in unscale.iter().enumerate() {
        a.row_mut(r).unscale_mut(*factor);
    }
    a
}

fn validate_pose(pose: &Frame) -> Result<(), CdprError> {
    let finite = pose
        .rotation
        .iter()
        .chain(pose.origin_mm.iter())
        .all(|v| v.is_finite());
    if !finite {
        return Err(CdprError::InvalidPose {
            message: "expected finite rotation and origin".into(),
        });
    }
    let orthonormality =
        (pose.rotation.transpose() * pose.rotation - nalgebra::Matrix3::identity()).norm();
    if orthonormality > 1e-6 || pose.rotation.determinant() <= 0.0 {
        return Err(CdprError::InvalidPose {
            message: format!(
                "expected a proper rotation matrix (|RᵀR − I| = {orthonormality:.1e}, det = {:.3})",
                pose.rotation.determinant()
            ),
        });
    }
    Ok(())
}

fn numerical_rank(a: &SMatrix<f64, 6, CABLE_COUNT>) -> usize {
    let singular = a.svd(false, false).singular_values;
    let largest = singular.max();
    singular
        .iter()
        .filter(|&&s| s > RANK_TOLERANCE * largest)
        .count()
}

/// The facet directions of the zonotope `a·[t_min, t_max]⁸` (see [`check_wrench`]):
/// for every non-degenerate choice of five columns, the unit normal `n` with the
/// support values `h(n)` and `h(−n)`.
fn facets(
    a: &SMatrix<f64, 6, CABLE_COUNT>,
    t_min: f64,
    t_max: f64,
) -> Vec<(Vector6<f64>, f64, f64)> {
    // Every 5-column choice, as an 8-bit mask with five bits set (56 of them).
    (0u32..1 << CABLE_COUNT)
        .filter(|m| m.count_ones() == 5)
        .filter_map(|mask| {
            let columns: Vec<usize> = (0..CABLE_COUNT).filter(|i| mask & (1 << i) != 0).collect();
            let n = facet_normal(a, &columns)?;
            let projections = n.transpose() * a;
            // h(n) and h(−n) = −Σ min(...); t_max > t_min ≥ 0.
            let h_plus: f64 = projections
                .iter()
                .map(|&p| (p * t_min).max(p * t_max))
                .sum();
            let h_minus: f64 = -projections
                .iter()
                .map(|&p| (p * t_min).min(p * t_max))
                .sum::<f64>();
            Some((n, h_plus, h_minus))
        })
        .collect()
}

/// Unit normal of the hyperplane spanned by five columns of `a`: the generalized
/// cross product, `nₖ = (−1)ᵏ det(M without row k)` for the 6×5 matrix `M` of those
/// columns. `None` if they span less than five dimensions.
fn facet_normal(a: &SMatrix<f64, 6, CABLE_COUNT>, columns: &[usize]) -> Option<Vector6<f64>> {
    let column_norms: f64 = columns.iter().map(|&c| a.column(c).norm()).product();
    let n = Vector6::from_fn(|k, _| {
        let minor = Matrix5::from_fn(|r, c| a[(if r < k { r } else { r + 1 }, columns[c])]);
        if k % 2 == 0 {
            minor.determinant()
        } else {
            -minor.determinant()
        }
    });
    let length = n.norm();
    // A zero column makes `column_norms` 0, and 0 <= 0.
    if length.is_nan() || length <= DEGENERATE_FACET * column_norms {
        return None;
    }
    Some(n / length)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::frame::{rot_x, rot_z};
    use nalgebra::{Matrix3, Rotation3, SVector};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    const CENTRE_MM: [f64; 3] = [900.0, 0.0, 900.0];
    /// The laser tracker in the base frame (jobs/robots/irb1600_145.toml's world).
    const TRACKER_MM: [f64; 3] = [-1326.0, -1362.0, 1476.0];

    fn pose(rotation: Matrix3<f64>, origin_mm: [f64; 3]) -> Frame {
        Frame {
            rotation,
            origin_mm: Vector3::from(origin_mm),
        }
    }

    /// The platform orientation the default geometry is designed for: tool z from
    /// `origin_mm` towards the tracker, tool x horizontal (the `poses` stage's
    /// upright roll, rebuilt here so that this module does not depend on `design`).
    fn facing_tracker(origin_mm: [f64; 3]) -> Matrix3<f64> {
        let z = (Vector3::from(TRACKER_MM) - Vector3::from(origin_mm)).normalize();
        let y = (Vector3::z() - z * z.z).normalize();
        Matrix3::from_columns(&[y.cross(&z), y, z])
    }

    /// A tool tilted 20° off the upright orientation and rolled 30°: the edge of
    /// what the `poses` stage draws.
    fn tilted() -> Matrix3<f64> {
        facing_tracker(CENTRE_MM) * rot_x(20f64.to_radians()) * rot_z(30f64.to_radians())
    }

    /// A random pose in the 500 mm workspace cube, tool turned up to ~35° from the
    /// upright orientation facing the tracker.
    fn random_pose(rng: &mut StdRng) -> Frame {
        let axis_angle = Vector3::from_fn(|_, _| rng.random_range(-0.35..0.35));
        let offset = Vector3::from_fn(|_, _| rng.random_range(-250.0..250.0));
        let origin_mm = Vector3::from(CENTRE_MM) + offset;
        Frame {
            rotation: facing_tracker(origin_mm.into())
                * *Rotation3::from_scaled_axis(axis_angle).matrix(),
            origin_mm,
        }
    }

    fn random_wrench(rng: &mut StdRng, force_n: f64, moment_nm: f64) -> [f64; 6] {
        std::array::from_fn(|k| {
            let limit = if k < 3 { force_n } else { moment_nm };
            rng.random_range(-limit..limit)
        })
    }

    #[test]
    fn single_cable_column_worked_by_hand() {
        // Tool at (900, 0, 900) turned 90° about z; attachment (0, 100, 50) mm in the
        // tool is (800, 0, 950) in the base; the anchor straight above it pulls along
        // base +z = tool +z. Moment about the tool origin: (0, 0.1, 0.05) m × (0, 0, 1)
        // = (0.1, 0, 0) N·m per N.
        let mut spec = CableRobotSpec::default();
        spec.attachments_tool_mm[0] = [0.0, 100.0, 50.0];
        spec.anchors_base_mm[0] = [800.0, 0.0, 1950.0];
        let tool = pose(rot_z(std::f64::consts::FRAC_PI_2), CENTRE_MM);
        let column = structure_matrix(&spec, &tool).column(0).into_owned();
        let expected = Vector6::new(0.0, 0.0, 1.0, 0.1, 0.0, 0.0);
        assert!((column - expected).norm() < 1e-12, "{column}");
    }

    #[test]
    fn structure_matrix_matches_virtual_work_of_cable_lengths() {
        // Unit tension in cable i does work −δlᵢ (m) when the platform moves by a small
        // twist (translation in m, rotation in rad, tool axes, about the tool origin),
        // so column i = −∂lᵢ/∂twist.
        let spec = CableRobotSpec::default();
        let mut rng = StdRng::seed_from_u64(7);
        for _ in 0..5 {
            let tool = random_pose(&mut rng);
            let a = structure_matrix(&spec, &tool);
            let lengths_m = |twist: &Vector6<f64>| -> SVector<f64, 8> {
                let motion = Frame {
                    rotation: *Rotation3::from_scaled_axis(twist.fixed_rows::<3>(3).into_owned())
                        .matrix(),
                    origin_mm: twist.fixed_rows::<3>(0) * 1000.0,
                };
                let moved = tool.compose(&motion);
                SVector::from_fn(|i, _| {
                    let attachment = Vector3::from(spec.attachments_tool_mm[i]);
                    let anchor = Vector3::from(spec.anchors_base_mm[i]);
                    (anchor - moved.transform_point(&attachment)).norm() / 1000.0
                })
            };
            let step = 1e-6;
            for k in 0..6 {
                let mut twist = Vector6::zeros();
                twist[k] = step;
                let derivative = (lengths_m(&twist) - lengths_m(&-twist)) / (2.0 * step);
                let row = a.row(k).transpose();
                assert!(
                    (row + derivative).norm() < 1e-7,
                    "row {k}: {row} vs {}",
                    -derivative
                );
            }
        }
    }

    #[test]
    fn wrench_from_inner_tensions_is_feasible_and_reproduced() {
        let spec = CableRobotSpec::default();
        let mut rng = StdRng::seed_from_u64(11);
        for _ in 0..50 {
            let tool = random_pose(&mut rng);
            let t = SVector::<f64, 8>::from_fn(|_, _| rng.random_range(30.0..580.0));
            let w = structure_matrix(&spec, &tool) * t;
            let verdict = check_wrench(&spec, &tool, w.into()).unwrap();
            assert!(verdict.feasible, "{verdict:?}");
            assert!(verdict.capacity_margin_n > 0.0, "{verdict:?}");
            let tensions = SVector::<f64, 8>::from(verdict.tensions_n);
            let produced = structure_matrix(&spec, &tool) * tensions;
            assert!((produced - w).amax() < 1e-6, "{produced} vs {w}");
            assert!(
                tensions
                    .iter()
                    .all(|&t| (spec.min_tension_n..=spec.max_tension_n).contains(&t)),
                "{tensions}"
            );
            // Minimum norm: never worse than the tensions that made the wrench.
            assert!(tensions.norm() <= t.norm() + 1e-6);
        }
    }

    #[test]
    fn wrench_beyond_the_total_tension_capacity_is_infeasible_with_negative_margin() {
        // Eight unit force columns at max tension give at most 8 · t_max of force in
        // any direction, whatever the geometry.
        let spec = CableRobotSpec::default();
        let tool = pose(facing_tracker(CENTRE_MM), CENTRE_MM);
        let beyond = 8.0 * spec.max_tension_n + 1.0;
        for wrench in [
            [beyond, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, -beyond, 0.0, 0.0, 0.0],
            [1e5, 0.0, 0.0, 0.0, 0.0, 0.0],
        ] {
            let verdict = check_wrench(&spec, &tool, wrench).unwrap();
            assert!(!verdict.feasible, "{wrench:?}: {verdict:?}");
            assert!(verdict.capacity_margin_n < 0.0, "{verdict:?}");
            assert_eq!(verdict.tensions_n, [0.0; 8]);
        }
        let verdict = check_wrench(&spec, &tool, [1e5, 0.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
        assert!(verdict.capacity_margin_n < -1e4, "{verdict:?}");
    }

    #[test]
    fn qp_verdict_and_margin_sign_agree_on_random_cases() {
        let spec = CableRobotSpec::default();
        let mut rng = StdRng::seed_from_u64(3);
        let (mut feasible, mut infeasible, mut near_boundary) = (0, 0, 0);
        for case in 0..200 {
            let tool = random_pose(&mut rng);
            let wrench = random_wrench(&mut rng, 600.0, 60.0);
            let verdict = check_wrench(&spec, &tool, wrench).unwrap();
            if verdict.capacity_margin_n.abs() < 1e-3 {
                near_boundary += 1;
                continue;
            }
            assert_eq!(
                verdict.feasible,
                verdict.capacity_margin_n > 0.0,
                "case {case}: {verdict:?} at {tool:?} for {wrench:?}"
            );
            if verdict.feasible {
                feasible += 1;
            } else {
                infeasible += 1;
            }
        }
        assert!(
            feasible >= 40 && infeasible >= 40,
            "{feasible} / {infeasible}"
        );
        assert!(near_boundary <= 2, "{near_boundary}");
    }

    #[test]
    fn inner_margin_is_not_overestimated() {
        // Every wrench within the margin (scaled space) of a feasible one is feasible.
        let spec = CableRobotSpec::default();
        let scale_m = spec.moment_scale_mm / 1000.0;
        let mut rng = StdRng::seed_from_u64(5);
        let mut checked = 0;
        while checked < 20 {
            let tool = random_pose(&mut rng);
            let w = random_wrench(&mut rng, 300.0, 30.0);
            let verdict = check_wrench(&spec, &tool, w).unwrap();
            if verdict.capacity_margin_n < 1.0 {
                continue;
            }
            checked += 1;
            for _ in 0..10 {
                let u = Vector6::from_fn(|_, _| rng.random_range(-1.0..1.0)).normalize();
                let step = u * (0.999 * verdict.capacity_margin_n);
                let moved: [f64; 6] =
                    std::array::from_fn(|k| w[k] + if k < 3 { step[k] } else { step[k] * scale_m });
                let inner = check_wrench(&spec, &tool, moved).unwrap();
                assert!(inner.feasible, "{verdict:?} → {inner:?}");
            }
        }
    }

    /// The design claim of `CableRobotSpec::default`: the whole ±120 N / ±10 N·m box
    /// (its 64 vertices; the wrench set is convex) is feasible at the workspace
    /// centre, upright and with a tool tilted to the edge of the `poses` draws.
    /// (Towards the workspace corners parts of the box fall out; the `wrenches`
    /// stage redraws those, and tests/design.rs bounds the acceptance.)
    #[test]
    fn default_geometry_covers_the_wrench_box_at_the_workspace_centre() {
        let spec = CableRobotSpec::default();
        for tool in [
            pose(facing_tracker(CENTRE_MM), CENTRE_MM),
            pose(tilted(), CENTRE_MM),
        ] {
            for vertex in 0..64 {
                let wrench: [f64; 6] = std::array::from_fn(|k| {
                    let limit = if k < 3 { 120.0 } else { 10.0 };
                    if vertex & (1 << k) != 0 {
                        limit
                    } else {
                        -limit
                    }
                });
                let verdict = check_wrench(&spec, &tool, wrench).unwrap();
                assert!(verdict.feasible, "{wrench:?} at {tool:?}: {verdict:?}");
            }
        }
    }

    #[test]
    fn most_wrenches_in_the_box_are_feasible_at_the_workspace_centre() {
        let spec = CableRobotSpec::default();
        let mut rng = StdRng::seed_from_u64(1);
        for (name, rotation) in [("upright", facing_tracker(CENTRE_MM)), ("tilted", tilted())] {
            let tool = pose(rotation, CENTRE_MM);
            let samples = 500;
            let start = std::time::Instant::now();
            let mut feasible = 0;
            for _ in 0..samples {
                let wrench = random_wrench(&mut rng, 120.0, 10.0);
                if check_wrench(&spec, &tool, wrench).unwrap().feasible {
                    feasible += 1;
                }
            }
            let fraction = f64::from(feasible) / f64::from(samples);
            eprintln!(
                "{name}: {:.1} % feasible, {:.0} µs per check_wrench",
                100.0 * fraction,
                start.elapsed().as_secs_f64() * 1e6 / f64::from(samples)
            );
            assert!(fraction > 0.95, "{name}: {fraction}");
        }
    }

    #[test]
    fn degenerate_geometry_does_not_panic() {
        let tool = pose(Matrix3::identity(), CENTRE_MM);
        // Cable 0 of zero length: its column is zero, the other seven still span.
        let mut spec = CableRobotSpec::default();
        let attachment = tool.transform_point(&Vector3::from(spec.attachments_tool_mm[0]));
        spec.anchors_base_mm[0] = attachment.into();
        assert_eq!(structure_matrix(&spec, &tool).column(0).norm(), 0.0);
        let verdict = check_wrench(&spec, &tool, [0.0; 6]);
        assert!(
            matches!(verdict, Ok(_) | Err(CdprError::RankDeficient { .. })),
            "{verdict:?}"
        );
        // All cables towards the tool origin: no moment at all, rank 3.
        let spec = CableRobotSpec {
            attachments_tool_mm: vec![[0.0; 3]; 8],
            ..CableRobotSpec::default()
        };
        let err = check_wrench(&spec, &tool, [0.0; 6]).unwrap_err();
        assert!(matches!(err, CdprError::RankDeficient { rank: 3 }), "{err}");
        // Every anchor on its attachment: zero matrix.
        let mut spec = CableRobotSpec::default();
        spec.anchors_base_mm = spec
            .attachments_tool_mm
            .iter()
            .map(|p| tool.transform_point(&Vector3::from(*p)).into())
            .collect();
        let err = check_wrench(&spec, &tool, [0.0; 6]).unwrap_err();
        assert!(matches!(err, CdprError::RankDeficient { rank: 0 }), "{err}");
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let spec = CableRobotSpec::default();
        let tool = pose(Matrix3::identity(), CENTRE_MM);
        let err = check_wrench(&spec, &tool, [0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0]).unwrap_err();
        assert!(
            matches!(err, CdprError::InvalidWrench { index: 2, .. }),
            "{err}"
        );
        let sheared = pose(
            Matrix3::new(1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            CENTRE_MM,
        );
        let err = check_wrench(&spec, &sheared, [0.0; 6]).unwrap_err();
        assert!(matches!(err, CdprError::InvalidPose { .. }), "{err}");
        let nowhere = pose(Matrix3::identity(), [f64::INFINITY, 0.0, 0.0]);
        let err = check_wrench(&spec, &nowhere, [0.0; 6]).unwrap_err();
        assert!(matches!(err, CdprError::InvalidPose { .. }), "{err}");
        let mut short = spec.clone();
        short.attachments_tool_mm.truncate(6);
        let err = check_wrench(&short, &tool, [0.0; 6]).unwrap_err();
        assert!(err.to_string().contains("attachments_tool_mm"), "{err}");
        // structure_matrix itself tolerates the unvalidated spec.
        assert_eq!(structure_matrix(&short, &tool).column(7).norm(), 0.0);
    }
}
