//! `identify`: kinematic and elasto-geometric identification (paper §III) from
//! measured rows — all of them, or those a `selection` marks `calibration`.
//!
//! Writes the `parameters` table (spec §6) with one set per requested model, the
//! residuals of each model on its rows, and the convergence trace. Dependent
//! parameters are found numerically by rank analysis at nominal and held at
//! nominal (status `dependent`).
//!
//! The log and the output metadata (facts) carry, per fitted model, why the
//! iteration stopped, the condition number of the scaled Jacobian, the strongest
//! parameter correlations and the rows beyond the outlier threshold.

use std::collections::HashSet;

use nalgebra::Vector3;
use polars::prelude::{Column, DataFrame};
use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::target_slots::TargetSlots;
use super::{
    InputTable, SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo,
    StageOutputs, TableSlot, conf_wrench_rows, model_name_problem, settings_error,
};
use crate::calibration::fit::{
    Algorithm, FitError, FitOptions, Loss, MeasuredOrientation, Observations, WarmStart,
};
use crate::calibration::groups::Grouping;
use crate::calibration::held::HoldOptions;
use crate::calibration::residual::ResidualOptions;
use crate::calibration::robust::RobustOptions;
use crate::calibration::selection::{ParameterSelection, SelectionRule};
use crate::calibration::{
    CalibrationOptions, ModelResult, calibrate, registered_start, row_checks, stream, unit_checks,
};
use crate::robot::params::MAX_HARMONIC_ORDER;
use crate::robot::{ConfWrench, MAX_TARGETS, ParamId, ParamValues};
use crate::table::frame;
use crate::table::parameters::{self, ModelName};
use crate::table::schema::{self, f64_values, i64_values, str_values};

/// Calibration rows each of several targets needs (see the check in `run`).
const MIN_ROWS_PER_TARGET: usize = 2;

/// Tables up to this many rows fit their models side by side (see `run`).
const SIDE_BY_SIDE_MAX_ROWS: usize = 100_000;

pub struct IdentifyStage;

/// How the fit steps (see `calibration::fit`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum AlgorithmSetting {
    /// Levenberg–Marquardt with column scaling: damped steps, taken only when the
    /// cost drops; stops on `stop_step_mm`, `stop_relative_cost` or `max_iterations`.
    LevenbergMarquardt,
    /// The paper's iteration (§III.B, eq. (25)): undamped Gauss–Newton steps, all
    /// taken; stops on `stop_step_mm` or `max_iterations`.
    Paper,
}

/// The cost of a row's residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LossSetting {
    /// The default: least squares; then, only if some row lies beyond
    /// `reject_sigmas` robust standard deviations (σ̂ from the residuals' median),
    /// a Huber fit at `huber_sigmas`·σ̂ and a final least-squares fit without the
    /// rows beyond `reject_sigmas`·σ̂ of it. No threshold in mm; clean data give
    /// exactly the least-squares result.
    Robust,
    /// Squared residuals only: the paper's estimator.
    LeastSquares,
    /// Huber on each row's residual norm with the fixed threshold
    /// `outlier_threshold_mm` (iteratively reweighted).
    Huber,
}

/// What to do with a row outside the joint limits or with an absurd value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum BadRowsSetting {
    /// Leave it out, count it, and name it in the log, the metadata and `excluded_rows`.
    Drop,
    /// Fail, naming the file, the row and the value.
    Fail,
}

/// A fixed parameter's value: a number in the parameter's unit, or `"nominal"`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum FixedValue {
    /// ±100 000 of any parameter's unit (mm, deg, rad/(N·m)) can only be a mistake.
    Value(#[schemars(range(min = -100_000.0, max = 100_000.0))] f64),
    Named(String),
}

/// Settings of `identify`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IdentifySettings {
    /// Models to identify: nominal, registered, kinematic, elastogeometric,
    /// reregistered, and the rungs beyond the paper eg_backlash (a backlash
    /// per joint, from the rows' `dir1..dir6`) and eg_harmonic (eg_backlash
    /// with transmission-error harmonics at `harmonic_orders`) and
    /// eg_residual (`residual_base`'s parameters and a Gaussian-process residual
    /// on joint angles and load, the output `residual_model`).
    pub models: Vec<String>,
    /// Parameters that may be freed (empty: all 42); rank analysis drops dependent ones.
    pub candidates: Vec<String>,
    /// Relative tolerance of the rank analysis on the column-scaled Jacobian.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub rank_tolerance: f64,
    /// levenberg_marquardt (robust default) or paper (eq. (25) as published).
    pub algorithm: AlgorithmSetting,
    /// Steps tried at most, rejected Levenberg–Marquardt steps included.
    #[schemars(range(min = 1, max = 100_000))]
    pub max_iterations: usize,
    /// Stop when a step changes no predicted position by more than this (mm). The
    /// paper used 0.05 mm. A 6-D row's turn counts as the displacement it makes
    /// at `orientation_lever_mm` (or at its σ ratio).
    #[schemars(range(min = 0.0, max = 100.0))]
    pub stop_step_mm: f64,
    /// Levenberg–Marquardt: stop when an accepted step lowers the cost by less than
    /// this fraction.
    #[schemars(range(min = 0.0, max = 1.0))]
    pub stop_relative_cost: f64,
    /// robust (default), least_squares or huber. The robust fit's scale comes
    /// from each model's own residuals, so a kinematic model's systematic load
    /// errors are not taken for outliers.
    pub loss: LossSetting,
    /// loss = robust: Huber threshold of the second stage, in robust standard deviations.
    #[schemars(range(min = 1.0, max = 100.0))]
    pub huber_sigmas: f64,
    /// loss = robust: rows beyond this many robust standard deviations are excluded.
    #[schemars(range(min = 2.0, max = 100.0))]
    pub reject_sigmas: f64,
    /// loss = robust: fail rather than exclude more than this fraction of the rows,
    /// and fail when row checks drop more than this fraction.
    #[schemars(range(min = 0.0))]
    #[schemars(extend("exclusiveMaximum" = 0.5))]
    pub max_excluded_fraction: f64,
    /// loss = least_squares or huber: rows whose residual norm exceeds this are
    /// reported as outliers, and down-weighted with huber (mm).
    #[schemars(range(max = 1000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub outlier_threshold_mm: f64,
    /// Rows outside the robot file's joint limits or with absurd values: drop (and
    /// name them) or fail.
    pub bad_rows: BadRowsSetting,
    /// Parameters held at a value in every fitted model: `{ k6 = "nominal", dd5 = 0.0 }`
    /// (status `fixed`).
    pub fixed: std::collections::BTreeMap<String, FixedValue>,
    /// The model of the `start` input the `reregistered` model takes its robot from.
    pub start_model: String,
    /// Hold (status `held`, spec §8) a length whose standard error exceeds this (mm).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_std_error_mm: f64,
    /// Hold an angle whose standard error exceeds this (deg).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_std_error_deg: f64,
    /// Hold a compliance whose standard error exceeds this (deg/(N·m)).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_std_error_compliance: f64,
    /// Hold a parameter whose variance inflation factor 1/(1 − R²) (R: its
    /// estimate's multiple correlation with the others) exceeds this; 1e4 is
    /// |R| ≈ 0.99995. Near-dependence the exact rank analysis lets through.
    #[schemars(range(min = 10.0))]
    pub max_variance_inflation: f64,
    /// Fail when an identified length error (da, dd) is farther than this from
    /// nominal (mm): a robot 10 mm off its data sheet is a wrong robot file or
    /// a unit mistake, not a calibration.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub plausible_length_mm: f64,
    /// Fail when an identified angle error (dtheta, dalpha, tool rotation) is
    /// farther than this from nominal (deg).
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub plausible_angle_deg: f64,
    /// Fail when the closed-form registration of the start leaves an RMS residual
    /// beyond this (mm): no robot is that far from its model, a unit or a robot
    /// file is wrong.
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub max_registration_rms_mm: f64,
    /// Accept a fit that stops at `max_iterations` (a warning in the log, the
    /// facts and the report's first screen) instead of failing the stage.
    pub accept_not_converged: bool,
    /// 6-D rows (spec §8: `rx_deg, ry_deg, rz_deg`): fit their measured tool
    /// orientation as well (three more equations a row); false: positions only.
    pub use_orientation: bool,
    /// 6-D rows without `sigma_rx_deg …`: a rotation residual of θ weighs as
    /// the position residual θ·lever it makes at this distance from the tool
    /// (mm). 100 mm is a typical tool's length (the T-Mac's centre sits 93 mm
    /// from the UR10's flange), and less than the 200–270 mm at which the
    /// IPA tracker data's own position and orientation σ are equal: orientations
    /// count, without letting what the model cannot explain of them outweigh
    /// the positions. With position σ columns, the orientation σ is
    /// σ_position/lever (σ_position the RMS of the three).
    #[schemars(range(max = 100_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub orientation_lever_mm: f64,
    /// How the free parameters are chosen. `standard_errors` (default): every
    /// identifiable parameter within the standard-error and variance-inflation
    /// bounds. Of those, by whole groups of rows left out in turn (the others
    /// are `held` with the figures in `reason`): `grouped_jackknife` holds,
    /// one at a time, a parameter whose leave-group-out estimates do not tell
    /// it from nominal (`held_out_min_t`); `held_out` keeps a parameter only
    /// if freeing it lowers the error on the groups left out (backward
    /// elimination). Neither is the default: the guide, docs/real-cells.md, held-out accuracy.
    pub parameter_choice: ParameterChoice,
    /// parameter_choice = held_out or grouped_jackknife: how the rows are
    /// grouped: configuration (clusters in joint space, default), region (of
    /// the workspace), load, time (`measured_at`) or random.
    pub held_out_grouping: Grouping,
    /// parameter_choice = held_out or grouped_jackknife: groups left out in
    /// turn (folds).
    #[schemars(range(min = 2, max = 50))]
    pub held_out_folds: usize,
    /// parameter_choice = grouped_jackknife: a parameter is held while
    /// |value − nominal| is below this many grouped-jackknife standard errors
    /// (2: the usual two-sided 95 % test).
    #[schemars(range(max = 10.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub held_out_min_t: f64,
    /// Model `eg_harmonic`: the orders n of the transmission-error terms
    /// sin(n·q) and cos(n·q) fitted per joint (1: once per output turn, 2:
    /// twice, the usual strain-wave and RV reducer errors), each 1..=3.
    pub harmonic_orders: Vec<usize>,
    /// Model `eg_residual`: inducing points of the Gaussian-process residual's
    /// sparse posterior; with at most this many calibration rows it is exact.
    /// Fit and prediction cost grow with its square.
    #[schemars(range(min = 16, max = 4096))]
    pub residual_inducing_points: usize,
    /// Model `eg_residual`: the parametric model under its Gaussian process,
    /// eg_harmonic (default) or elastogeometric (no backlash or harmonics:
    /// where harmonics extrapolate into configurations the rows do not
    /// surround, the process then corrects the paper's model instead).
    pub residual_base: crate::calibration::ResidualBase,
}

