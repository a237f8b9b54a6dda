//! The one Clarabel call of the module: the minimum-norm tension distribution.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use nalgebra::{SMatrix, Vector6};

use super::{CABLE_COUNT, CdprError};

/// Solves the QP
///
/// ```text
/// minimise ½‖t‖²  subject to  A t = w,  t_min ≤ t ≤ t_max
/// ```
///
/// and returns `Ok(Some(t))` if it is feasible, `Ok(None)` if Clarabel certifies it
/// infeasible, and an error if Clarabel fails or stops without a verdict.
///
/// Clarabel's form is `A_c x + s = b`, `s ∈ K`: six equality rows (zero cone) for
/// `A t = w`, then `t ≤ t_max` and `−t ≤ −t_min` (nonnegative cone). The
/// interior-point iterates keep the bounds strictly and the equality rows converge far
/// below Clarabel's stopping tolerance (residuals ≲ 1e-10 N observed); the answer is
/// only clamped into the bounds to remove rounding.
pub(super) fn min_norm_tensions(
    a: &SMatrix<f64, 6, CABLE_COUNT>,
    w: &Vector6<f64>,
    t_min: f64,
    t_max: f64,
) -> Result<Option<[f64; CABLE_COUNT]>, CdprError> {
    let solver_error = |message: String| CdprError::Solver { message };

    let mut rows: Vec<[f64; CABLE_COUNT]> = Vec::with_capacity(6 + 2 * CABLE_COUNT);
    let mut b: Vec<f64> = Vec::with_capacity(6 + 2 * CABLE_COUNT);
    for r in 0..6 {
        rows.push(std::array::from_fn(|c| a[(r, c)]));
        b.push(w[r]);
    }
    for (sign, bound) in [(1.0, t_max), (-1.0, -t_min)] {
        for i in 0..CABLE_COUNT {
            rows.push(std::array::from_fn(|c| if c == i { sign } else { 0.0 }));
            b.push(bound);
        }
    }
    let constraints = CscMatrix::from(&rows);
    let p = CscMatrix::<f64>::identity(CABLE_COUNT);
    let q = [0.0; CABLE_COUNT];
    let cones = [
        SupportedConeT::ZeroConeT(6),
        SupportedConeT::NonnegativeConeT(2 * CABLE_COUNT),
    ];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .map_err(|e| solver_error(format!("settings: {e}")))?;
    let mut solver = DefaultSolver::new(&p, &q, &constraints, &b, &cones, settings)
        .map_err(|e| solver_error(format!("setup: {e}")))?;
    solver.solve();

    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => {
            let x = &solver.solution.x;
            if x.len() != CABLE_COUNT || !x.iter().all(|v| v.is_finite()) {
                return Err(solver_error(format!(
                    "solver reported {:?} but returned a bad solution {x:?}",
                    solver.solution.status
                )));
            }
            Ok(Some(std::array::from_fn(|i| x[i].clamp(t_min, t_max))))
        }
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => Ok(None),
        status => Err(solver_error(format!("no verdict (status {status:?})"))),
    }
}
