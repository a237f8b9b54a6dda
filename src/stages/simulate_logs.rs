//! `simulate_logs`: a robot cell's daily check logs, written by the simulator, so
//! the nightly re-calibration (`jobs/nightly.toml`) has real input without a cell.
//!
//! Each day the simulated robot measures `rows_per_day` conf-wrench rows drawn from
//! the input pool, and the rows are written as the cell would log them: one
//! Parquet file per robot and day under `robot_id=<id>/date=<YYYY-MM-DD>/`. The
//! robot's true parameters move over the days, as real robots do: a slow drift per
//! day (thermal growth of a link) and steps on given dates (a joint offset after a
//! collision). A `commissioning` table holds the whole pool measured the day before
//! the logs start, on the undrifted robot: the data of the calibration put in
//! service first.
//!
//! On a linear track the carriage moves to each row's `e1_mm` and the logs
//! carry the position read back. The daily check is the arm's: a pool row
//! measuring a positioner's nest is refused.

use std::collections::BTreeMap;

use polars::prelude::ParquetWriter;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::measure::{Reading, measure_row, measurements_frame};
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, model_name_problem, settings_error,
};
use crate::rig::Rig;
use crate::rig::simulator::{Simulator, SimulatorSettings};
use crate::robot::{ConfWrench, ParamId, ParamValues};
use crate::table::schema;
use crate::table::time::{date_string, parse_date};

pub struct SimulateLogsStage;

/// A parameter that changes by the same amount every day.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Drift {
    /// Parameter name (spec §3), e.g. `da2`.
    pub parameter: String,
    /// Change per day, in the parameter's unit (mm, deg, rad/(N·m)).
    #[schemars(range(min = -10_000.0, max = 10_000.0))]
    pub per_day: f64,
}

/// A parameter that changes at once on a date and stays changed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Step {
    pub parameter: String,
    /// First day with the change, `YYYY-MM-DD`.
    pub date: String,
    /// Change in the parameter's unit.
    #[schemars(range(min = -10_000.0, max = 10_000.0))]
    pub change: f64,
}

/// Settings of `simulate_logs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SimulateLogsSettings {
    /// The robot whose logs these are (the `robot_id` column and partition).
    pub robot_id: String,
    /// First logged day, `YYYY-MM-DD`. A fixed date keeps the logs reproducible.
    pub first_day: String,
    /// Logged days.
    #[schemars(range(min = 1, max = 36_600))]
    pub days: u32,
    /// Rows measured per day, drawn from the pool without repetition within a day.
    #[schemars(range(min = 1, max = 10_000_000))]
    pub rows_per_day: usize,
    /// Hour of the day (UTC) the daily check starts.
    #[schemars(range(min = 0.0))]
    #[schemars(extend("exclusiveMaximum" = 24.0))]
    pub start_hour_utc: f64,
    /// Seconds between rows of a day's check.
    #[schemars(range(max = 86_400.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub seconds_per_row: f64,
    /// Model of the `truth` input the robot starts from.
    pub truth_model: String,
    /// This robot's own differences from the truth table (parameter name → change
    /// in its unit): two robots of a cell are not the same individual.
    #[schemars(transform = parameter_change_range)]
    pub offsets: BTreeMap<String, f64>,
    pub drifts: Vec<Drift>,
    pub steps: Vec<Step>,
    /// Noise and unmodelled errors of the rig.
    pub simulator: SimulatorSettings,
}

/// The range of a map of parameter changes (`offsets`): a range attribute applies
/// to numbers, not to a map's values, so it is set on `additionalProperties` here.
/// The bound matches `Drift::per_day` and `Step::change`: ±10 000 of any
/// parameter's unit (mm, deg, rad/(N·m)) can only be a typing mistake.
fn parameter_change_range(schema: &mut schemars::Schema) {
    if let Some(serde_json::Value::Object(values)) = schema.get_mut("additionalProperties") {
        values.insert("minimum".into(), (-10_000.0).into());
        values.insert("maximum".into(), 10_000.0.into());
    }
}