/// How `identify` chooses the free parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ParameterChoice {
    /// Backward elimination on the grouped cross-validation error (issue #28).
    HeldOut,
    /// The grouped-jackknife significance of each parameter (issue #28).
    GroupedJackknife,
    /// By the standard-error and variance-inflation bounds alone.
    StandardErrors,
}

impl Default for IdentifySettings {
    fn default() -> Self {
        IdentifySettings {
            models: ModelName::ALL
                .iter()
                .map(|m| m.as_str().to_string())
                .collect(),
            candidates: Vec::new(),
            rank_tolerance: 1e-6,
            algorithm: AlgorithmSetting::LevenbergMarquardt,
            max_iterations: 30,
            stop_step_mm: 1e-4,
            stop_relative_cost: 1e-10,
            loss: LossSetting::Robust,
            huber_sigmas: RobustOptions::default().huber_sigmas,
            reject_sigmas: RobustOptions::default().reject_sigmas,
            max_excluded_fraction: RobustOptions::default().max_excluded_fraction,
            outlier_threshold_mm: 0.5,
            bad_rows: BadRowsSetting::Drop,
            fixed: Default::default(),
            start_model: ModelName::Elastogeometric.as_str().into(),
            max_std_error_mm: HoldOptions::default().max_std_error_mm,
            max_std_error_deg: HoldOptions::default().max_std_error_deg,
            max_std_error_compliance: HoldOptions::default().max_std_error_compliance,
            max_variance_inflation: HoldOptions::default().max_variance_inflation,
            plausible_length_mm: 10.0,
            plausible_angle_deg: 2.0,
            max_registration_rms_mm: 25.0,
            accept_not_converged: false,
            parameter_choice: ParameterChoice::StandardErrors,
            held_out_grouping: Grouping::Configuration,
            held_out_folds: 5,
            held_out_min_t: 2.0,
            harmonic_orders: vec![1, 2],
            residual_inducing_points: ResidualOptions::default().inducing_points,
            residual_base: crate::calibration::ResidualBase::default(),
            use_orientation: true,
            orientation_lever_mm: DEFAULT_ORIENTATION_LEVER_MM,
        }
    }
}

/// Default of `orientation_lever_mm` (see there for why).
pub const DEFAULT_ORIENTATION_LEVER_MM: f64 = 100.0;

impl IdentifySettings {
    /// The fit options these settings describe (their ranges are checked in phase 2).
    pub fn fit_options(&self) -> FitOptions {
        FitOptions {
            algorithm: match self.algorithm {
                AlgorithmSetting::LevenbergMarquardt => Algorithm::LevenbergMarquardt,
                AlgorithmSetting::Paper => Algorithm::Paper,
            },
            loss: match self.loss {
                LossSetting::LeastSquares | LossSetting::Robust => Loss::LeastSquares,
                LossSetting::Huber => Loss::Huber {
                    threshold_mm: self.outlier_threshold_mm,
                },
            },
            max_iterations: self.max_iterations,
            stop_step_mm: self.stop_step_mm,
            stop_relative_cost: self.stop_relative_cost,
            chunk_rows: stream::CHUNK_ROWS,
            warm_start: Some(WarmStart::default()),
        }
    }

    /// The bounds of the held parameters (spec §8).
    pub fn hold_options(&self) -> HoldOptions {
        HoldOptions {
            max_std_error_mm: self.max_std_error_mm,
            max_std_error_deg: self.max_std_error_deg,
            max_std_error_compliance: self.max_std_error_compliance,
            max_variance_inflation: self.max_variance_inflation,
        }
    }

    /// The robust fit's options (`None` unless loss = robust); ranges and
    /// `huber_sigmas` ≤ `reject_sigmas` are checked by [`Stage::check_settings`].
    pub fn robust_options(&self) -> Option<RobustOptions> {
        (self.loss == LossSetting::Robust).then_some(RobustOptions {
            huber_sigmas: self.huber_sigmas,
            reject_sigmas: self.reject_sigmas,
            max_excluded_fraction: self.max_excluded_fraction,
        })
    }

    /// The fixed parameters with their values (`"nominal"`: the robot file's), or
    /// every bad key and value.
    pub fn fixed_values(
        &self,
        nominal: &ParamValues,
    ) -> Result<Vec<(ParamId, f64)>, Vec<SettingsProblem>> {
        let mut values = Vec::new();
        let mut problems = Vec::new();
        for (name, value) in &self.fixed {
            let key = format!("fixed.{name}");
            let Some(id) = ParamId::from_name(name) else {
                problems.push(SettingsProblem::new(
                    &key,
                    format!(
                        "unknown parameter{}",
                        crate::suggest::did_you_mean(name, ParamId::known_names())
                    ),
                ));
                continue;
            };
            match value {
                FixedValue::Value(v) => values.push((id, *v)),
                FixedValue::Named(n) if n == "nominal" => values.push((id, nominal.get(id))),
                FixedValue::Named(n) => problems.push(SettingsProblem::new(
                    &key,
                    format!(
                        "expected a number in {} or \"nominal\", found \"{n}\"",
                        id.unit()
                    ),
                )),
            }
        }
        if problems.is_empty() {
            Ok(values)
        } else {
            Err(problems)
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "identify",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Kinematic and elasto-geometric identification with rank analysis and standard errors",
    code_version: 16,
    inputs: &[
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "measured rows (spec §6)",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "rows with role = calibration are used; all rows when absent",
        },
        TableSlot {
            name: "start",
            schema: schema::parameters,
            required: false,
            meaning: "an earlier calibration: the robot the `reregistered` model re-registers (its set `start_model`)",
        },
    ],
    outputs: &[
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: true,
            meaning: "one set per model (spec §6)",
        },
        TableSlot {
            name: "identification_trace",
            schema: schema::identification_trace,
            required: true,
            meaning: "steps tried per model (rms, max, step, damping, accepted)",
        },
        TableSlot {
            name: "residuals",
            schema: schema::residuals,
            required: true,
            meaning: "each model's residual and weight on each calibration row",
        },
        TableSlot {
            name: "covariance",
            schema: schema::covariance,
            required: true,
            meaning: "each fitted model's parameter covariance (spec §7)",
        },
        TableSlot {
            name: "excluded_rows",
            schema: schema::excluded_rows,
            required: true,
            meaning: "rows left out (row checks, robust fit) and why",
        },
        super::residual_rung::RESIDUAL_OUTPUT,
    ],
};

