//! Calibration maths above the robot model: rank analysis (which parameters the
//! data can identify) and the least-squares fit (Levenberg–Marquardt or the paper's
//! Gauss–Newton) with standard errors. Knows nothing of tables or stages.
//!
//! Both work on any number of rows in bounded memory: each pass over the rows is
//! chunked, parallel, and reduced to a small triangular factor ([`stream`]).

pub mod accuracy_map;
mod dense;
pub mod fit;
pub mod groups;
pub mod held;
pub mod parameter_set;
pub mod rank;
pub mod registration;
pub mod residual;
pub mod robust;
pub mod row_checks;
pub mod selection;
pub mod stream;
mod subsample;
pub mod uncertainty;
pub mod unit_checks;

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::robot::{Frame, ParamId, ParamValues, Robot};
use fit::{FitError, FitOptions, Iteration, Loss, Observations, Stop};
use held::{Hold, HoldOptions};
use parameter_set::{ModelName, ParamStatus, ParameterSet};
use rank::RankAnalysis;
use robust::RobustOptions;
use selection::SelectionRule;

/// Options of a whole calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// Parameters the identification may free (subject to rank analysis); the
    /// translations of targets 1.. are candidates whenever `x_t`.. are.
    pub candidates: Vec<ParamId>,
    pub rank_tolerance: f64,
    pub fit: FitOptions,
    /// The robust default (`None`: `fit.loss` alone, as asked).
    pub robust: Option<RobustOptions>,
    /// Parameters held at a value in every fitted model (status `fixed`).
    pub fixed: Vec<(ParamId, f64)>,
    /// Targets in the rows (1 for a one-target cell).
    pub targets: usize,
    /// Bounds beyond which an identifiable parameter is held at its start value
    /// (spec §8 `held`); `None`: every identifiable parameter is fitted.
    pub hold: Option<HoldOptions>,
    /// Folds of the rows and the rule for choosing the free parameters by
    /// held-out rows ([`selection`]); `None`: every identifiable parameter
    /// within the `hold` bounds is fitted.
    pub selection: Option<selection::ParameterSelection>,
    /// Orders of the transmission-error harmonics the `eg_harmonic` model
    /// fits per joint (1: once per output turn).
    pub harmonic_orders: Vec<usize>,
    /// The parametric model under `eg_residual`'s Gaussian process.
    pub residual_base: ResidualBase,
}

/// The parametric model `eg_residual` identifies before fitting its
/// Gaussian process to what that model leaves.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    serde::Serialize,
    serde::Deserialize,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum ResidualBase {
    /// The backlash and the transmission harmonics (`eg_harmonic`'s parameters).
    #[default]
    EgHarmonic,
    /// The paper's model alone: where harmonics fitted without a region of
    /// joint space extrapolate into it, the process corrects what the paper's
    /// model leaves without them.
    Elastogeometric,
}

impl CalibrationOptions {
    /// `candidates` and `fit` for one target, rank tolerance 1e-6, the robust
    /// default, nothing fixed.
    pub fn new(candidates: Vec<ParamId>, fit: FitOptions) -> Self {
        CalibrationOptions {
            candidates,
            rank_tolerance: 1e-6,
            fit,
            robust: Some(RobustOptions::default()),
            fixed: Vec::new(),
            targets: 1,
            hold: Some(HoldOptions::default()),
            selection: None,
            harmonic_orders: vec![1, 2],
            residual_base: ResidualBase::default(),
        }
    }
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
    /// Per row, a 6-D row's rotation residual (deg, [`fit::orientation_residual_deg`]);
    /// `None` for position-only rows.
    pub residuals_deg: Vec<Option<Vector3<f64>>>,
    /// The loss's weight of each row (1 where nothing is fitted, 0 for an excluded row).
    pub weights: Vec<f64>,
    /// Fit diagnostics; `None` where nothing is fitted (the nominal model).
    pub diagnostics: Option<Diagnostics>,
    /// What the robust fit did; `None` without it or where nothing is fitted.
    pub robust: Option<RobustSummary>,
    /// Identifiable parameters held at their start value because the data do
    /// not determine them ([`held`]), in the order they were chosen.
    pub held: Vec<Hold>,
}

