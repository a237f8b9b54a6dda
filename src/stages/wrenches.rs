//! `wrenches`: K wrenches per configuration inside the cable robot's
//! wrench-feasible set (paper §IV.A step (c)): forces and moments drawn from
//! normal distributions, clipped to the paper's ranges, kept only when tensions
//! within bounds exist that produce them (decided by the cable robot's QP), redrawn
//! otherwise up to a limit.
//!
//! Cost: one Clarabel QP per draw that is not clearly outside the wrench set (a
//! few hundred µs); the pose-dependent facets are built once per configuration
//! and configurations run in parallel.

use std::sync::atomic::{AtomicU64, Ordering};

use polars::prelude::Column;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot, budget};
use crate::cdpr::{AvailableWrenchSet, Feasibility};
use crate::robot::{MAX_JOINTS, ParamValues};
use crate::table::frame;
use crate::table::schema::{self, TENSION_COLUMNS, WRENCH_COLUMNS, i64_values};

pub struct WrenchesStage;

/// What one configuration's draws produced.
#[derive(Default)]
struct ConfigWrenches {
    q_deg: [f64; MAX_JOINTS],
    /// Feasible wrenches in draw order, with their verdicts.
    kept: Vec<([f64; 6], Feasibility)>,
    attempts: usize,
}

/// Settings of `wrenches`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct WrenchesSettings {
    /// Wrenches per configuration.
    #[schemars(range(min = 1, max = 10_000))]
    pub per_config: usize,
    /// Standard deviation of each force component (N).
    #[schemars(range(min = 0.0, max = 100_000.0))]
    pub sigma_force_n: f64,
    /// Standard deviation of each moment component (N·m).
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub sigma_moment_nm: f64,
    /// Forces are clipped to ±this (N).
    #[schemars(range(min = 0.0, max = 100_000.0))]
    pub max_force_n: f64,
    /// Moments are clipped to ±this (N·m).
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub max_moment_nm: f64,
    /// Draws per wanted wrench before the configuration is reported short.
    #[schemars(range(min = 1, max = 1_000_000))]
    pub max_draws: usize,
}