/// Measured rows: ids, model inputs (measured joints and wrench) and measured
/// positions, with the optional §7 columns. Rows' `target` is 0 until a caller
/// maps the target ids ([`MeasuredRows::set_targets`]).
#[derive(Debug, Default)]
pub struct MeasuredRows {
    pub ids: Vec<i64>,
    /// Each row's 0-based row in the file (for messages).
    pub file_rows: Vec<usize>,
    pub rows: Vec<ConfWrench>,
    pub positions: Vec<Vector3<f64>>,
    /// `target_id` of each row, when the table has the column.
    pub target_ids: Option<Vec<Option<String>>>,
    /// `sigma_x_mm, sigma_y_mm, sigma_z_mm` of each row, when the table has them.
    pub sigma_mm: Option<Vec<Vector3<f64>>>,
    /// `measured_at` of each row (µs since the epoch, `None` where null), when
    /// the table has it.
    pub measured_at_us: Option<Vec<Option<i64>>>,
    /// `rx_deg, ry_deg, rz_deg` of each row (6-D rows, spec §8), when the table has them.
    pub orientation_deg: Option<Vec<Vector3<f64>>>,
    /// `sigma_rx_deg, sigma_ry_deg, sigma_rz_deg`, when the table has them.
    pub sigma_orientation_deg: Option<Vec<Vector3<f64>>>,
}

impl MeasuredRows {
    /// Keeps the rows whose flag in `wanted` (one per row) is set.
    pub fn retain(&mut self, wanted: &[bool]) {
        retain_wanted(&mut self.ids, wanted);
        retain_wanted(&mut self.file_rows, wanted);
        retain_wanted(&mut self.rows, wanted);
        retain_wanted(&mut self.positions, wanted);
        if let Some(targets) = self.target_ids.as_mut() {
            retain_wanted(targets, wanted);
        }
        if let Some(sigma) = self.sigma_mm.as_mut() {
            retain_wanted(sigma, wanted);
        }
        if let Some(times) = self.measured_at_us.as_mut() {
            retain_wanted(times, wanted);
        }
        if let Some(angles) = self.orientation_deg.as_mut() {
            retain_wanted(angles, wanted);
        }
        if let Some(sigma) = self.sigma_orientation_deg.as_mut() {
            retain_wanted(sigma, wanted);
        }
    }

    /// A copy of the rows whose flag in `wanted` (one per row) is set.
    pub fn subset(&self, wanted: &[bool]) -> MeasuredRows {
        fn pick<T: Clone>(values: &[T], wanted: &[bool]) -> Vec<T> {
            values
                .iter()
                .zip(wanted)
                .filter(|(_, keep)| **keep)
                .map(|(v, _)| v.clone())
                .collect()
        }
        MeasuredRows {
            ids: pick(&self.ids, wanted),
            file_rows: pick(&self.file_rows, wanted),
            rows: pick(&self.rows, wanted),
            positions: pick(&self.positions, wanted),
            target_ids: self.target_ids.as_deref().map(|v| pick(v, wanted)),
            sigma_mm: self.sigma_mm.as_deref().map(|v| pick(v, wanted)),
            measured_at_us: self.measured_at_us.as_deref().map(|v| pick(v, wanted)),
            orientation_deg: self.orientation_deg.as_deref().map(|v| pick(v, wanted)),
            sigma_orientation_deg: self
                .sigma_orientation_deg
                .as_deref()
                .map(|v| pick(v, wanted)),
        }
    }

    /// Why row `k` cannot be used ([`row_checks::row_problem`], and its
    /// orientation's [`row_checks::orientation_problem`]); `None` when it can.
    pub fn row_problem(&self, robot: &crate::robot::Robot, k: usize) -> Option<String> {
        row_checks::row_problem(
            robot,
            &self.rows[k],
            &self.positions[k],
            self.sigma_mm.as_ref().map(|s| &s[k]),
        )
        .or_else(|| {
            let angles = self.orientation_deg.as_ref()?;
            row_checks::orientation_problem(
                &angles[k],
                self.sigma_orientation_deg.as_ref().map(|s| &s[k]),
            )
        })
    }

    /// Each row's measured world ← tool rotation (spec §8: Rot(x, rx)·Rot(y,
    /// ry)·Rot(z, rz)), when the table has the orientation columns.
    pub fn measured_rotations(&self) -> Option<Vec<nalgebra::Matrix3<f64>>> {
        let angles = self.orientation_deg.as_ref()?;
        Some(
            angles
                .iter()
                .map(|a| {
                    crate::robot::Frame::from_xyz_euler_then_translation(
                        [a.x.to_radians(), a.y.to_radians(), a.z.to_radians()],
                        Vector3::zeros(),
                    )
                    .rotation
                })
                .collect(),
        )
    }

    /// The 6-D rows' orientations with their weights for the fit (spec §8):
    /// `1/σ` (σ the RMS of the three angle σ, which keeps their total variance:
    /// the Euler-rate axes are unit vectors) where the table has
    /// `sigma_rx_deg …`; else the weight `lever_mm` gives a degree against the
    /// row's position σ (1 mm without position σ). `None` without orientation
    /// columns.
    pub fn orientations_for_fit(&self, lever_mm: f64) -> Option<Vec<Option<MeasuredOrientation>>> {
        let rotations = self.measured_rotations()?;
        Some(
            rotations
                .into_iter()
                .enumerate()
                .map(|(k, world_from_tool)| {
                    let rms = |s: &Vector3<f64>| (s.norm_squared() / 3.0).sqrt();
                    let scale_per_deg = match &self.sigma_orientation_deg {
                        Some(sigma) => 1.0 / rms(&sigma[k]),
                        None => {
                            let sigma_position_mm =
                                self.sigma_mm.as_ref().map_or(1.0, |s| rms(&s[k]));
                            lever_mm.to_radians() / sigma_position_mm
                        }
                    };
                    Some(MeasuredOrientation {
                        world_from_tool,
                        scale_per_deg,
                    })
                })
                .collect(),
        )
    }

    /// Leaves out the rows that fail the row checks ([`row_checks::row_problem`]):
    /// a corrupt row would dominate an error statistic as it would a fit. Returns
    /// what went, for a note and a fact; `None` when every row passed.
    pub fn leave_out_bad_rows(
        &mut self,
        robot: &crate::robot::Robot,
        file: &std::path::Path,
    ) -> Option<String> {
        // On the threads: a million rows' checks took 0.2 s on one (issue #31).
        let problems: Vec<Option<String>> = (0..self.rows.len())
            .into_par_iter()
            .with_min_len(crate::calibration::stream::CHUNK_ROWS)
            .map(|k| self.row_problem(robot, k))
            .collect();
        let first = problems.iter().position(Option::is_some)?;
        let count = problems.iter().filter(|p| p.is_some()).count();
        let summary = format!(
            "{count} of {} rows of {} fail the row checks and are left out (first: row {}, cw_id {}: {})",
            self.rows.len(),
            file.display(),
            self.file_rows[first],
            self.ids[first],
            problems[first].as_deref().unwrap_or_default()
        );
        let keep: Vec<bool> = problems.iter().map(Option::is_none).collect();
        self.retain(&keep);
        Some(summary)
    }

    /// Sets each row's target index (no-op for an empty list).
    pub fn set_targets(&mut self, indices: &[usize]) {
        for (row, target) in self.rows.iter_mut().zip(indices) {
            row.target = *target;
        }
    }
}