/// What the robust fit found (see [`robust`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RobustSummary {
    /// σ̂ of the least-squares residuals (mm, or σ units with per-point σ).
    pub sigma_least_squares: f64,
    /// σ̂ the exclusion used (from the Huber fit); equal to the above when no row
    /// was beyond the threshold.
    pub sigma: f64,
    /// Rows beyond `reject_sigmas`·σ̂ (indices into the rows), excluded from the
    /// final fit.
    pub excluded: Vec<usize>,
    /// The exclusion threshold (`reject_sigmas`·σ̂).
    pub threshold: f64,
}

/// What the fit says about its own reliability.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostics {
    pub stop: Stop,
    /// σ_max / σ_min of the column-scaled, weighted Jacobian at the solution.
    pub condition_number: f64,
    /// The most correlated parameter pairs, strongest |ρ| first.
    pub correlations: Vec<(ParamId, ParamId, f64)>,
    /// The identified parameters and their covariance (parameters' units, row-major).
    pub free: Vec<ParamId>,
    pub covariance: Vec<f64>,
    /// σ² the covariance is scaled by ([`fit::Fit::variance_factor`]).
    pub variance_factor: f64,
}

/// Identifies one model from the rows and measured positions, starting from
/// `start` (the robot file's values with the frames registered, or an earlier
/// calibration's for `reregistered`).
///
/// * `nominal`: nothing is fitted; the robot file's values.
/// * `registered`, `reregistered`: the world frame and tool translation(s) only
///   (spec §7), and the tool rotation where rows carry orientations (spec §8:
///   a probe's mounting is a frame like its translation); every other
///   parameter keeps its `start` value.
/// * `kinematic`: every identifiable candidate except compliances (held at zero).
/// * `elastogeometric`: every identifiable candidate.
///
/// Dependent candidates (rank analysis at the start, paper §III.D) stay at their
/// start value with status `dependent`; parameters outside the model and those
/// in `options.fixed` keep status `fixed`.
pub fn calibrate(
    robot: &Robot,
    model: ModelName,
    data: &Observations<'_>,
    start: &ParamValues,
    options: &CalibrationOptions,
) -> Result<ModelResult, FitError> {
    let nominal = ParamValues::nominal(robot.spec());
    let targets = options.targets.max(1);
    let allowed = |id: &ParamId| {
        let base = match id.kind() {
            crate::robot::params::ParamKind::ToolTranslation { axis, .. } => {
                ParamId::target_translation(0, axis)
            }
            _ => *id,
        };
        options.candidates.contains(&base) && !options.fixed.iter().any(|(f, _)| f == id)
    };
    let six_d = data.has_orientations();
    let joint_terms: Vec<ParamId> = match model {
        ModelName::EgBacklash => ParamId::backlashes(robot.joint_count()).collect(),
        ModelName::EgResidual if options.residual_base == ResidualBase::Elastogeometric => {
            Vec::new()
        }
        ModelName::EgHarmonic | ModelName::EgResidual => ParamId::backlashes(robot.joint_count())
            .chain(ParamId::harmonics(
                robot.joint_count(),
                &options.harmonic_orders,
            ))
            .collect(),
        _ => Vec::new(),
    };
    // A track's errors along its travel are the cell's geometry: every model
    // that fits the arm's geometry fits them too (issue #30).
    let track_terms: Vec<ParamId> = match (robot.spec().track, model) {
        (
            Some(track),
            ModelName::Kinematic
            | ModelName::Elastogeometric
            | ModelName::EgBacklash
            | ModelName::EgHarmonic
            | ModelName::EgResidual,
        ) => ParamId::track_terms(track.polynomial_order).collect(),
        _ => Vec::new(),
    };
    // A positioner's base is a frame, registered like the world's; its axes'
    // errors are geometry, fitted with the arm's (issue #30).
    let positioner_terms: Vec<ParamId> = match &robot.spec().positioner {
        Some(positioner) => ParamId::positioner_terms(positioner.axes.len())
            .filter(|id| match (model, id.kind()) {
                (ModelName::Nominal, _) => false,
                (
                    ModelName::Registered | ModelName::Reregistered,
                    crate::robot::params::ParamKind::Positioner(term),
                ) => term.axis().is_none(),
                _ => true,
            })
            .collect(),
        None => Vec::new(),
    };
    let candidates: Vec<ParamId> = ParamId::all_with_targets(robot.joint_count(), targets)
        .filter(allowed)
        .filter(|p| match model {
            ModelName::Nominal => false,
            ModelName::Registered | ModelName::Reregistered => {
                p.is_world() || p.is_tool_translation() || (six_d && p.is_tool_rotation())
            }
            ModelName::Kinematic => !p.is_compliance(),
            ModelName::Elastogeometric
            | ModelName::EgBacklash
            | ModelName::EgHarmonic
            | ModelName::EgResidual => true,
        })
        .chain(
            joint_terms
                .into_iter()
                .chain(track_terms)
                .chain(positioner_terms)
                .filter(|id| !options.fixed.iter().any(|(f, _)| f == id)),
        )
        .collect();
    if candidates.is_empty() {
        let set = ParameterSet::fixed(model, nominal);
        let residuals_mm = fit::residuals(robot, &nominal, data.rows, data.measured_mm);
        let residuals_deg = fit::orientation_residuals(robot, &nominal, data);
        return Ok(ModelResult {
            residuals_deg,
            set,
            trace: Vec::new(),
            rank: None,
            converged: true,
            weights: vec![1.0; residuals_mm.len()],
            residuals_mm,
            diagnostics: None,
            robust: None,
            held: Vec::new(),
        });
    }
    let mut start = *start;
    for (id, value) in &options.fixed {
        start.set(*id, *value);
    }
    if model == ModelName::Kinematic {
        for id in ParamId::of_arm(robot.joint_count()).filter(|p| p.is_compliance()) {
            if !options.fixed.iter().any(|(f, _)| *f == id) {
                start.set(id, 0.0);
            }
        }
    }
    let (rank, least_squares) = fit::fit_identifiable(
        robot,
        &start,
        data,
        &candidates,
        options.rank_tolerance,
        &options.fit,
    )?;
    let mut free = rank.independent.clone();
    let mut held: Vec<Hold> = Vec::new();
    let mut trace: Vec<Iteration> = Vec::new();
    let mut least_squares = least_squares;
    let mut selected = false;
    // Each round holds at least one parameter, so this ends within `m` rounds;
    // without holds it is the one fit it always was.
    let (fit, robust) = loop {
        let (fit, robust) = match options.robust {
            Some(robust) => {
                let (refit, summary) =
                    robust_refit(robot, data, least_squares, &free, &robust, options)?;
                (refit, Some(summary))
            }
            None => (least_squares, None),
        };
        let mut new_holds = options.hold.as_ref().map_or_else(Vec::new, |bounds| {
            held::parameters_to_hold(&fit.free, &fit.covariance, bounds, |id| {
                id.name().to_string()
            })
        });
        // Once the standard errors are within bounds, the held-out rows
        // decide: elimination once (the refit only drops what they did not
        // support), the jackknife one parameter per round.
        if new_holds.is_empty()
            && !selected
            && let (Some(selection), Some(bounds)) = (&options.selection, &options.hold)
        {
            let folds = &selection.folds;
            let unsupported = match selection.rule {
                SelectionRule::Elimination => {
                    selected = true;
                    selection::choose_parameters(robot, data, &fit, &start, folds, bounds)
                }
                SelectionRule::Jackknife { min_t } => {
                    selection::least_significant(robot, data, &fit, &start, folds, bounds, min_t)
                        .into_iter()
                        .collect()
                }
            };
            new_holds = unsupported
                .into_iter()
                .map(|u| Hold {
                    id: u.id,
                    reason: u.reason,
                })
                .collect();
        }
        if new_holds.is_empty() {
            break (fit, robust);
        }
        trace.extend(fit.trace.iter().copied());
        free.retain(|id| !new_holds.iter().any(|h| h.id == *id));
        held.extend(new_holds);
        // From the start again: the held values are the start's, and the
        // others should not inherit what the loose ones did to them.
        least_squares = fit::fit(robot, &start, data, &free, &options.fit)?;
    };
    let mut fit = fit;
    trace.extend(fit.trace.iter().copied());
    fit.trace = trace;
    let diagnostics = Diagnostics {
        stop: fit.stop,
        condition_number: fit.condition_number,
        correlations: fit.strongest_correlations(CORRELATIONS_REPORTED),
        free: fit.free.clone(),
        covariance: fit.covariance.clone(),
        variance_factor: fit.variance_factor,
    };
    let mut set = ParameterSet::fixed(model, fit.values);
    set.std_errors = fit.std_errors;
    for id in &free {
        set.status[id.index()] = ParamStatus::Identified;
    }
    for (id, combined) in &rank.dependent {
        set.status[id.index()] = ParamStatus::Dependent;
        set.reasons[id.index()] = Some(if combined.is_empty() {
            "no effect on these rows".to_string()
        } else {
            format!(
                "dependent on {} (rank analysis)",
                combined
                    .iter()
                    .map(|p| p.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        });
    }
    for hold in &held {
        set.status[hold.id.index()] = ParamStatus::Held;
        set.reasons[hold.id.index()] = Some(hold.reason.clone());
    }
    for (id, _) in &options.fixed {
        set.reasons[id.index()] = Some("fixed by the job".to_string());
    }
    for id in ParamId::all_with_targets(robot.joint_count(), targets) {
        if set.status[id.index()] == ParamStatus::Fixed && set.reasons[id.index()].is_none() {
            set.reasons[id.index()] = Some(if allowed(&id) {
                format!("not part of the {model} model")
            } else {
                "not among the job's candidates".to_string()
            });
        }
    }
    Ok(ModelResult {
        set,
        trace: fit.trace,
        rank: Some(rank),
        converged: fit.converged,
        residuals_mm: fit.residuals_mm,
        residuals_deg: fit.residuals_deg,
        weights: fit.weights,
        diagnostics: Some(diagnostics),
        robust,
        held,
    })
}

/// Stages 2 and 3 of the robust fit ([`robust`]) after the least-squares `fit`.
fn robust_refit(
    robot: &Robot,
    data: &Observations<'_>,
    least_squares: fit::Fit,
    free: &[ParamId],
    robust: &RobustOptions,
    options: &CalibrationOptions,
) -> Result<(fit::Fit, RobustSummary), FitError> {
    let taking_part = |k: &usize| data.scale_of(*k).iter().any(|s| *s != 0.0);
    // A 6-D row is one row: the norm of its six scaled residuals.
    let scaled_norm = |fit: &fit::Fit, k: usize| {
        data.scaled_norm(k, &fit.residuals_mm[k], fit.residuals_deg[k].as_ref())
    };
    let sigma_of = |fit: &fit::Fit| {
        if data.has_orientations() {
            robust::robust_sigma_of_rows(
                (0..data.rows.len())
                    .filter(taking_part)
                    .map(|k| (scaled_norm(fit, k), data.orientation_of(k).is_some())),
            )
        } else {
            robust::robust_sigma(&fit.residuals_mm, data.row_scale)
        }
    };
    let beyond = |fit: &fit::Fit, threshold: f64| -> Vec<usize> {
        (0..data.rows.len())
            .filter(taking_part)
            .filter(|k| {
                let norm = scaled_norm(fit, *k);
                norm.is_nan() || norm > threshold
            })
            .collect()
    };
    let sigma_least_squares = sigma_of(&least_squares);
    let threshold = robust.reject_sigmas * sigma_least_squares;
    if beyond(&least_squares, threshold).is_empty() {
        return Ok((
            least_squares,
            RobustSummary {
                sigma_least_squares,
                sigma: sigma_least_squares,
                excluded: Vec::new(),
                threshold,
            },
        ));
    }
    let mut trace = least_squares.trace.clone();
    let huber_options = FitOptions {
        loss: Loss::Huber {
            threshold_mm: robust.huber_sigmas * sigma_least_squares,
        },
        ..options.fit
    };
    let huber = fit::refit(robot, &least_squares.values, data, free, &huber_options)?;
    trace.extend(huber.trace.iter().copied());
    let sigma = sigma_of(&huber);
    let threshold = robust.reject_sigmas * sigma;
    let excluded = beyond(&huber, threshold);
    let included_before = data.included_rows();
    if excluded.len() as f64 > robust.max_excluded_fraction * included_before as f64 {
        return Err(FitError::Untrustworthy(format!(
            "{} of {included_before} rows lie beyond {:.3} ({} robust standard deviations) of the robust fit; \
             more than {:.0} % of the rows disagree with the model, so the data cannot be trusted",
            excluded.len(),
            threshold,
            robust.reject_sigmas,
            100.0 * robust.max_excluded_fraction
        )));
    }
    let mut scales: Vec<Vector3<f64>> = (0..data.rows.len()).map(|k| data.scale_of(k)).collect();
    for k in &excluded {
        scales[*k] = Vector3::zeros();
    }
    let clean = Observations {
        row_scale: Some(&scales),
        ..*data
    };
    let mut last = fit::refit(robot, &huber.values, &clean, free, &options.fit)?;
    trace.extend(last.trace.iter().copied());
    last.trace = trace;
    Ok((
        last,
        RobustSummary {
            sigma_least_squares,
            sigma,
            excluded,
            threshold,
        },
    ))
}

/// Rows the registered start uses at most: it is only a start, and a strided
/// subset keeps a million-row table's registration in milliseconds.
const REGISTRATION_ROWS: usize = 10_000;

/// The start of the fitted models: `values` with the world frame and each
/// target's tool translation replaced by their closed-form registration onto
/// the measured positions ([`registration`], spec §7). So a robot file without
/// `[world]`, or with one metres and degrees off, calibrates the same; and
/// `reregistered` starts from its calibration's robot in the new frames.
///
/// Where rows carry orientations (spec §8) the tool rotation is registered
/// too, after the world frame: the world rotation from the positions (their
/// metre-wide spread fixes it to hundredths of a degree), then the tool
/// rotation that best maps each row's flange onto its measured tool axes
/// ([`registration::tool_rotation`]), which positions cannot see.
///
/// The flange frames are those of `values`' robot under each row's load.
///
/// Rows of a positioner's nests (issue #30) do not see the flange: the world
/// frame and the arm's targets come from the arm's rows, then the
/// positioner's base and its nests from the nests' rows the same way, their
/// table frames standing for the flange ([`register_positioner`]).
pub fn registered_start(
    robot: &Robot,
    values: &ParamValues,
    data: &Observations<'_>,
) -> Result<(ParamValues, registration::Registration), registration::RegistrationError> {
    let prepared = robot.prepare(values);
    let stride = data.rows.len().div_ceil(REGISTRATION_ROWS).max(1);
    let weighted: Vec<usize> = (0..data.rows.len())
        .step_by(stride)
        .filter(|k| data.scale_of(*k).iter().any(|s| *s != 0.0))
        .collect();
    let (used, nest_rows): (Vec<usize>, Vec<usize>) = weighted
        .into_iter()
        .partition(|k| data.rows[*k].positioner_deg.is_none());
    // The arm's targets, numbered as the registration counts them.
    let arm_targets: Vec<usize> = used
        .iter()
        .map(|k| data.rows[*k].target)
        .collect::<std::collections::BTreeSet<usize>>()
        .into_iter()
        .collect();
    // On the threads: a 10 000-row night's frames took 4 ms on one core.
    let flange: Vec<Frame> = used
        .par_iter()
        .map(|k| {
            let row = &data.rows[*k];
            let flange = *prepared.loaded_chains(row).deflected.flange();
            // On a track, the base frame at e = 0 is the one registered.
            match prepared.carriage(row.track_mm) {
                Some(carriage) => carriage.frame.compose(&flange),
                None => flange,
            }
        })
        .collect();
    let measured: Vec<Vector3<f64>> = used.iter().map(|k| data.measured_mm[*k]).collect();
    let target_of_row: Vec<usize> = used
        .iter()
        .map(|k| {
            arm_targets
                .iter()
                .position(|t| *t == data.rows[*k].target)
                .unwrap_or_default()
        })
        .collect();
    // Isotropic weight per row: the mean of its axes' 1/σ².
    let weights: Option<Vec<f64>> = data.row_scale.map(|_| {
        used.iter()
            .map(|k| data.scale_of(*k).norm_squared() / 3.0)
            .collect()
    });
    let v = &values.0;
    const DEG: f64 = std::f64::consts::PI / 180.0;
    // The translation parameters follow the tool rotation (eq. (4)): in the
    // flange frame a target sits at R_tool·t.
    let tool_rotation = Frame::from_xyz_euler_then_translation(
        [v[9] * DEG, v[10] * DEG, v[11] * DEG],
        Vector3::zeros(),
    )
    .rotation;
    let target_translation = |target: usize| {
        Vector3::from_fn(|axis, _| values.get(ParamId::target_translation(target, axis)))
    };
    let initial: Vec<Vector3<f64>> = arm_targets
        .iter()
        .map(|t| tool_rotation * target_translation(*t))
        .collect();
    let mut found = registration::register_world_and_tools(
        &flange,
        &measured,
        &target_of_row,
        arm_targets.len(),
        &initial,
        weights.as_deref(),
    )?;
    let mut start = *values;
    let world = registration::world_params_from_frame(
        &found.rotation,
        &found.translation_mm,
        [v[3], v[4], v[5]],
    );
    for (slot, value) in world.iter().enumerate() {
        start.0[slot] = *value;
    }
    let oriented: Vec<(usize, &fit::MeasuredOrientation)> = used
        .iter()
        .enumerate()
        .filter_map(|(i, k)| data.orientation_of(*k).map(|o| (i, o)))
        .collect();
    let tool_rotation = if oriented.is_empty() {
        tool_rotation
    } else {
        let flange_rotations: Vec<_> = oriented.iter().map(|(i, _)| flange[*i].rotation).collect();
        let measured_rotations: Vec<_> = oriented.iter().map(|(_, o)| o.world_from_tool).collect();
        let weights: Vec<f64> = oriented
            .iter()
            .map(|(_, o)| o.scale_per_deg * o.scale_per_deg)
            .collect();
        let (rotation, rms_deg) = registration::tool_rotation(
            &flange_rotations,
            &measured_rotations,
            &found.rotation,
            &weights,
        )?;
        let angles = registration::xyz_euler_nearest(&rotation, [v[9], v[10], v[11]]);
        start.0[9..12].copy_from_slice(&angles);
        found.orientation_rms_deg = Some(rms_deg);
        rotation
    };
    for (target, in_flange) in arm_targets.iter().zip(&found.tool_translations_mm) {
        let t = tool_rotation.transpose() * in_flange;
        for axis in 0..3 {
            start.set(ParamId::target_translation(*target, axis), t[axis]);
        }
    }
    if !nest_rows.is_empty() {
        found.positioner_rms_mm = register_positioner(robot, &mut start, data, &nest_rows, &found);
    }
    Ok((start, found))
}

/// The positioner's base and its nests' translations registered onto the
/// nests' rows (`nest_rows`, each weighted as the arm's) in the registered
/// world frame `world`: the table frames at each row's axis values (in the
/// positioner's base, on `start`'s axes) stand for the flange frames, so
/// the closed form that registers the world and the tools registers robot
/// base ← positioner base and the nests. Returns its RMS (mm), or `None`
/// where the rows cannot determine it (a one-axis positioner turns its
/// nests about one axis only): `start` then keeps the robot file's base and
/// the nests their start, for the fit to move.
fn register_positioner(
    robot: &Robot,
    start: &mut ParamValues,
    data: &Observations<'_>,
    nest_rows: &[usize],
    world: &registration::Registration,
) -> Option<f64> {
    use crate::robot::positioner::PositionerTerm;
    let prepared = robot.prepare(start);
    let positioner = prepared.positioner.as_ref()?;
    let base_inverse = positioner.base().inverse();
    let nests: Vec<usize> = nest_rows
        .iter()
        .map(|k| data.rows[*k].target)
        .collect::<std::collections::BTreeSet<usize>>()
        .into_iter()
        .collect();
    let mut tables = Vec::with_capacity(nest_rows.len());
    for k in nest_rows {
        let q = data.rows[*k].positioner_deg?;
        tables.push(base_inverse.compose(&positioner.chain(&q).table()));
    }
    let in_base: Vec<Vector3<f64>> = nest_rows
        .iter()
        .map(|k| world.rotation.transpose() * (data.measured_mm[*k] - world.translation_mm))
        .collect();
    let nest_of_row: Vec<usize> = nest_rows
        .iter()
        .map(|k| {
            nests
                .iter()
                .position(|t| *t == data.rows[*k].target)
                .unwrap_or_default()
        })
        .collect();
    let initial: Vec<Vector3<f64>> = nests
        .iter()
        .map(|t| Vector3::from_fn(|axis, _| start.get(ParamId::target_translation(*t, axis))))
        .collect();
    let weights: Option<Vec<f64>> = data.row_scale.map(|_| {
        nest_rows
            .iter()
            .map(|k| data.scale_of(*k).norm_squared() / 3.0)
            .collect()
    });
    let found = registration::register_world_and_tools(
        &tables,
        &in_base,
        &nest_of_row,
        nests.len(),
        &initial,
        weights.as_deref(),
    )
    .ok()?;
    let base_term = |slot: usize| ParamId::positioner(PositionerTerm::of_slot(slot));
    let nominal_angles = [3, 4, 5].map(|slot| start.get(base_term(slot)));
    let base = registration::world_params_from_frame(
        &found.rotation,
        &found.translation_mm,
        nominal_angles,
    );
    for (slot, value) in base.iter().enumerate() {
        start.set(base_term(slot), *value);
    }
    for (target, on_table) in nests.iter().zip(&found.tool_translations_mm) {
        for axis in 0..3 {
            start.set(ParamId::target_translation(*target, axis), on_table[axis]);
        }
    }
    Some(found.rms_mm)
}