impl Default for SimulateLogsSettings {
    fn default() -> Self {
        SimulateLogsSettings {
            robot_id: String::new(),
            first_day: String::new(),
            days: 30,
            rows_per_day: 50,
            start_hour_utc: 2.0,
            seconds_per_row: 30.0,
            truth_model: "elastogeometric".into(),
            offsets: BTreeMap::new(),
            drifts: Vec::new(),
            steps: Vec::new(),
            simulator: SimulatorSettings::default(),
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "simulate_logs",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Daily check logs of a simulated robot whose parameters drift, as Hive-partitioned Parquet",
    code_version: 3,
    inputs: &[
        TableSlot {
            name: "conf_wrenches",
            schema: schema::conf_wrenches,
            required: true,
            meaning: "the pool of check rows (cw_id, q1_deg..q6_deg, commanded wrench)",
        },
        TableSlot {
            name: "truth",
            schema: schema::parameters,
            required: false,
            meaning: "the robot's true parameters before any drift (nominal when absent)",
        },
    ],
    outputs: &[TableSlot {
        name: "commissioning",
        schema: schema::measurements,
        required: true,
        meaning: "the whole pool measured the day before the logs start, undrifted",
    }],
};

/// Day ids are `day number · ROWS_PER_DAY_LIMIT + row`, unique over a robot's logs.
const ROWS_PER_DAY_LIMIT: usize = 10_000;
/// Attempts per row when the simulated tracker loses the beam.
const ATTEMPTS: u32 = 5;

/// A parameter change over time, resolved against the parameter list.
enum Change {
    Drift {
        id: ParamId,
        per_day: f64,
    },
    Step {
        id: ParamId,
        from_day: i64,
        change: f64,
    },
}

impl SimulateLogsSettings {
    fn first_day(&self) -> Result<i64, SettingsProblem> {
        parse_date(&self.first_day).ok_or_else(|| {
            SettingsProblem::new(
                "first_day",
                format!("expected a date YYYY-MM-DD, found `{}`", self.first_day),
            )
        })
    }

    /// The drifts and steps resolved against the parameter list, or every bad
    /// parameter name and date.
    fn changes(&self) -> Result<Vec<Change>, Vec<SettingsProblem>> {
        let mut changes = Vec::new();
        let mut problems = Vec::new();
        for (k, drift) in self.drifts.iter().enumerate() {
            match parameter(&format!("drifts[{k}].parameter"), &drift.parameter) {
                Ok(id) => changes.push(Change::Drift {
                    id,
                    per_day: drift.per_day,
                }),
                Err(p) => problems.push(p),
            }
        }
        for (k, step) in self.steps.iter().enumerate() {
            let id = parameter(&format!("steps[{k}].parameter"), &step.parameter);
            let from_day = parse_date(&step.date).ok_or_else(|| {
                SettingsProblem::new(
                    &format!("steps[{k}].date"),
                    format!("expected a date YYYY-MM-DD, found `{}`", step.date),
                )
            });
            match (id, from_day) {
                (Ok(id), Ok(from_day)) => changes.push(Change::Step {
                    id,
                    from_day,
                    change: step.change,
                }),
                (id, from_day) => problems.extend(id.err().into_iter().chain(from_day.err())),
            }
        }
        if problems.is_empty() {
            Ok(changes)
        } else {
            Err(problems)
        }
    }

    /// This robot's offsets from the truth, resolved against the parameter list.
    fn offsets(&self) -> Result<Vec<(ParamId, f64)>, Vec<SettingsProblem>> {
        let (ok, bad): (Vec<_>, Vec<_>) = self
            .offsets
            .iter()
            .map(|(name, change)| {
                parameter(&format!("offsets.{name}"), name).map(|id| (id, *change))
            })
            .partition(Result::is_ok);
        if bad.is_empty() {
            Ok(ok.into_iter().filter_map(Result::ok).collect())
        } else {
            Err(bad.into_iter().filter_map(Result::err).collect())
        }
    }
}

fn parameter(key: &str, name: &str) -> Result<ParamId, SettingsProblem> {
    ParamId::from_name(name).ok_or_else(|| {
        SettingsProblem::new(
            key,
            format!(
                "unknown parameter `{name}`{}",
                crate::suggest::did_you_mean(name, ParamId::all().map(|p| p.name()))
            ),
        )
    })
}

/// The robot's true parameters on `day`, `days_in` days after the first logged day.
fn truth_on(base: &ParamValues, changes: &[Change], day: i64, days_in: i64) -> ParamValues {
    let mut values = *base;
    for change in changes {
        match *change {
            Change::Drift { id, per_day } => {
                values.set(id, values.get(id) + per_day * days_in as f64);
            }
            Change::Step {
                id,
                from_day,
                change,
            } if day >= from_day => values.set(id, values.get(id) + change),
            Change::Step { .. } => {}
        }
    }
    values
}

impl Stage for SimulateLogsStage {
    type Settings = SimulateLogsSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &SimulateLogsSettings,
        _: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems = Vec::new();
        if settings.robot_id.is_empty() || settings.robot_id.contains(['/', '\\', '=']) {
            problems.push(SettingsProblem::new(
                "robot_id",
                format!(
                    "expected a name without `/`, `\\` or `=`, found `{}`",
                    settings.robot_id
                ),
            ));
        }
        problems.extend(settings.first_day().err());
        problems.extend(settings.changes().err().into_iter().flatten());
        problems.extend(settings.offsets().err().into_iter().flatten());
        problems.extend(model_name_problem("truth_model", &settings.truth_model));
        let check_seconds = settings.start_hour_utc * 3600.0
            + settings.rows_per_day as f64 * settings.seconds_per_row;
        if check_seconds >= 86_400.0 {
            problems.push(SettingsProblem::new(
                "rows_per_day",
                format!(
                    "`start_hour_utc` = {} h and `rows_per_day` × `seconds_per_row` = {} × {} s: the daily check must end within its day",
                    settings.start_hour_utc, settings.rows_per_day, settings.seconds_per_row
                ),
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &SimulateLogsSettings,
    ) -> Result<StageOutputs, StageError> {
        let invalid = |m: String| StageError::Invalid(m);
        super::refuse_prismatic_joints(
            ctx.robot.spec(),
            "simulate_logs (the logged measurements' `q1_deg … q6_deg`)",
            "simulate a gantry's campaign with a measure stage",
        )?;
        let first_day = settings.first_day().map_err(|p| settings_error(&[p]))?;
        let changes = settings.changes().map_err(|p| settings_error(&p))?;
        let input = ctx.input("conf_wrenches")?;
        let (pool_ids, pool) = super::commanded_rows(ctx, input)?;
        if let Some(row) = pool.iter().position(|r| r.positioner_deg.is_some()) {
            return Err(invalid(format!(
                "{}: row {row} (cw_id {}) measures a nest on the positioner's table; the simulated daily check measures the arm's SMR only: leave the nests' rows out of the pool",
                input.path.display(),
                pool_ids[row]
            )));
        }
        let day_limit = ROWS_PER_DAY_LIMIT.min(pool.len());
        if settings.rows_per_day == 0 || settings.rows_per_day > day_limit {
            return Err(invalid(format!(
                "setting `rows_per_day`: expected 1 to {day_limit} (the pool has {} rows), found {}",
                pool.len(),
                settings.rows_per_day
            )));
        }
        let mut base = super::model_values(ctx, "truth", "truth_model", &settings.truth_model)?;
        for (id, change) in settings.offsets().map_err(|p| settings_error(&p))? {
            base.set(id, base.get(id) + change);
        }

        let mut outputs = StageOutputs::default();
        let day_rows = |day: i64, truth: ParamValues, rows: &[usize]| {
            self.day(ctx, settings, day, truth, &pool, rows)
        };
        let commissioning_day = first_day - 1;
        let all: Vec<usize> = (0..pool.len()).collect();
        let readings = day_rows(commissioning_day, base, &all)?;
        let with_pool_ids: Vec<(&Reading, Option<i64>)> = readings
            .iter()
            .zip(&all)
            .map(|(r, &k)| (r, Some(pool_ids[k])))
            .collect();
        outputs.tables.insert(
            "commissioning".into(),
            measurements_frame(
                &with_pool_ids,
                &schema::JOINT_COLUMNS,
                true,
                Some(&settings.robot_id),
            ),
        );

        ctx.progress.start(u64::from(settings.days), "days");
        for days_in in 0..i64::from(settings.days) {
            let day = first_day + days_in;
            let mut order = all.clone();
            order.shuffle(&mut StdRng::seed_from_u64(ctx.seed ^ day as u64));
            order.truncate(settings.rows_per_day);
            let truth = truth_on(&base, &changes, day, days_in);
            let readings = day_rows(day, truth, &order)?;
            let rows: Vec<(&Reading, Option<i64>)> = readings
                .iter()
                .zip(&order)
                .map(|(r, &k)| (r, Some(pool_ids[k])))
                .collect();
            let mut df = measurements_frame(
                &rows,
                &schema::JOINT_COLUMNS,
                true,
                Some(&settings.robot_id),
            );
            let mut bytes = Vec::new();
            ParquetWriter::new(&mut bytes)
                .finish(&mut df)
                .map_err(|e| StageError::Failed(format!("writing the log of {day}: {e}")))?;
            outputs.files.insert(
                format!(
                    "robot_id={}/date={}/part-0.parquet",
                    settings.robot_id,
                    date_string(day)
                ),
                bytes,
            );
            ctx.progress.advance(days_in as u64 + 1);
        }
        outputs.facts.insert(
            "logged".into(),
            format!(
                "{} days from {} x {} rows",
                settings.days, settings.first_day, settings.rows_per_day
            ),
        );
        Ok(outputs)
    }
}

impl SimulateLogsStage {
    /// The readings of pool rows `rows` on `day`, by a simulator of `truth` seeded
    /// by the day, timed from the day's check start.
    fn day(
        &self,
        ctx: &StageContext,
        settings: &SimulateLogsSettings,
        day: i64,
        truth: ParamValues,
        pool: &[ConfWrench],
        rows: &[usize],
    ) -> Result<Vec<Reading>, StageError> {
        let simulator = SimulatorSettings {
            clock_start: format!("{}T00:00:00Z", date_string(day)),
            seconds_per_row: settings.seconds_per_row,
            ..settings.simulator.clone()
        };
        let mut rig = Simulator::new(
            ctx.robot.clone(),
            truth,
            simulator,
            ctx.seed ^ (day as u64).rotate_left(32),
        )
        .map_err(StageError::Invalid)?;
        let start_us = (settings.start_hour_utc * 3600e6) as i64;
        let on_track = ctx.robot.spec().track.is_some();
        let mut readings = Vec::with_capacity(rows.len());
        for (k, &row) in rows.iter().enumerate() {
            let cw_id = day * ROWS_PER_DAY_LIMIT as i64 + k as i64;
            let mut attempts = 0;
            let mut reading = loop {
                attempts += 1;
                let moved = match on_track {
                    true => rig.move_track(cw_id, pool[row].track_mm),
                    false => Ok(()),
                };
                match moved.and_then(|()| {
                    measure_row(
                        &mut rig,
                        cw_id,
                        &pool[row],
                        on_track,
                        ctx.robot.joint_count(),
                    )
                }) {
                    Ok(reading) => break reading,
                    Err(e) if e.is_transient() && attempts < ATTEMPTS => {
                        rig.release_wrench()
                            .map_err(|e| StageError::Failed(e.to_string()))?;
                    }
                    Err(e) => {
                        return Err(StageError::Failed(format!(
                            "{} cw_id {cw_id}: {e}",
                            date_string(day)
                        )));
                    }
                }
            };
            reading.measured_at_us = day * 86_400_000_000
                + start_us
                + (k as f64 * settings.seconds_per_row * 1e6) as i64;
            readings.push(reading);
        }
        Ok(readings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, truth_params};

    #[test]
    fn drift_grows_daily_and_steps_hold_from_their_date() {
        let robot = irb1600();
        let base = truth_params(&robot);
        let a2 = ParamId::from_name("da2").unwrap();
        let theta2 = ParamId::from_name("dtheta2").unwrap();
        let step_day = parse_date("2026-11-10").unwrap();
        let changes = [
            Change::Drift {
                id: a2,
                per_day: 0.01,
            },
            Change::Step {
                id: theta2,
                from_day: step_day,
                change: 0.05,
            },
        ];
        let before = truth_on(&base, &changes, step_day - 1, 9);
        let on = truth_on(&base, &changes, step_day, 10);
        assert!((before.get(a2) - base.get(a2) - 0.09).abs() < 1e-12);
        assert!((on.get(a2) - base.get(a2) - 0.10).abs() < 1e-12);
        assert_eq!(before.get(theta2), base.get(theta2));
        assert!((on.get(theta2) - base.get(theta2) - 0.05).abs() < 1e-12);
    }
}