/// The measured rows of a table, optionally only those whose id is in `keep`.
/// All rows are converted once and filtered in place, so a large table is not
/// copied twice.
pub fn measured_rows(
    table: &InputTable,
    robot: &crate::robot::RobotSpec,
    keep: Option<&HashSet<i64>>,
) -> Result<MeasuredRows, StageError> {
    let (ids, rows) = conf_wrench_rows(table, robot)?;
    let xyz = schema::POSITION_COLUMNS
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    let positions = (0..ids.len())
        .map(|k| Vector3::new(xyz[0][k], xyz[1][k], xyz[2][k]))
        .collect();
    let target_ids = match table.df.column("target_id") {
        Ok(_) => Some(str_values(&table.df, "target_id", &table.path)?),
        Err(_) => None,
    };
    if let Some((row, message)) = target_ids
        .iter()
        .flatten()
        .enumerate()
        .find_map(|(row, id)| {
            crate::table::parameters::target_id_problem(id.as_deref().unwrap_or_default())
                .map(|m| (row, m))
        })
    {
        return Err(StageError::Table(crate::table::TableError::BadValue {
            file: table.path.clone(),
            column: "target_id".into(),
            row,
            message,
        }));
    }
    let sigma_mm = optional_triple(table, &schema::SIGMA_COLUMNS, ids.len())?;
    let orientation_deg = optional_triple(table, &schema::ORIENTATION_COLUMNS, ids.len())?;
    let sigma_orientation_deg =
        optional_triple(table, &schema::ORIENTATION_SIGMA_COLUMNS, ids.len())?;
    if sigma_orientation_deg.is_some() && orientation_deg.is_none() {
        return Err(StageError::Invalid(format!(
            "{}: has {} but not the orientation they are the uncertainty of ({})",
            table.path.display(),
            schema::ORIENTATION_SIGMA_COLUMNS.join(", "),
            schema::ORIENTATION_COLUMNS.join(", ")
        )));
    }
    let measured_at_us = match table.df.column("measured_at") {
        Ok(column) => Some(
            column
                .cast(&polars::prelude::DataType::Int64)
                .and_then(|c| c.i64().cloned())
                .map_err(|e| {
                    StageError::Invalid(format!("{}: measured_at: {e}", table.path.display()))
                })?
                .iter()
                .collect(),
        ),
        Err(_) => None,
    };
    let mut out = MeasuredRows {
        file_rows: (0..ids.len()).collect(),
        ids,
        rows,
        positions,
        target_ids,
        sigma_mm,
        measured_at_us,
        orientation_deg,
        sigma_orientation_deg,
    };
    if let Some(keep) = keep {
        let wanted: Vec<bool> = out.ids.iter().map(|id| keep.contains(id)).collect();
        out.retain(&wanted);
    }
    Ok(out)
}

/// Three optional float columns of a table read together: all three or none.
fn optional_triple(
    table: &InputTable,
    names: &[&str; 3],
    rows: usize,
) -> Result<Option<Vec<Vector3<f64>>>, StageError> {
    let present: Vec<bool> = names.iter().map(|c| table.df.column(c).is_ok()).collect();
    if present.iter().all(|p| !*p) {
        return Ok(None);
    }
    if !present.iter().all(|p| *p) {
        return Err(StageError::Invalid(format!(
            "{}: has some of {} but not all three; give all or none",
            table.path.display(),
            names.join(", ")
        )));
    }
    let columns = names
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Some(
        (0..rows)
            .map(|k| Vector3::new(columns[0][k], columns[1][k], columns[2][k]))
            .collect(),
    ))
}

/// Keeps the elements whose flag in `wanted` (one per element) is set.
fn retain_wanted<T>(values: &mut Vec<T>, wanted: &[bool]) {
    let mut flags = wanted.iter();
    values.retain(|_| flags.next().copied().unwrap_or(false));
}

/// The cw_ids a selection table gives `role`.
pub fn ids_with_role(table: &InputTable, role: &str) -> Result<HashSet<i64>, StageError> {
    let ids = i64_values(&table.df, "cw_id", &table.path)?;
    let roles = str_values(&table.df, "role", &table.path)?;
    for (row, r) in roles.iter().enumerate() {
        let r = r.as_deref().unwrap_or_default();
        if r != "calibration" && r != "validation" {
            return Err(StageError::Table(crate::table::TableError::BadValue {
                file: table.path.clone(),
                column: "role".into(),
                row,
                message: format!("expected calibration or validation, found `{r}`"),
            }));
        }
    }
    Ok(ids
        .into_iter()
        .zip(roles)
        .filter(|(_, r)| r.as_deref() == Some(role))
        .map(|(id, _)| id)
        .collect())
}

/// The job's candidates, default the arm's parameters (the 42, and a
/// seventh joint's for an arm of `joints` = 7).
fn parse_candidates(names: &[String], joints: usize) -> Result<Vec<ParamId>, StageError> {
    if names.is_empty() {
        return Ok(ParamId::of_arm(joints).collect());
    }
    names
        .iter()
        .map(|n| {
            ParamId::from_name(n).ok_or_else(|| {
                StageError::Invalid(format!(
                    "setting `candidates`: unknown parameter `{n}`{}",
                    crate::suggest::did_you_mean(n, ParamId::known_names())
                ))
            })
        })
        .collect()
}

