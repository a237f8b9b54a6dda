//! The identification Jacobian d(SMR position)/d(parameters) (paper eqs. (20)–(24)),
//! analytic, for any subset of the 42 parameters.
//!
//! Every geometric parameter is an elementary screw on part of the chain: a
//! rotation about an axis through a point, or a translation along an axis, that
//! moves the bodies from some link `s` on (the tool and payload are body 7). Its
//! column is the screw's velocity at the SMR on the deflected chain, plus the change
//! in deflection `k_i·dτ_i/dv` that the screw causes through the load torques on
//! the undeflected chain. The torque derivatives use the fact that a screw moves
//! everything downstream rigidly except gravity; see [`torque_rates`].
//!
//! Cost per row: two chain evaluations and O(m·6) cross products; no allocation.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::frame::Frame;
use super::model::{Chain, JOINTS, Loads, Prediction, Robot, Wrench};
use super::params::{ParamId, ParamKind, ParamValues};

const DEG: f64 = std::f64::consts::PI / 180.0;
const MM: f64 = 1e-3;

/// An infinitesimal motion of part of the chain, in one frame's coordinates.
#[derive(Debug, Clone, Copy)]
enum Screw {
    /// Rotation (per radian) about `axis` through `point_mm`.
    Rotation {
        axis: Vector3<f64>,
        point_mm: Vector3<f64>,
    },
    /// Translation (per millimetre) along `axis`.
    Translation { axis: Vector3<f64> },
}

impl Screw {
    fn velocity_at(&self, point_mm: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Screw::Rotation { axis, point_mm: o } => axis.cross(&(point_mm - o)),
            Screw::Translation { axis } => *axis,
        }
    }

    /// Scale from the screw's natural unit to the parameter's unit (deg or mm).
    fn per_unit(&self) -> f64 {
        match self {
            Screw::Rotation { .. } => DEG,
            Screw::Translation { .. } => 1.0,
        }
    }
}

/// The screw of a geometric parameter on `chain`, and the first body it moves
/// (1..=6 links, 7 the tool and payload). `None` for world parameters and compliances,
/// which need no torque term.
fn chain_screw(id: ParamId, chain: &Chain) -> Option<(Screw, usize)> {
    let flange = &chain.joints[JOINTS];
    Some(match id.kind() {
        ParamKind::Theta(i) => (
            Screw::Rotation {
                axis: chain.joints[i + 1].axis(2),
                point_mm: chain.joints[i + 1].origin_mm,
            },
            i + 1,
        ),
        ParamKind::Alpha(i) => (
            Screw::Rotation {
                axis: chain.joints[i].axis(0),
                point_mm: chain.joints[i].origin_mm,
            },
            i + 1,
        ),
        ParamKind::A(i) => (
            Screw::Translation {
                axis: chain.joints[i].axis(0),
            },
            i + 1,
        ),
        ParamKind::D(i) => (
            Screw::Translation {
                axis: chain.joints[i + 1].axis(2),
            },
            i + 1,
        ),
        ParamKind::ToolRotation(r) => {
            let local_axis = match r {
                0 => Vector3::x(),
                1 => chain.tool_rx.column(1).into_owned(),
                _ => chain.tool_rxy.column(2).into_owned(),
            };
            (
                Screw::Rotation {
                    axis: flange.rotation * local_axis,
                    point_mm: flange.origin_mm,
                },
                JOINTS + 1,
            )
        }
        ParamKind::ToolTranslation(t) => (
            Screw::Translation {
                axis: chain.tool.axis(t),
            },
            JOINTS + 1,
        ),
        ParamKind::WorldTranslation(_) | ParamKind::WorldRotation(_) | ParamKind::Compliance(_) => {
            return None;
        }
    })
}

/// Per-row quantities every torque derivative uses (base frame, metres):
/// `gravity_arm[i] = z_i × G_i` with `G_i` the first mass moment of bodies i..7
/// about joint i, and `wrench_arm[i] = z_i × (tool − o_i)`.
struct TorqueGeometry {
    z: [Vector3<f64>; JOINTS],
    gravity_arm: [Vector3<f64>; JOINTS],
    wrench_arm: [Vector3<f64>; JOINTS],
    tool_m: Vector3<f64>,
}