impl Default for WrenchesSettings {
    fn default() -> Self {
        WrenchesSettings {
            per_config: 7,
            // "Normally distributed in the range of −120 N to 120 N and −10 Nm to 10 Nm"
            // (paper §IV.A): the range read as ±3σ.
            sigma_force_n: 40.0,
            sigma_moment_nm: 10.0 / 3.0,
            max_force_n: 120.0,
            max_moment_nm: 10.0,
            max_draws: 50,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "wrenches",
    uses_cable_robot: true,
    updates_input: None,
    summary: "Feasible cable-robot wrenches per configuration: the conf-wrench candidates",
    code_version: 5,
    inputs: &[TableSlot {
        name: "poses",
        schema: schema::poses,
        required: true,
        meaning: "configurations (config_id, q1_deg..q6_deg)",
    }],
    outputs: &[TableSlot {
        name: "candidates",
        schema: schema::candidates,
        required: true,
        meaning: "cw_id, config_id, q, wrench, cable tensions, capacity margin",
    }],
};

/// Bytes a wanted wrench may cost: its output row (23 columns of 8 bytes) and
/// the kept wrench with its feasibility while configurations run, rounded up.
const BYTES_PER_ROW: f64 = 512.0;

/// Wanted wrenches from which a run is announced as long.
const LONG_RUN_ROWS: f64 = 1e6;

impl Stage for WrenchesStage {
    type Settings = WrenchesSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &WrenchesSettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("poses")?;
        let config_ids = i64_values(&input.df, "config_id", &input.path)?;
        let joints = schema::joint_vectors(&input.df, &input.path, ctx.robot.spec())?;
        // The carriage rides with the cable robot (both in the base frame):
        // each configuration's position passes through to its wrenches.
        let positions = super::track_positions(&input.df, &input.path, ctx.robot.spec())?;
        let track_mm = ctx.robot.spec().track.is_some().then_some(positions);
        let force = Normal::new(0.0, settings.sigma_force_n)
            .map_err(|e| StageError::Invalid(format!("setting `sigma_force_n`: {e}")))?;
        let moment = Normal::new(0.0, settings.sigma_moment_nm)
            .map_err(|e| StageError::Invalid(format!("setting `sigma_moment_nm`: {e}")))?;
        let nominal = ParamValues::nominal(ctx.robot.spec());
        let wanted = settings.per_config;
        // The row count is known only now (the poses input's): checked before the
        // wrench sets are built, and announced when long.
        let rows = config_ids.len() as f64 * wanted as f64;
        if let Some(why) = budget::over_budget(
            rows * BYTES_PER_ROW,
            &format!(
                "{} configurations × per_config = {wanted} wrenches",
                config_ids.len()
            ),
        ) {
            return Err(StageError::Invalid(format!(
                "setting `per_config`: {why}; lower `per_config` or use fewer poses"
            )));
        }
        if rows >= LONG_RUN_ROWS {
            ctx.progress.note(&format!(
                "{rows:.0} wrenches wanted ({} configurations × {wanted}), each a feasibility QP: this takes a while",
                config_ids.len()
            ));
        }
        let max_attempts = settings.max_draws * wanted;
        let draw = |rng: &mut StdRng| -> [f64; 6] {
            std::array::from_fn(|i| {
                if i < 3 {
                    force
                        .sample(rng)
                        .clamp(-settings.max_force_n, settings.max_force_n)
                } else {
                    moment
                        .sample(rng)
                        .clamp(-settings.max_moment_nm, settings.max_moment_nm)
                }
            })
        };
        ctx.progress
            .start(config_ids.len() as u64, "configurations");
        let done = AtomicU64::new(0);
        // Configurations run in parallel, each with its own seeded stream (so the
        // result does not depend on scheduling) and its wrench set built once.
        let per_config: Vec<ConfigWrenches> = (0..config_ids.len())
            .into_par_iter()
            .map(|k| {
                let config_id = config_ids[k];
                let q_deg = joints[k];
                let (_, tool) = ctx.robot.frames_in_base(&nominal, &q_deg);
                let failed = |e| StageError::Failed(format!("config_id {config_id}: {e}"));
                let set = AvailableWrenchSet::new(ctx.cable_robot, &tool).map_err(failed)?;
                let mut rng = StdRng::seed_from_u64(
                    ctx.seed ^ (k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
                );
                let mut found = ConfigWrenches {
                    q_deg,
                    ..ConfigWrenches::default()
                };
                while found.kept.len() < wanted && found.attempts < max_attempts {
                    found.attempts += 1;
                    let wrench = draw(&mut rng);
                    let feasibility = set.check(wrench).map_err(failed)?;
                    if feasibility.feasible {
                        found.kept.push((wrench, feasibility));
                    }
                }
                ctx.progress
                    .advance(done.fetch_add(1, Ordering::Relaxed) + 1);
                Ok(found)
            })
            .collect::<Result<_, StageError>>()?;

        let mut cw_id = Vec::new();
        let mut config = Vec::new();
        let mut q: Vec<Vec<f64>> = vec![Vec::new(); MAX_JOINTS];
        let mut w: Vec<Vec<f64>> = vec![Vec::new(); 6];
        let mut tensions: Vec<Vec<f64>> = vec![Vec::new(); TENSION_COLUMNS.len()];
        let mut margin = Vec::new();
        let mut track_of_row = Vec::new();
        let (mut draws, mut short_configs) = (0usize, 0usize);
        for (k, (found, &config_id)) in per_config.iter().zip(&config_ids).enumerate() {
            draws += found.attempts;
            for (n, (wrench, feasibility)) in found.kept.iter().enumerate() {
                cw_id.push((k * wanted + n + 1) as i64);
                config.push(config_id);
                for (column, value) in q.iter_mut().zip(found.q_deg) {
                    column.push(value);
                }
                for (column, value) in w.iter_mut().zip(wrench) {
                    column.push(*value);
                }
                for (column, value) in tensions.iter_mut().zip(feasibility.tensions_n) {
                    column.push(value);
                }
                margin.push(feasibility.capacity_margin_n);
                if let Some(track_mm) = &track_mm {
                    track_of_row.push(track_mm[k]);
                }
            }
            if found.kept.len() < wanted {
                short_configs += 1;
                ctx.progress.note(&format!(
                    "config_id {config_id}: only {} of {wanted} feasible wrenches after {} draws",
                    found.kept.len(),
                    found.attempts
                ));
            }
        }
        let kept = cw_id.len();
        let mut columns = vec![Column::new("cw_id".into(), cw_id)];
        for (name, values) in schema::joint_column_names(ctx.robot.spec()).iter().zip(q) {
            columns.push(Column::new((*name).into(), values));
        }
        for (name, values) in WRENCH_COLUMNS.iter().zip(w) {
            columns.push(Column::new((*name).into(), values));
        }
        columns.push(Column::new("config_id".into(), config));
        for (name, values) in TENSION_COLUMNS.iter().zip(tensions) {
            columns.push(Column::new((*name).into(), values));
        }
        columns.push(Column::new("margin_n".into(), margin));
        if track_mm.is_some() {
            columns.push(Column::new(schema::TRACK_COLUMN.into(), track_of_row));
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert("candidates".into(), frame(columns));
        outputs.facts.insert("candidates".into(), kept.to_string());
        outputs.facts.insert("draws".into(), draws.to_string());
        outputs.facts.insert(
            "rejection_rate".into(),
            format!("{:.3}", 1.0 - kept as f64 / draws.max(1) as f64),
        );
        outputs
            .facts
            .insert("short_configs".into(), short_configs.to_string());
        Ok(outputs)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::path::{Path, PathBuf};

    use super::*;
    use crate::cdpr::CableRobotSpec;
    use crate::robot::test_support::irb1600;
    use crate::stages::{InputTable, NoProgress, StageKind};

    /// `configs` poses, all at the zero configuration.
    fn poses(configs: usize) -> InputTable {
        let mut columns = vec![Column::new(
            "config_id".into(),
            (1..=configs as i64).collect::<Vec<_>>(),
        )];
        for name in schema::JOINT_COLUMNS {
            columns.push(Column::new(name.into(), vec![0.0; configs]));
        }
        InputTable {
            path: PathBuf::from("poses.parquet"),
            df: frame(columns),
        }
    }

    #[test]
    fn too_many_wrenches_for_memory_are_refused_before_any_is_drawn() {
        let robot = irb1600();
        let cable_robot = CableRobotSpec::default();
        let inputs = BTreeMap::from([("poses".to_string(), poses(1_000_000))]);
        let ctx = StageContext {
            robot: &robot,
            cable_robot: &cable_robot,
            seed: 1,
            inputs: &inputs,
            work_dir: Path::new("."),
            job_dir: Path::new("."),
            run_date: 0,
            progress: &NoProgress,
        };
        let canonical = WrenchesStage
            .canonical_settings(&toml::from_str("per_config = 10000").unwrap())
            .unwrap();
        // 10^10 wanted wrenches: refused at once, naming the setting and the sizes.
        let err = StageKind::run(&WrenchesStage, &ctx, &canonical)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("setting `per_config`: 1000000 configurations × per_config = 10000 wrenches need about"),
            "{err}"
        );
    }
}