impl Stage for IdentifyStage {
    type Settings = IdentifySettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &IdentifySettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> = settings
            .models
            .iter()
            .enumerate()
            .filter_map(|(i, m)| model_name_problem(&format!("models[{i}]"), m))
            .collect();
        problems.extend(model_name_problem("start_model", &settings.start_model));
        let reregistered = ModelName::Reregistered.as_str();
        if let Some(i) = settings.models.iter().position(|m| m == reregistered)
            && !ctx.bound_inputs.contains(&"start")
        {
            problems.push(SettingsProblem::new(
                &format!("models[{i}]"),
                "model `reregistered` needs the input `start` (an earlier calibration's parameters table)",
            ));
        }
        if let Err(bad) = settings.fixed_values(&ParamValues::nominal(ctx.robot)) {
            problems.extend(bad);
        }
        for (i, order) in settings.harmonic_orders.iter().enumerate() {
            if settings.harmonic_orders[..i].contains(order) {
                problems.push(SettingsProblem::new(
                    &format!("harmonic_orders[{i}]"),
                    format!("order {order} is listed twice"),
                ));
            } else if !(1..=MAX_HARMONIC_ORDER).contains(order) {
                problems.push(SettingsProblem::new(
                    &format!("harmonic_orders[{i}]"),
                    format!(
                        "order {order}: expected 1 to {MAX_HARMONIC_ORDER} (times per output turn)"
                    ),
                ));
            }
        }
        if settings.huber_sigmas > settings.reject_sigmas {
            problems.push(SettingsProblem::new(
                "huber_sigmas",
                format!(
                    "`huber_sigmas` ({}) must not exceed `reject_sigmas` ({}): rows are down-weighted before they are excluded",
                    settings.huber_sigmas, settings.reject_sigmas
                ),
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &IdentifySettings,
    ) -> Result<StageOutputs, StageError> {
        let models: Vec<ModelName> = settings
            .models
            .iter()
            .map(|m| {
                m.parse()
                    .map_err(|e: String| StageError::Invalid(format!("setting `models`: {e}")))
            })
            .collect::<Result<_, _>>()?;
        let nominal = ParamValues::nominal(ctx.robot.spec());
        let robust = settings.robust_options();
        let mut fixed = settings
            .fixed_values(&nominal)
            .map_err(|p| settings_error(&p))?;
        let start_set = match ctx.inputs.get("start") {
            Some(_) => Some(super::model_values(
                ctx,
                "start",
                "start_model",
                &settings.start_model,
            )?),
            None => None,
        };
        let keep = match ctx.inputs.get("selection") {
            Some(selection) => Some(ids_with_role(selection, "calibration")?),
            None => None,
        };
        let measurements = ctx.input("measurements")?;
        let mut data = measured_rows(measurements, ctx.robot.spec(), keep.as_ref())?;
        if data.rows.is_empty() {
            return Err(StageError::Invalid(
                "no calibration rows (selection marks none, or measurements is empty)".into(),
            ));
        }
        let mut outputs = StageOutputs::default();
        let mut excluded = ExcludedColumns::default();
        let checked = check_rows(ctx, settings, measurements, &mut data, &mut excluded)?;
        outputs.facts.insert("rows_dropped".into(), checked);

        let TargetSlots {
            ids: targets,
            slot_of_row: target_of_row,
        } = TargetSlots::of_ids(data.target_ids.as_deref(), data.rows.len());
        if targets.len() > MAX_TARGETS {
            return Err(StageError::Invalid(format!(
                "{}: {} targets ({}); at most {MAX_TARGETS} can be fitted jointly",
                measurements.path.display(),
                targets.len(),
                targets.join(", ")
            )));
        }
        // A target's translation takes three equations: a target measured on one
        // row absorbs that row whole, and nothing checks it.
        if targets.len() > 1 {
            for (index, id) in targets.iter().enumerate() {
                let rows = target_of_row.iter().filter(|t| **t == index).count();
                if rows < MIN_ROWS_PER_TARGET {
                    return Err(StageError::Invalid(format!(
                        "{}: target `{id}` has {rows} calibration row(s) after the selection and row checks; each of several targets needs at least {MIN_ROWS_PER_TARGET} (its translation alone takes 3 equations per row); measure it more or drop its rows",
                        measurements.path.display(),
                    )));
                }
            }
        }
        data.set_targets(&target_of_row);
        // A fixed tool translation holds every target's.
        let tool_fixed: Vec<(ParamId, f64)> = fixed
            .iter()
            .filter(|(id, _)| id.is_tool_translation())
            .flat_map(|(id, value)| {
                let axis = id.index() - 6;
                (1..targets.len()).map(move |t| (ParamId::target_translation(t, axis), *value))
            })
            .collect();
        fixed.extend(tool_fixed);
        let options = CalibrationOptions {
            candidates: parse_candidates(&settings.candidates, ctx.robot.joint_count())?,
            rank_tolerance: settings.rank_tolerance,
            fit: settings.fit_options(),
            robust,
            fixed,
            targets: targets.len().max(1),
            harmonic_orders: settings.harmonic_orders.clone(),
            residual_base: settings.residual_base,
            hold: Some(settings.hold_options()),
            selection: match settings.parameter_choice {
                ParameterChoice::StandardErrors => None,
                ParameterChoice::HeldOut | ParameterChoice::GroupedJackknife => {
                    let folds = super::held_out::fold_assignment(
                        &data,
                        settings.held_out_grouping,
                        settings.held_out_folds,
                        ctx.seed,
                    )
                    .map_err(|e| {
                        StageError::Invalid(format!(
                            "{}: setting `held_out_grouping` = {}: {e}",
                            measurements.path.display(),
                            settings.held_out_grouping
                        ))
                    })?;
                    let rule = if settings.parameter_choice == ParameterChoice::HeldOut {
                        SelectionRule::Elimination
                    } else {
                        SelectionRule::Jackknife {
                            min_t: settings.held_out_min_t,
                        }
                    };
                    Some(ParameterSelection { folds, rule })
                }
            },
        };
        let scales: Option<Vec<Vector3<f64>>> = data
            .sigma_mm
            .as_ref()
            .map(|sigma| sigma.iter().map(|s| s.map(|v| 1.0 / v)).collect());
        let orientations = if settings.use_orientation {
            if data.sigma_orientation_deg.is_some() && data.sigma_mm.is_none() {
                return Err(StageError::Invalid(format!(
                    "{}: has {} but not {}: the orientations would weigh 1/σ against positions weighed as if σ were 1 mm; give both or neither (`orientation_lever_mm` weighs orientations without σ)",
                    measurements.path.display(),
                    schema::ORIENTATION_SIGMA_COLUMNS.join(", "),
                    schema::SIGMA_COLUMNS.join(", ")
                )));
            }
            data.orientations_for_fit(settings.orientation_lever_mm)
        } else {
            None
        };
        if let Some(orientations) = &orientations {
            outputs.facts.insert(
                "orientation_rows".into(),
                orientations.iter().flatten().count().to_string(),
            );
        }
        let observations = Observations {
            rows: &data.rows,
            measured_mm: &data.positions,
            row_scale: scales.as_deref(),
            orientations: orientations.as_deref(),
        };
        if let Some(suspicion) = unit_checks::suspect_units(ctx.robot, &data.rows, &data.positions)
        {
            return Err(StageError::Invalid(format!(
                "{}: {} (columns {} and {}); fix the unit where the table was made (import_measurements: `length_unit`, `joint_unit`)",
                measurements.path.display(),
                suspicion.describe(),
                schema::POSITION_COLUMNS.join(", "),
                crate::table::schema::joint_column_names(ctx.robot.spec()).join(", "),
            )));
        }
        let registered = register(ctx, "robot file", &nominal, &observations, &mut outputs);
        let reregistered = start_set
            .as_ref()
            .map(|start| register(ctx, "start", start, &observations, &mut outputs));
        for (what, registration) in [
            ("robot file", Some(&registered)),
            ("start", reregistered.as_ref()),
        ] {
            if let Some((_, Some(rms_mm))) = registration
                && *rms_mm > settings.max_registration_rms_mm
            {
                return Err(StageError::Invalid(format!(
                    "{}: the {what}'s robot registered onto the measured positions leaves an RMS residual of {rms_mm:.1} mm (setting `max_registration_rms_mm` = {}): no robot is that far from its model, so a unit (`length_unit`, `joint_unit` of the import), the joint zero or sign, or the robot file does not match the rows",
                    measurements.path.display(),
                    settings.max_registration_rms_mm
                )));
            }
        }
        let registered = registered.0;
        let reregistered = reregistered.map(|r| r.0);
        let ids = &data.ids;
        let mut sets = Vec::new();
        let mut trace = TraceColumns::default();
        let mut covariance = CovarianceColumns::default();
        let mut residuals: Option<DataFrame> = None;
        let mut residual_models = Vec::new();
        // A model that did not converge or came out implausible fails the
        // stage, after every model was tried: a later model's bad input (too
        // few rows) is the better message, and all failures show at once.
        let mut failures: Vec<String> = Vec::new();
        let start_of = |model: ModelName| match (model, reregistered) {
            (ModelName::Reregistered, Some(start)) => start,
            _ => registered,
        };
        let fit_model = |model: ModelName| {
            calibrate(ctx.robot, model, &observations, &start_of(model), &options)
        };
        // The models' fits are independent. On a table too small for one
        // fit's passes to keep every core busy (its steps and the subsample's
        // fit are a few chunks each) they run side by side; on a larger one
        // each pass already fills the cores, and fits in flight together
        // would only hold several sets of per-row state (issue #31; measured,
        // kinematic and elasto-geometric: 10 010 rows 132–145 ms side by side
        // against 143–167 ms, 10⁶ rows 5.7 s either way and 50 MB more).
        let fits: Vec<_> = if data.rows.len() <= SIDE_BY_SIDE_MAX_ROWS {
            for model in &models {
                ctx.progress
                    .note(&format!("identifying {model} on {} rows", data.rows.len()));
            }
            models.par_iter().map(|model| fit_model(*model)).collect()
        } else {
            models
                .iter()
                .map(|model| {
                    ctx.progress
                        .note(&format!("identifying {model} on {} rows", data.rows.len()));
                    fit_model(*model)
                })
                .collect()
        };
        for (model, fitted) in models.into_iter().zip(fits) {
            let mut result = fitted.map_err(
                |e| match e {
                    // Too small a table is a property of the input, not a failure of the fit.
                    FitError::TooFewRows { .. } => StageError::Invalid(format!(
                        "{}: {model}: {e}",
                        measurements.path.display()
                    )),
                    FitError::Diverged(_) => StageError::Failed(format!(
                        "{}: {model}: {e}; look at {}the rows far from the others (`excluded_rows`, the row checks), and the `fixed` values and start model",
                        measurements.path.display(),
                        smallest_sigma(&data)
                            .map(|(id, sigma)| format!(
                                "the sigma columns (each row weighs 1/σ; the smallest is {sigma} mm at cw_id {id}), "
                            ))
                            .unwrap_or_default()
                    )),
                    _ => StageError::Failed(format!("{model}: {e}")),
                },
            )?;
            if targets.len() > 1 {
                result.set.targets = targets.clone();
            }
            if !result.converged {
                let steps = result.trace.len();
                if !settings.accept_not_converged {
                    failures.push(format!(
                        "{}: {model}: the fit did not converge after {steps} steps (setting `max_iterations` = {}); try a larger `max_iterations`, fix or hold the parameters named in the correlations below (`fixed`), or set `accept_not_converged = true` to use it anyway (a warning in the report){}",
                        measurements.path.display(),
                        settings.max_iterations,
                        result
                            .diagnostics
                            .as_ref()
                            .map(|d| format!(
                                "; strongest correlations: {}",
                                d.correlations
                                    .iter()
                                    .map(|(a, b, rho)| format!(
                                        "{}/{} {rho:+.4}",
                                        result.set.name_of(*a),
                                        result.set.name_of(*b)
                                    ))
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ))
                            .unwrap_or_default()
                    ));
                    continue;
                }
                let warning = format!(
                    "{model}: not converged after {steps} steps, accepted (`accept_not_converged = true`)"
                );
                ctx.progress.note(&format!("warning: {warning}"));
                outputs
                    .facts
                    .insert(format!("{model}_not_converged_accepted"), warning);
            }
            if !result.held.is_empty() {
                let held = result
                    .held
                    .iter()
                    .map(|h| format!("{}: {}", h.id, h.reason))
                    .collect::<Vec<_>>()
                    .join("; ");
                ctx.progress
                    .note(&format!("{model}: held at nominal: {held}"));
                outputs.facts.insert(format!("{model}_held"), held);
            }
            if let Some(problem) = implausible_parameter(
                &result.set,
                &nominal,
                settings,
                observations.has_orientations(),
            ) {
                failures.push(format!(
                    "{}: {model}: {problem}",
                    measurements.path.display()
                ));
                continue;
            }
            for (key, value) in model_facts(model, &result, ids, settings) {
                ctx.progress.note(&format!("{model}: {key} = {value}"));
                outputs.facts.insert(format!("{model}_{key}"), value);
            }
            if let Some(summary) = &result.robust
                && !summary.excluded.is_empty()
            {
                ctx.progress.note(&format!(
                    "warning: {model}: {} of {} rows left out of the fit as outliers (residual beyond {:.4}, {} robust standard deviations; listed in the output table `excluded_rows`)",
                    summary.excluded.len(),
                    ids.len(),
                    summary.threshold,
                    settings.reject_sigmas
                ));
            }
            if let Some(summary) = &result.robust {
                for k in &summary.excluded {
                    let scaled = result.residuals_mm[*k].component_mul(&observations.scale_of(*k));
                    excluded.push(
                        ids[*k],
                        Some(model.as_str()),
                        "robust_fit",
                        format!(
                            "residual {:.4} mm{}{} beyond {:.4} ({} robust standard deviations)",
                            result.residuals_mm[*k].norm(),
                            result
                                .residuals_deg
                                .get(*k)
                                .copied()
                                .flatten()
                                .map(|r| format!(" and {:.4} deg", r.norm()))
                                .unwrap_or_default(),
                            if scales.is_some() {
                                format!(" ({:.2} σ-scaled)", scaled.norm())
                            } else {
                                String::new()
                            },
                            summary.threshold,
                            settings.reject_sigmas
                        ),
                    );
                }
            }
            trace.push(model, &result);
            covariance.push(model, &result);
            let flagged: Vec<bool> = match &result.robust {
                Some(summary) => {
                    let mut flags = vec![false; ids.len()];
                    for k in &summary.excluded {
                        flags[*k] = true;
                    }
                    flags
                }
                None => result
                    .residuals_mm
                    .iter()
                    .map(|r| r.norm() > settings.outlier_threshold_mm)
                    .collect(),
            };
            if model.has_residual_model() {
                super::refuse_prismatic_joints(
                    ctx.robot.spec(),
                    &format!("model {model}'s residual model"),
                    "use eg_harmonic, eg_backlash or elastogeometric",
                )?;
                ctx.progress
                    .note(&format!("{model}: fitting the residual model"));
                let options = ResidualOptions {
                    inducing_points: settings.residual_inducing_points,
                    seed: ctx.seed,
                    ..ResidualOptions::default()
                };
                let fitted = super::residual_rung::fit_over(
                    model,
                    &result,
                    ids,
                    &data.rows,
                    &options,
                    &measurements.path,
                )?;
                let h = fitted.fitted.hyperparameters();
                outputs.facts.insert(
                    format!("{model}_residual"),
                    format!(
                        "prior σ {:.4} mm, noise σ {:.4} mm, {} rows, {} inducing points",
                        h.signal_variance_mm2.sqrt(),
                        h.noise_variance_mm2.sqrt(),
                        fitted.rows.len(),
                        fitted.fitted.inducing_points()
                    ),
                );
                residual_models.push(fitted);
            }
            let part = residual_frame(model, &result.residuals_mm, &result.weights, ids, &flagged);
            match residuals.as_mut() {
                // Appends the columns' chunks; no copy.
                Some(all) => {
                    all.vstack_mut(&part)
                        .expect("residual frames share one schema");
                }
                None => residuals = Some(part),
            }
            sets.push(result.set);
        }
        if !failures.is_empty() {
            return Err(StageError::Failed(failures.join("\n")));
        }
        outputs.tables.insert(
            "parameters".into(),
            parameters::to_frame(ctx.robot.spec(), &sets),
        );
        outputs
            .tables
            .insert("identification_trace".into(), trace.into_frame());
        let residuals =
            residuals.unwrap_or_else(|| residual_frame(ModelName::Nominal, &[], &[], &[], &[]));
        outputs.tables.insert("residuals".into(), residuals);
        outputs
            .tables
            .insert("covariance".into(), covariance.into_frame());
        outputs
            .tables
            .insert("excluded_rows".into(), excluded.into_frame());
        outputs.tables.insert(
            super::residual_rung::RESIDUAL_OUTPUT.name.into(),
            super::residual_rung::to_frame(&residual_models),
        );
        outputs
            .facts
            .insert("calibration_rows".into(), data.rows.len().to_string());
        if targets.len() > 1 {
            outputs.facts.insert("targets".into(), targets.join(","));
        }
        Ok(outputs)
    }
}

/// The start of the fitted models: `values` with the frames registered in closed
/// form onto the measurements (spec §7) and the registration's RMS residual
/// (mm); `values` themselves, with a note, where the rows cannot determine the
/// frames.
fn register(
    ctx: &StageContext,
    what: &str,
    values: &ParamValues,
    data: &Observations<'_>,
    outputs: &mut StageOutputs,
) -> (ParamValues, Option<f64>) {
    let key = if what == "start" {
        "registration_start"
    } else {
        "registration"
    };
    match registered_start(ctx.robot, values, data) {
        Ok((start, found)) => {
            let fact = format!(
                "frames of the {what} registered in closed form: rms {:.3} mm after {} rounds{}",
                found.rms_mm,
                found.iterations,
                found
                    .orientation_rms_deg
                    .map(|deg| format!("; tool rotation from the orientations: rms {deg:.4} deg"))
                    .unwrap_or_default()
            ) + &found
                .positioner_rms_mm
                .map(|mm| format!("; the positioner's base and nests: rms {mm:.3} mm"))
                .unwrap_or_default();
            ctx.progress.note(&fact);
            outputs.facts.insert(key.into(), fact);
            (start, Some(found.rms_mm))
        }
        Err(e) => {
            let fact = format!("frames of the {what} kept as given: {e}");
            ctx.progress.note(&fact);
            outputs.facts.insert(key.into(), fact);
            (*values, None)
        }
    }
}

/// The first identified parameter no robot could have, if any: a length error
/// (da, dd) or an angle error (dtheta, dalpha, tool rotation) beyond the
/// plausibility bounds, or a compliance significantly below zero. Frames are
/// not bounded: a tracker stands anywhere.
///
/// With 6-D rows the tool rotation is a frame too (a probe's mounting,
/// registered from the measured orientations) and is not bounded either.
fn implausible_parameter(
    set: &crate::table::parameters::ParameterSet,
    nominal: &ParamValues,
    settings: &IdentifySettings,
    tool_rotation_is_a_frame: bool,
) -> Option<String> {
    use crate::robot::params::ParamKind;
    use crate::table::parameters::ParamStatus;
    set.ids()
        .filter(|id| set.status[id.index()] == ParamStatus::Identified)
        .find_map(|id| {
            let value = set.values.get(id);
            let deviation = value - nominal.get(id);
            let std_error = set.std_errors[id.index()].unwrap_or(0.0);
            let beyond = |bound: f64, key: &str, unit: &str| {
                (deviation.abs() > bound).then(|| {
                    format!(
                        "`{}` = {value:.4} {unit} is {deviation:+.4} {unit} from nominal (± {std_error:.4}), beyond the plausible {bound} {unit} (setting `{key}`): a unit, the joint zero or sign, or the robot file is wrong; raise `{key}` only if the robot truly differs that much from its file",
                        set.name_of(id)
                    )
                })
            };
            match id.kind() {
                ParamKind::A(_) | ParamKind::D(_) => {
                    beyond(settings.plausible_length_mm, "plausible_length_mm", "mm")
                }
                ParamKind::ToolRotation(_) if tool_rotation_is_a_frame => None,
                ParamKind::Theta(_) | ParamKind::Alpha(_) | ParamKind::ToolRotation(_) => {
                    beyond(settings.plausible_angle_deg, "plausible_angle_deg", "deg")
                }
                // A positioner's axes are bounded as the arm's; its base is a frame.
                ParamKind::Positioner(term) if term.axis().is_some() => match term.unit() {
                    "mm" => beyond(settings.plausible_length_mm, "plausible_length_mm", "mm"),
                    _ => beyond(settings.plausible_angle_deg, "plausible_angle_deg", "deg"),
                },
                ParamKind::Compliance(_) if value < -3.0 * std_error && value < 0.0 => Some(format!(
                    "`{}` = {value:.3e} deg/(N·m) ± {std_error:.1e}: a negative compliance (the joint would bend against its load); the load columns' sign or frame, or the robot file's masses, are wrong",
                    set.name_of(id)
                )),
                _ => None,
            }
        })
}

/// The row with the smallest σ (cw_id and σ in mm), when the rows have sigmas.
fn smallest_sigma(data: &MeasuredRows) -> Option<(i64, String)> {
    let sigmas = data.sigma_mm.as_ref()?;
    sigmas
        .iter()
        .enumerate()
        .map(|(k, s)| (k, s.min()))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(k, s)| (data.ids[k], crate::calibration::row_checks::compact(s)))
}

/// Checks every row against the robot file's joint limits and for absurd values
/// ([`row_checks`]): fails on the first bad row with `bad_rows = "fail"`, else
/// drops the bad rows, records them, and says how many went (the returned fact).
fn check_rows(
    ctx: &StageContext,
    settings: &IdentifySettings,
    table: &InputTable,
    data: &mut MeasuredRows,
    excluded: &mut ExcludedColumns,
) -> Result<String, StageError> {
    let problems: Vec<Option<String>> = (0..data.rows.len())
        .map(|k| data.row_problem(ctx.robot, k))
        .collect();
    let bad: Vec<usize> = (0..problems.len())
        .filter(|k| problems[*k].is_some())
        .collect();
    if bad.is_empty() {
        return Ok("0".into());
    }
    if settings.bad_rows == BadRowsSetting::Fail {
        let k = bad[0];
        return Err(StageError::Invalid(format!(
            "{}: row {} (cw_id {}): {}; {} bad rows in all (setting `bad_rows = \"drop\"` leaves them out)",
            table.path.display(),
            data.file_rows[k],
            data.ids[k],
            problems[k].as_deref().unwrap_or_default(),
            bad.len()
        )));
    }
    let fraction = bad.len() as f64 / data.rows.len() as f64;
    if fraction > settings.max_excluded_fraction {
        return Err(StageError::Invalid(format!(
            "{}: {} of {} rows fail the row checks (first: row {}, cw_id {}: {}); more than {:.0} % bad rows means the table or the robot file is wrong",
            table.path.display(),
            bad.len(),
            data.rows.len(),
            data.file_rows[bad[0]],
            data.ids[bad[0]],
            problems[bad[0]].as_deref().unwrap_or_default(),
            100.0 * settings.max_excluded_fraction
        )));
    }
    let mut shown = Vec::new();
    for k in &bad {
        let reason = problems[*k].clone().unwrap_or_default();
        if shown.len() < OUTLIERS_LISTED {
            shown.push(format!("cw_id {}: {reason}", data.ids[*k]));
        }
        excluded.push(data.ids[*k], None, "row_check", reason);
    }
    let summary = format!(
        "{} of {} rows of {} dropped by the row checks (setting `bad_rows = \"drop\"`; all listed in the output table `excluded_rows`): {}{}",
        bad.len(),
        data.rows.len(),
        table.path.display(),
        shown.join("; "),
        if bad.len() > shown.len() {
            format!(" and {} more", bad.len() - shown.len())
        } else {
            String::new()
        }
    );
    ctx.progress.note(&format!("warning: {summary}"));
    let wanted: Vec<bool> = problems.iter().map(Option::is_none).collect();
    data.retain(&wanted);
    Ok(summary)
}

/// What the log and the metadata say about one model's fit.
fn model_facts(
    model: ModelName,
    result: &ModelResult,
    ids: &[i64],
    settings: &IdentifySettings,
) -> Vec<(&'static str, String)> {
    let mut facts = Vec::new();
    if let Some(rank) = &result.rank {
        facts.push((
            "identified",
            format!(
                "{} of {} (svd rank {})",
                rank.independent.len(),
                rank.independent.len() + rank.dependent.len(),
                rank.svd_rank
            ),
        ));
    }
    if let Some(diagnostics) = &result.diagnostics {
        facts.push((
            "stop",
            format!(
                "{} after {} steps",
                diagnostics.stop.as_str(),
                result.trace.len()
            ),
        ));
        facts.push((
            "condition_number",
            format!("{:.3e}", diagnostics.condition_number),
        ));
        facts.push((
            "correlations",
            diagnostics
                .correlations
                .iter()
                .map(|(a, b, rho)| {
                    format!(
                        "{}/{}={rho:+.4}",
                        result.set.name_of(*a),
                        result.set.name_of(*b)
                    )
                })
                .collect::<Vec<_>>()
                .join(","),
        ));
    }
    if let Some(summary) = &result.robust {
        let shown = summary
            .excluded
            .iter()
            .take(OUTLIERS_LISTED)
            .map(|k| format!("{}:{:.3}", ids[*k], result.residuals_mm[*k].norm()))
            .collect::<Vec<_>>()
            .join(",");
        let more = summary.excluded.len().saturating_sub(OUTLIERS_LISTED);
        facts.push((
            "robust",
            format!(
                "sigma {:.4} (least squares {:.4}); {} rows excluded beyond {:.4}{}{shown}{}",
                summary.sigma,
                summary.sigma_least_squares,
                summary.excluded.len(),
                summary.threshold,
                if summary.excluded.is_empty() {
                    ""
                } else {
                    " (cw_id:r_mm) "
                },
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
        ));
    } else if model != ModelName::Nominal {
        let threshold_mm = settings.outlier_threshold_mm;
        // Counted over all rows, formatted only for those listed.
        let beyond = || {
            ids.iter()
                .zip(&result.residuals_mm)
                .map(|(id, r)| (*id, r.norm()))
                .filter(|(_, r_mm)| *r_mm > threshold_mm)
        };
        let count = beyond().count();
        let shown = beyond()
            .take(OUTLIERS_LISTED)
            .map(|(id, r_mm)| format!("{id}:{r_mm:.3}"))
            .collect::<Vec<_>>()
            .join(",");
        let more = count.saturating_sub(OUTLIERS_LISTED);
        facts.push((
            "outliers",
            format!(
                "{count} rows beyond {threshold_mm} mm{}{shown}{}",
                if count == 0 { "" } else { " (cw_id:r_mm) " },
                if more > 0 {
                    format!(" and {more} more")
                } else {
                    String::new()
                }
            ),
        ));
    }
    facts
}

/// Outlier rows named in the log and metadata per model (all are in `residuals`).
const OUTLIERS_LISTED: usize = 10;

/// Columns of `identification_trace`.
#[derive(Default)]
struct TraceColumns {
    model: Vec<&'static str>,
    iteration: Vec<i64>,
    rms_mm: Vec<f64>,
    max_mm: Vec<f64>,
    step_mm: Vec<f64>,
    damping: Vec<Option<f64>>,
    accepted: Vec<bool>,
}

impl TraceColumns {
    fn push(&mut self, model: ModelName, result: &ModelResult) {
        for it in &result.trace {
            self.model.push(model.as_str());
            self.iteration.push(it.iteration as i64);
            self.rms_mm.push(it.rms_mm);
            self.max_mm.push(it.max_mm);
            self.step_mm.push(it.step_mm);
            self.damping.push(it.damping);
            self.accepted.push(it.accepted);
        }
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("model".into(), self.model),
            Column::new("iteration".into(), self.iteration),
            Column::new("rms_mm".into(), self.rms_mm),
            Column::new("max_mm".into(), self.max_mm),
            Column::new("step_mm".into(), self.step_mm),
            Column::new("damping".into(), self.damping),
            Column::new("accepted".into(), self.accepted),
        ])
    }
}

