//! Calibration maths above the robot model: rank analysis (which parameters the
//! data can identify) and the Gauss–Newton fit with standard errors. Knows nothing
//! of tables or stages.

pub mod fit;
pub mod rank;

use nalgebra::Vector3;

use crate::robot::{ConfWrench, ParamId, ParamValues, Robot};
use crate::table::parameters::{ModelName, ParamStatus, ParameterSet};
use fit::{Fit, FitError, FitOptions, Iteration};
use rank::RankAnalysis;

/// Options of a whole calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// Parameters the identification may free (subject to rank analysis).
    pub candidates: Vec<ParamId>,
    pub rank_tolerance: f64,
    pub fit: FitOptions,
}

/// One model's identification.
#[derive(Debug, Clone)]
pub struct ModelResult {
    pub set: ParameterSet,
    pub trace: Vec<Iteration>,
    pub rank: Option<RankAnalysis>,
    pub converged: bool,
}

/// Identifies one model from the rows and measured positions.
///
/// * `nominal`: nothing is fitted.
/// * `registered`: only the world frame, on the nominal robot (what users do before
///   any calibration).
/// * `kinematic`: every identifiable candidate except compliances (held at zero).
/// * `elastogeometric`: every identifiable candidate.
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
        return Ok(ModelResult {
            set,
            trace: Vec::new(),
            rank: None,
            converged: true,
        });
    }
    let rank = rank::analyse(robot, &nominal, rows, &candidates, options.rank_tolerance);
    let Fit {
        values,
        std_errors,
        trace,
        converged,
        ..
    } = fit::fit(
        robot,
        &nominal,
        rows,
        measured,
        &rank.independent,
        &options.fit,
    )?;
    set.values = values;
    set.std_errors = std_errors;
    for id in &rank.independent {
        set.status[id.index()] = ParamStatus::Identified;
    }
    for (id, _) in &rank.dependent {
        set.status[id.index()] = ParamStatus::Dependent;
    }
    Ok(ModelResult {
        set,
        trace,
        rank: Some(rank),
        converged,
    })
}