impl TorqueGeometry {
    fn new(chain: &Chain, loads: &Loads) -> Self {
        let tool_m = chain.tool.origin_mm * MM;
        let z: [Vector3<f64>; JOINTS] = std::array::from_fn(|i| chain.joints[i + 1].axis(2));
        let o = |i: usize| chain.joints[i + 1].origin_mm * MM;
        TorqueGeometry {
            gravity_arm: std::array::from_fn(|i| {
                z[i].cross(&(loads.suffix_moment_kgm[i + 1] - o(i) * loads.suffix_mass_kg[i + 1]))
            }),
            wrench_arm: std::array::from_fn(|i| z[i].cross(&(tool_m - o(i)))),
            z,
            tool_m,
        }
    }
}

/// dτ_i/dv (N·m per parameter unit) for a screw on the undeflected chain moving
/// bodies `first_body..=7`.
///
/// For joints at or after `first_body`, the joint axis, the bodies and the wrench
/// all move rigidly and only gravity stays put, so only the gravity term changes
/// (as if gravity turned the other way): `−(u × g)·(z_i × G_i)`. For joints before
/// it, the joint axis is fixed and the moved bodies' centres of gravity, the
/// wrench's point of application and its direction change:
/// `z_i·V + (u × f)·(z_i × (t − o_i))`, with `V` the same for every joint.
fn torque_rates(
    screw: &Screw,
    first_body: usize,
    geometry: &TorqueGeometry,
    loads: &Loads,
    gravity: &Vector3<f64>,
) -> [f64; JOINTS] {
    let f = &loads.force_base_n;
    let mass_s = loads.suffix_mass_kg[first_body];
    let moment_s = &loads.suffix_moment_kgm[first_body];
    let mut rates = [0.0; JOINTS];
    match screw {
        Screw::Rotation { axis: u, point_mm } => {
            let p_m = point_mm * MM;
            let u_g = u.cross(gravity);
            let u_f = u.cross(f);
            let common = u.cross(&(moment_s - p_m * mass_s)).cross(gravity)
                + u.cross(&(geometry.tool_m - p_m)).cross(f)
                + u.cross(&loads.moment_base_nm);
            for (i, rate) in rates.iter_mut().enumerate() {
                let per_rad = if i + 1 >= first_body {
                    -u_g.dot(&geometry.gravity_arm[i])
                } else {
                    geometry.z[i].dot(&common) + u_f.dot(&geometry.wrench_arm[i])
                };
                *rate = per_rad * DEG;
            }
        }
        Screw::Translation { axis: u } => {
            let common = u.cross(gravity) * mass_s + u.cross(f);
            for (i, rate) in rates
                .iter_mut()
                .enumerate()
                .take(first_body.saturating_sub(1))
            {
                *rate = geometry.z[i].dot(&common) * MM;
            }
        }
    }
    rates
}