/// The `residuals` rows of one model. Built as soon as the model is fitted, with
/// exact sizes, so that a million rows per model cost only the table's own
/// columns (about 64 bytes a row) and no growing buffers.
fn residual_frame(
    model: ModelName,
    residuals_mm: &[Vector3<f64>],
    weights: &[f64],
    ids: &[i64],
    outlier: &[bool],
) -> DataFrame {
    let axis = |a: usize| -> Vec<f64> { residuals_mm.iter().map(|r| r[a]).collect() };
    let norms: Vec<f64> = residuals_mm.iter().map(|r| r.norm()).collect();
    frame(vec![
        Column::new("cw_id".into(), ids),
        Column::new("model".into(), vec![model.as_str(); ids.len()]),
        Column::new("rx_mm".into(), axis(0)),
        Column::new("ry_mm".into(), axis(1)),
        Column::new("rz_mm".into(), axis(2)),
        Column::new("r_mm".into(), norms),
        Column::new("weight".into(), weights),
        Column::new("outlier".into(), outlier),
    ])
}

/// Columns of `covariance`.
#[derive(Default)]
struct CovarianceColumns {
    model: Vec<&'static str>,
    name_i: Vec<String>,
    name_j: Vec<String>,
    value: Vec<f64>,
    variance_factor: Vec<f64>,
}

