//! Calibration maths above the robot model: rank analysis (which parameters the
//! data can identify) and the least-squares fit (Levenberg–Marquardt or the paper's
//! Gauss–Newton) with standard errors. Knows nothing of tables or stages.
//!
//! Both work on any number of rows in bounded memory: each pass over the rows is
//! chunked, parallel, and reduced to a small triangular factor ([`stream`]).

mod dense;
pub mod fit;
pub mod rank;
pub mod stream;

use nalgebra::Vector3;

use crate::robot::{ConfWrench, ParamId, ParamValues, Robot};
use crate::table::parameters::{ModelName, ParamStatus, ParameterSet};
use fit::{FitError, FitOptions, Iteration, Stop};
use rank::RankAnalysis;

/// Options of a whole calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// Parameters the identification may free (subject to rank analysis).
    pub candidates: Vec<ParamId>,
    pub rank_tolerance: f64,
    pub fit: FitOptions,
}

/// Parameter pairs reported as the strongest correlations.
pub const CORRELATIONS_REPORTED: usize = 5;

/// One model's identification.
#[derive(Debug, Clone)]
pub struct ModelResult {
    pub set: ParameterSet,
    pub trace: Vec<Iteration>,
    pub rank: Option<RankAnalysis>,
    pub converged: bool,
    /// `measured − predicted` per row with the model's values (mm).
    pub residuals_mm: Vec<Vector3<f64>>,
    /// The loss's weight of each row (1 where nothing is fitted).
    pub weights: Vec<f64>,
    /// Fit diagnostics; `None` where nothing is fitted (the nominal model).
    pub diagnostics: Option<Diagnostics>,
}

/// What the fit says about its own reliability.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostics {
    pub stop: Stop,
    /// σ_max / σ_min of the column-scaled, weighted Jacobian at the solution.
    pub condition_number: f64,
    /// The most correlated parameter pairs, strongest |ρ| first.
    pub correlations: Vec<(ParamId, ParamId, f64)>,
}

/// Identifies one model from the rows and measured positions.
///
/// * `nominal`: nothing is fitted.
/// * `registered`: only the world frame, on the nominal robot (what users do before
///   any calibration).
/// * `kinematic`: every identifiable candidate except compliances (held at zero).
/// * `elastogeometric`: every identifiable candidate.
///
/// Dependent candidates (rank analysis at nominal, paper §III.D) stay at nominal
/// with status `dependent`; parameters outside the model keep status `fixed`.
pub fn calibrate(
    robot: &Robot,
    model: ModelName,
    rows: &[ConfWrench],
    measured: &[Vector3<f64>],
    options: &CalibrationOptions,
) -> Result<ModelResult, FitError> {
    let nominal = ParamValues::nominal(robot.spec());
    let candidates: Vec<ParamId> = match model {
        ModelName::Nominal => Vec::new(),
        ModelName::Registered => options
            .candidates
            .iter()
            .copied()
            .filter(|p| p.is_world())
            .collect(),
        ModelName::Kinematic => options
            .candidates
            .iter()
            .copied()
            .filter(|p| !p.is_compliance())
            .collect(),
        ModelName::Elastogeometric => options.candidates.clone(),
    };
    let mut set = ParameterSet::fixed(model, nominal);
    if candidates.is_empty() {
        let residuals_mm = fit::residuals(robot, &nominal, rows, measured);
        return Ok(ModelResult {
            set,
            trace: Vec::new(),
            rank: None,
            converged: true,
            weights: vec![1.0; residuals_mm.len()],
            residuals_mm,
            diagnostics: None,
        });
    }
    let (rank, fit) = fit::fit_identifiable(
        robot,
        &nominal,
        rows,
        measured,
        &candidates,
        options.rank_tolerance,
        &options.fit,
    )?;
    let diagnostics = Diagnostics {
        stop: fit.stop,
        condition_number: fit.condition_number,
        correlations: fit.strongest_correlations(CORRELATIONS_REPORTED),
    };
    set.values = fit.values;
    set.std_errors = fit.std_errors;
    for id in &rank.independent {
        set.status[id.index()] = ParamStatus::Identified;
    }
    for (id, _) in &rank.dependent {
        set.status[id.index()] = ParamStatus::Dependent;
    }
    Ok(ModelResult {
        set,
        trace: fit.trace,
        rank: Some(rank),
        converged: fit.converged,
        residuals_mm: fit.residuals_mm,
        weights: fit.weights,
        diagnostics: Some(diagnostics),
    })
}