/// One row's prediction and its Jacobian columns for `selected`, written to
/// `columns[j]` (mm per parameter unit, world frame).
pub fn jacobian_row(
    robot: &Robot,
    p: &ParamValues,
    q_deg: &[f64; JOINTS],
    wrench: &Wrench,
    selected: &[ParamId],
    columns: &mut [Vector3<f64>],
) -> Prediction {
    assert_eq!(
        selected.len(),
        columns.len(),
        "one column per selected parameter"
    );
    let undeflected = robot.chain(p, q_deg, &[0.0; JOINTS]);
    let loads = robot.loads(&undeflected, wrench);
    let deflections_deg: [f64; JOINTS] = std::array::from_fn(|i| p.0[36 + i] * loads.torques_nm[i]);
    let deflected = robot.chain(p, q_deg, &deflections_deg);
    let world = robot.world_from_base(p);
    let tool_base = deflected.tool.origin_mm;
    let position_mm = world.transform_point(&tool_base);

    // d(position in base)/d(joint angle i) per degree, on the deflected chain.
    let joint_rates: [Vector3<f64>; JOINTS] = std::array::from_fn(|i| {
        let joint = &deflected.joints[i + 1];
        joint.axis(2).cross(&(tool_base - joint.origin_mm)) * DEG
    });
    let gravity = Vector3::from(robot.spec().gravity_mps2);
    let geometry = TorqueGeometry::new(&undeflected, &loads);

    for (column, &id) in columns.iter_mut().zip(selected) {
        *column = match id.kind() {
            ParamKind::WorldTranslation(t) => world.axis(t),
            ParamKind::WorldRotation(r) => world_rotation_rate(p, r).cross(&position_mm) * DEG,
            ParamKind::Compliance(i) => world.rotation * joint_rates[i] * loads.torques_nm[i],
            _ => {
                let (screw, _) =
                    chain_screw(id, &deflected).expect("geometric parameter has a screw");
                let (torque_screw, first_body) =
                    chain_screw(id, &undeflected).expect("geometric parameter has a screw");
                let dtau = torque_rates(&torque_screw, first_body, &geometry, &loads, &gravity);
                let mut rate = screw.velocity_at(&tool_base) * screw.per_unit();
                for i in 0..JOINTS {
                    rate += joint_rates[i] * (p.0[36 + i] * dtau[i]);
                }
                world.rotation * rate
            }
        };
    }
    Prediction {
        position_mm,
        torques_nm: loads.torques_nm,
        deflections_deg,
    }
}

/// Axis (world frame, through the world origin) of world rotation `r` of eq. (3).
fn world_rotation_rate(p: &ParamValues, r: usize) -> Vector3<f64> {
    let v = &p.0;
    let rx = super::frame::rot_x(v[3] * DEG);
    match r {
        0 => Vector3::x(),
        1 => rx.column(1).into_owned(),
        _ => (rx * super::frame::rot_y(v[4] * DEG))
            .column(2)
            .into_owned(),
    }
}

/// One conf-wrench combination: joint commands (deg) and the wrench on the robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConfWrench {
    pub q_deg: [f64; JOINTS],
    pub wrench: Wrench,
}

/// Predictions and the stacked identification Jacobian for many rows.
#[derive(Debug, Clone)]
pub struct BatchJacobian {
    pub predictions: Vec<Prediction>,
    /// Row-major `3n × m`: rows 3k..3k+3 are x, y, z of conf-wrench k.
    pub jacobian: Vec<f64>,
    pub columns: usize,
}

impl BatchJacobian {
    pub fn rows(&self) -> usize {
        self.predictions.len() * 3
    }

    pub fn entry(&self, row: usize, column: usize) -> f64 {
        self.jacobian[row * self.columns + column]
    }
}

/// Rows per parallel task: large enough that rayon's overhead is noise.
const CHUNK_ROWS: usize = 64;

/// Predictions and Jacobian for every row, in parallel chunks.
pub fn batch_jacobian(
    robot: &Robot,
    p: &ParamValues,
    rows: &[ConfWrench],
    selected: &[ParamId],
) -> BatchJacobian {
    let m = selected.len();
    let mut jacobian = vec![0.0; rows.len() * 3 * m];
    let mut predictions = vec![
        Prediction {
            position_mm: Vector3::zeros(),
            torques_nm: [0.0; JOINTS],
            deflections_deg: [0.0; JOINTS],
        };
        rows.len()
    ];
    let fill = |(rows, (out, preds)): (&[ConfWrench], (&mut [f64], &mut [Prediction]))| {
        let mut columns = vec![Vector3::zeros(); m];
        for (k, row) in rows.iter().enumerate() {
            preds[k] = jacobian_row(robot, p, &row.q_deg, &row.wrench, selected, &mut columns);
            for (j, column) in columns.iter().enumerate() {
                for axis in 0..3 {
                    out[(3 * k + axis) * m + j] = column[axis];
                }
            }
        }
    };
    if rows.len() > CHUNK_ROWS {
        rows.par_chunks(CHUNK_ROWS)
            .zip(
                jacobian
                    .par_chunks_mut(CHUNK_ROWS * 3 * m.max(1))
                    .zip(predictions.par_chunks_mut(CHUNK_ROWS)),
            )
            .for_each(fill);
    } else {
        fill((rows, (&mut jacobian, &mut predictions)));
    }
    BatchJacobian {
        predictions,
        jacobian,
        columns: m,
    }
}