impl CovarianceColumns {
    fn push(&mut self, model: ModelName, result: &ModelResult) {
        let Some(diagnostics) = &result.diagnostics else {
            return;
        };
        let free = &diagnostics.free;
        let m = free.len();
        for (i, a) in free.iter().enumerate() {
            for (j, b) in free.iter().enumerate() {
                self.model.push(model.as_str());
                self.name_i.push(result.set.name_of(*a));
                self.name_j.push(result.set.name_of(*b));
                self.value.push(diagnostics.covariance[i * m + j]);
                self.variance_factor.push(diagnostics.variance_factor);
            }
        }
    }

    fn into_frame(self) -> DataFrame {
        frame(vec![
            Column::new("model".into(), self.model),
            Column::new("name_i".into(), self.name_i),
            Column::new("name_j".into(), self.name_j),
            Column::new("value".into(), self.value),
            Column::new("variance_factor".into(), self.variance_factor),
        ])
    }
}

/// Columns of `excluded_rows`.
#[derive(Default)]
struct ExcludedColumns {
    cw_id: Vec<i64>,
    model: Vec<Option<&'static str>>,
    check: Vec<&'static str>,
    reason: Vec<String>,
}

impl ExcludedColumns {
    fn push(
        &mut self,
        cw_id: i64,
        model: Option<&'static str>,
        check: &'static str,
        reason: String,
    ) {
        self.cw_id.push(cw_id);
        self.model.push(model);
        self.check.push(check);
        self.reason.push(reason);
    }

    fn into_frame(self) -> DataFrame {
        frame(vec![
            Column::new("cw_id".into(), self.cw_id),
            Column::new("model".into(), self.model),
            Column::new("check".into(), self.check),
            Column::new("reason".into(), self.reason),
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::irb1600;

    /// The orientation convention of 6-D rows (spec §8: Rot(x, rx)·Rot(y,
    /// ry)·Rot(z, rz), scipy's intrinsic "XYZ") and the rotation residual
    /// (scipy's `(R_meas * R_model.inv()).as_rotvec()`), against the numbers of
    /// fixtures/tools/orientation_fixtures.py (pasted); the weights the fit
    /// gives the rows, with and without σ columns.
    #[test]
    #[allow(clippy::excessive_precision)]
    fn orientation_convention_and_residual_match_scipy() {
        use crate::calibration::fit::orientation_residual_deg;
        let measured = Vector3::new(-90.179563, -20.112975, -90.157388);
        let model = Vector3::new(-90.1, -20.25, -89.9);
        let rows = MeasuredRows {
            orientation_deg: Some(vec![measured, model]),
            ..Default::default()
        };
        let rotations = rows.measured_rotations().unwrap();
        let scipy = nalgebra::Matrix3::new(
            -0.002579417353162,
            0.939012861301302,
            -0.343872349741674,
            0.002189358136570,
            0.343877972450392,
            0.939011792670549,
            0.999994276642156,
            0.001669243585990,
            -0.002942840257742,
        );
        assert!((rotations[0] - scipy).norm() < 1e-14, "{}", rotations[0]);
        let residual = orientation_residual_deg(&rotations[0], &rotations[1]);
        let scipy = Vector3::new(0.009234737164374, -0.241919152077053, -0.136434965174114);
        assert!((residual - scipy).norm() < 1e-12, "{residual}");
        assert!((residual.norm() - 0.277893246111231).abs() < 1e-12);
        // A hand case: 10° more about z is the residual (0, 0, 10).
        let turned = MeasuredRows {
            orientation_deg: Some(vec![Vector3::new(0.0, 0.0, 10.0), Vector3::zeros()]),
            ..Default::default()
        }
        .measured_rotations()
        .unwrap();
        let r = orientation_residual_deg(&turned[0], &turned[1]);
        assert!((r - Vector3::new(0.0, 0.0, 10.0)).norm() < 1e-13, "{r}");

        // Weights: the lever arm's radian per degree without σ (1 mm positions),
        // σ_position/lever with position σ, 1/σ_rms with orientation σ.
        let weights = |rows: &MeasuredRows| -> Vec<f64> {
            rows.orientations_for_fit(100.0)
                .unwrap()
                .iter()
                .map(|o| o.unwrap().scale_per_deg)
                .collect()
        };
        let mut rows = rows;
        let lever = 100.0_f64.to_radians();
        assert_eq!(weights(&rows), [lever, lever]);
        rows.sigma_mm = Some(vec![Vector3::repeat(0.02), Vector3::new(0.01, 0.02, 0.02)]);
        let w = weights(&rows);
        assert!(
            (w[0] - lever / 0.02).abs() < 1e-9 && (w[1] - lever / 0.3e-3f64.sqrt()).abs() < 1e-9
        );
        rows.sigma_orientation_deg = Some(vec![
            Vector3::repeat(0.004),
            Vector3::new(0.001, 0.002, 0.002),
        ]);
        let w = weights(&rows);
        assert!(
            (w[0] - 250.0).abs() < 1e-9 && (w[1] - 1.0 / 3e-6f64.sqrt()).abs() < 1e-9,
            "{w:?}"
        );
    }

    #[test]
    fn fixed_values_take_numbers_or_nominal_and_name_bad_keys() {
        let nominal = ParamValues::nominal(irb1600().spec());
        let mut settings = IdentifySettings::default();
        settings
            .fixed
            .insert("k6".into(), FixedValue::Named("nominal".into()));
        settings.fixed.insert("dd5".into(), FixedValue::Value(0.1));
        let fixed = settings.fixed_values(&nominal).unwrap();
        assert!(fixed.contains(&(ParamId::from_name("k6").unwrap(), 0.0)));
        assert!(fixed.contains(&(ParamId::from_name("dd5").unwrap(), 0.1)));

        settings.fixed.insert("dd55".into(), FixedValue::Value(0.1));
        settings
            .fixed
            .insert("k2".into(), FixedValue::Named("zero".into()));
        let problems = settings.fixed_values(&nominal).unwrap_err();
        assert_eq!(problems.len(), 2, "{problems:?}");
        assert_eq!(problems[0].key, "fixed.dd55");
        assert!(problems[0].message.contains("dd5"), "{problems:?}");
        assert_eq!(problems[1].key, "fixed.k2");
        assert!(problems[1].message.contains("\"nominal\""), "{problems:?}");
    }

    #[test]
    fn settings_out_of_range_or_inconsistent_are_named() {
        use crate::stages::StageKind;
        for (toml, key) in [
            ("reject_sigmas = 1.0", "reject_sigmas"),
            ("huber_sigmas = nan", "huber_sigmas"),
            ("max_excluded_fraction = 0.7", "max_excluded_fraction"),
            ("outlier_threshold_mm = 0.0", "outlier_threshold_mm"),
        ] {
            let raw: toml::Table = toml::from_str(toml).unwrap();
            let problems = IdentifyStage.canonical_settings(&raw).unwrap_err();
            assert_eq!(problems[0].key, key, "{problems:?}");
        }
        let robot = irb1600();
        let ctx = SettingsContext {
            robot: robot.spec(),
            cable_robot: &crate::cdpr::CableRobotSpec::default(),
            job_dir: std::path::Path::new("."),
            bound_inputs: &["measurements"],
        };
        let crossed = IdentifySettings {
            huber_sigmas: 5.0,
            reject_sigmas: 3.0,
            ..Default::default()
        };
        let problems = Stage::check_settings(&IdentifyStage, &crossed, &ctx);
        assert_eq!(problems[0].key, "huber_sigmas", "{problems:?}");
        let reregistered = IdentifySettings {
            models: vec!["nominal".into(), "reregistered".into()],
            ..Default::default()
        };
        let problems = Stage::check_settings(&IdentifyStage, &reregistered, &ctx);
        assert_eq!(problems[0].key, "models[1]", "{problems:?}");
        assert!(
            problems[0].message.contains("input `start`"),
            "{problems:?}"
        );
        let least_squares = IdentifySettings {
            loss: LossSetting::LeastSquares,
            ..Default::default()
        };
        assert_eq!(least_squares.robust_options(), None);
    }
}