/// Predictions for every row, in parallel chunks (no Jacobian).
pub fn batch_predict(robot: &Robot, p: &ParamValues, rows: &[ConfWrench]) -> Vec<Prediction> {
    rows.par_iter()
        .with_min_len(CHUNK_ROWS)
        .map(|row| robot.predict(p, &row.q_deg, &row.wrench))
        .collect()
}

/// Tool frame in the world on the deflected chain; shared with the inverse kinematics.
pub(crate) fn deflected_tool_and_joints(
    robot: &Robot,
    p: &ParamValues,
    q_deg: &[f64; JOINTS],
    wrench: &Wrench,
) -> (Frame, [Frame; JOINTS + 1]) {
    let (_, deflections) = robot.deflections(p, q_deg, wrench);
    let chain = robot.chain(p, q_deg, &deflections);
    let world = robot.world_from_base(p);
    (
        world.compose(&chain.tool),
        chain.joints.map(|j| world.compose(&j)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::params::PARAM_COUNT;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// Central difference step per parameter unit: small enough that the O(h²)
    /// truncation error is below 1e-9 relative, large enough for round-off.
    fn step(id: ParamId) -> f64 {
        if id.is_compliance() { 1e-6 } else { 1e-4 }
    }

    #[test]
    fn analytic_jacobian_matches_central_differences_for_all_42() {
        let robot = irb1600();
        let all: Vec<ParamId> = ParamId::all().collect();
        let mut rng = StdRng::seed_from_u64(7);
        for trial in 0..40 {
            let mut p = truth_params(&robot);
            // Also away from the truth: random errors and larger payload-like loads.
            for id in ParamId::all() {
                if !id.is_compliance() && !id.is_world() && trial % 2 == 1 {
                    p.0[id.index()] += rng.random_range(-0.5..0.5);
                }
            }
            let q = random_q(&robot, &mut rng);
            let w = random_wrench(&mut rng);
            let mut columns = vec![Vector3::zeros(); PARAM_COUNT];
            jacobian_row(&robot, &p, &q, &w, &all, &mut columns);
            for id in ParamId::all() {
                let h = step(id);
                let mut plus = p;
                plus.0[id.index()] += h;
                let mut minus = p;
                minus.0[id.index()] -= h;
                let fd = (robot.predict(&plus, &q, &w).position_mm
                    - robot.predict(&minus, &q, &w).position_mm)
                    / (2.0 * h);
                let analytic = columns[id.index()];
                let scale = analytic.norm().max(fd.norm());
                assert!(
                    (fd - analytic).norm() <= 1e-6 * scale + 1e-9,
                    "trial {trial} {id}: analytic {analytic:?} fd {fd:?}"
                );
            }
        }
    }

    #[test]
    fn batch_equals_row_by_row_for_a_subset() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let selected: Vec<ParamId> = ["x_w", "dtheta2", "dd4", "k6", "gamma_t"]
            .iter()
            .map(|n| ParamId::from_name(n).unwrap())
            .collect();
        let mut rng = StdRng::seed_from_u64(9);
        let rows: Vec<ConfWrench> = (0..200)
            .map(|_| ConfWrench {
                q_deg: random_q(&robot, &mut rng),
                wrench: random_wrench(&mut rng),
            })
            .collect();
        let batch = batch_jacobian(&robot, &p, &rows, &selected);
        assert_eq!(batch.rows(), 600);
        let mut columns = vec![Vector3::zeros(); selected.len()];
        for (k, row) in rows.iter().enumerate() {
            let pred = jacobian_row(&robot, &p, &row.q_deg, &row.wrench, &selected, &mut columns);
            assert_eq!(pred, batch.predictions[k]);
            for (j, column) in columns.iter().enumerate() {
                for axis in 0..3 {
                    assert_eq!(batch.entry(3 * k + axis, j), column[axis]);
                }
            }
        }
    }
}
