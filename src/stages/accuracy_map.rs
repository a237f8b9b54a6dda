//! `accuracy_map`: the predicted 95 % position uncertainty over a grid of the
//! workspace the calibration rows covered and a margin beyond it (issue #16),
//! so a user sees where the calibration holds and where it extrapolates. The
//! maths (grid, configurations, `u95`) is [`crate::calibration::accuracy_map`];
//! this file reads the calibration rows as `identify` takes them (the
//! `measurements`, restricted to a `selection`'s calibration rows when one is
//! bound), the model and its covariance, and writes the tables.

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::identify::ids_with_role;
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, bound_covariance, conf_wrench_rows, covariance_columns, model_name_problem,
    model_set,
};
use crate::calibration::accuracy_map::{self, GridSpec, MapPoint, PointStatus};
use crate::robot::params::ParamKind;
use crate::robot::{ConfWrench, ParamId, ParamValues, Wrench, batch_predict};
use crate::table::frame;
use crate::table::parameters::ModelName;
use crate::table::schema::{self, POSITION_COLUMNS};

pub struct AccuracyMapStage;

/// Settings of `accuracy_map`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct AccuracyMapSettings {
    /// Which model of the `parameters` input (and of `covariance`) to map:
    /// registered, kinematic, elastogeometric or reregistered.
    pub model: String,
    /// Grid points along world x and along world y in each slice.
    #[schemars(range(min = 2, max = 200))]
    pub points_per_axis: usize,
    /// Horizontal slices (world z levels) from the bottom to the top of the
    /// enlarged box; one slice lies at mid height.
    #[schemars(range(min = 1, max = 20))]
    pub slices: usize,
    /// How far (mm) the grid extends beyond the calibration rows' bounding box
    /// on every side, so that extrapolation shows.
    #[schemars(range(min = 0.0, max = 5000.0))]
    pub margin_mm: f64,
    /// Which target's tool the grid is for, with a several-target calibration
    /// (spec §7: one tool translation per SMR); empty for a one-target one.
    pub target: String,
}

impl Default for AccuracyMapSettings {
    fn default() -> Self {
        AccuracyMapSettings {
            model: ModelName::Elastogeometric.as_str().to_string(),
            points_per_axis: 15,
            slices: 3,
            margin_mm: 200.0,
            target: String::new(),
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "accuracy_map",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Predicted 95 % position uncertainty (J·Σ·Jᵀ) over a grid around the calibration rows, for the report's accuracy map",
    code_version: 6,
    inputs: &[
        TableSlot {
            name: "parameters",
            schema: schema::parameters,
            required: true,
            meaning: "identified parameter sets (identify); the model of the `model` setting is mapped",
        },
        TableSlot {
            name: "covariance",
            schema: schema::covariance,
            required: true,
            meaning: "identify's parameter covariance of that model",
        },
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: true,
            meaning: "the rows identify was given: their configurations place the grid and its orientations",
        },
        TableSlot {
            name: "selection",
            schema: schema::selection,
            required: false,
            meaning: "rows with role = calibration are the calibration rows; all rows when absent",
        },
        super::residual_rung::RESIDUAL_INPUT,
    ],
    outputs: &[
        TableSlot {
            name: "accuracy_map",
            schema: schema::accuracy_map,
            required: true,
            meaning: "per grid point: position, inside_box, status, configuration, cov_xx_mm2..cov_zz_mm2, u95_mm",
        },
        TableSlot {
            name: "calibration_positions",
            schema: schema::calibration_positions,
            required: true,
            meaning: "the calibration rows' unloaded tool positions the grid was built around",
        },
    ],
};

impl Stage for AccuracyMapStage {
    type Settings = AccuracyMapSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &AccuracyMapSettings,
        _ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems: Vec<SettingsProblem> = model_name_problem("model", &settings.model)
            .into_iter()
            .collect();
        if settings.model == ModelName::Nominal.as_str() {
            problems.push(SettingsProblem::new(
                "model",
                "the nominal model identifies nothing, so it has no covariance to map; choose registered, kinematic, elastogeometric or reregistered",
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &AccuracyMapSettings,
    ) -> Result<StageOutputs, StageError> {
        let set = model_set(ctx, "parameters", "model", &settings.model)?
            .ok_or_else(|| StageError::Invalid("input `parameters` is not bound".into()))?;
        let covariance = bound_covariance(ctx, &set)?.flatten().ok_or_else(|| {
            StageError::Invalid(format!(
                "input `covariance` ({}) has no covariance for model `{}`",
                ctx.input("covariance")
                    .map_or_else(|_| "not bound".into(), |t| t.path.display().to_string()),
                settings.model
            ))
        })?;
        let measurements = ctx.input("measurements")?;
        let (ids, mut rows) = conf_wrench_rows(measurements, ctx.robot.spec())?;
        super::aim_rows(measurements, &set, &mut rows)?;
        if let Some(positioner) = &ctx.robot.spec().positioner
            && positioner.nests.contains(&settings.target)
        {
            return Err(StageError::Invalid(format!(
                "setting `target`: `{}` is a nest on the positioner's table (robot file {}), not a tool of the arm; name the arm's target",
                settings.target,
                ctx.robot.spec().path.display()
            )));
        }
        let (mapped_values, mapped_free) =
            tool_of_target(&set, &covariance.free, &settings.target)?;
        let keep = ctx
            .inputs
            .get("selection")
            .map(|s| ids_with_role(s, "calibration"))
            .transpose()?;
        let (calibration_ids, calibration_rows): (Vec<i64>, Vec<_>) = ids
            .iter()
            .zip(&rows)
            .filter(|(id, _)| keep.as_ref().is_none_or(|k| k.contains(id)))
            // The arm's workspace: a positioner's nest rows were not measured
            // with the arm's SMR.
            .filter(|(_, row)| row.positioner_deg.is_none())
            .map(|(id, row)| (*id, *row))
            .unzip();
        if calibration_rows.is_empty() {
            return Err(StageError::Invalid(format!(
                "{}: no calibration rows (the selection marks none, or the table is empty)",
                measurements.path.display()
            )));
        }
        let spec = GridSpec {
            points_per_axis: settings.points_per_axis,
            slices: settings.slices,
            margin_mm: settings.margin_mm,
        };
        let mut map = accuracy_map::accuracy_map(
            ctx.robot,
            &mapped_values,
            &mapped_free,
            &covariance.matrix,
            &calibration_rows,
            &spec,
        );
        // The eg_residual set's residual variance at each reachable point,
        // unloaded: the prior's far from the calibration rows.
        if let Some(residual) = super::residual_rung::bound_residual(ctx, &set)? {
            let reachable: Vec<usize> = (0..map.len())
                .filter(|k| map[*k].q_deg.is_some() && map[*k].covariance_mm2.is_some())
                .collect();
            let rows: Vec<ConfWrench> = reachable.iter().filter_map(|k| map[*k].row()).collect();
            let extra = super::residual_rung::predict_rows(&residual, &rows)?;
            let mut covariances: Vec<_> =
                reachable.iter().map(|k| map[*k].covariance_mm2).collect();
            super::residual_rung::add_variance(&mut covariances, &extra);
            for (k, c) in reachable.iter().zip(covariances) {
                map[*k].covariance_mm2 = c;
            }
        }
        let mut outputs = StageOutputs::default();
        let on_track = ctx.robot.spec().track.is_some();
        outputs.tables.insert(
            "accuracy_map".into(),
            map_frame(&map, ctx.robot.spec(), on_track),
        );
        // Each calibration row's own SMR, unloaded.
        let unloaded: Vec<ConfWrench> = calibration_rows
            .iter()
            .map(|r| ConfWrench {
                target: r.target,
                track_mm: r.track_mm,
                ..ConfWrench::new(r.q_deg, Wrench::zero())
            })
            .collect();
        let positions: Vec<_> = batch_predict(ctx.robot, &set.values, &unloaded)
            .into_iter()
            .map(|p| p.position_mm)
            .collect();
        let mut columns = vec![Column::new("cw_id".into(), calibration_ids)];
        for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = positions.iter().map(|p| p[axis]).collect();
            columns.push(Column::new((*name).into(), v));
        }
        outputs
            .tables
            .insert("calibration_positions".into(), frame(columns));
        let reachable = map
            .iter()
            .filter(|p| p.status == PointStatus::Reachable)
            .count();
        outputs.facts.insert("points".into(), map.len().to_string());
        outputs
            .facts
            .insert("reachable".into(), reachable.to_string());
        for (inside, name) in [
            (true, "median_u95_inside_mm"),
            (false, "median_u95_margin_mm"),
        ] {
            if let Some(median) = median_u95(&map, inside) {
                outputs.facts.insert(name.into(), format!("{median:.4}"));
            }
        }
        Ok(outputs)
    }
}

/// The values and identified parameters with `target`'s tool translation in
/// target 0's place, so the grid (built for target 0's tool) maps that
/// target's tool; its covariance entries move with it. An error names the
/// targets when a several-target set is not told which, or an unknown one.
fn tool_of_target(
    set: &crate::table::parameters::ParameterSet,
    free: &[ParamId],
    target: &str,
) -> Result<(ParamValues, Vec<ParamId>), StageError> {
    if set.targets.len() <= 1 {
        if !target.is_empty() && set.targets.first().is_none_or(|only| only != target) {
            return Err(StageError::Invalid(format!(
                "setting `target`: `{target}` is not a target of the {} parameters (they have one tool{})",
                set.model,
                set.targets
                    .first()
                    .map(|t| format!(", target `{t}`"))
                    .unwrap_or_default()
            )));
        }
        return Ok((set.values, free.to_vec()));
    }
    let Some(chosen) = set.targets.iter().position(|t| t == target) else {
        return Err(StageError::Invalid(format!(
            "setting `target`: the {} parameters have one tool per target ({}); name the one to map{}",
            set.model,
            set.targets.join(", "),
            if target.is_empty() {
                String::new()
            } else {
                format!(" (`{target}` is not one of them)")
            }
        )));
    };
    let swap = |id: ParamId| match id.kind() {
        ParamKind::ToolTranslation { target, axis } if target == chosen => {
            ParamId::target_translation(0, axis)
        }
        ParamKind::ToolTranslation { target: 0, axis } => ParamId::target_translation(chosen, axis),
        _ => id,
    };
    let mut values = set.values;
    for axis in 0..3 {
        let (a, b) = (
            ParamId::target_translation(0, axis),
            ParamId::target_translation(chosen, axis),
        );
        let (va, vb) = (set.values.get(a), set.values.get(b));
        values.set(a, vb);
        values.set(b, va);
    }
    Ok((values, free.iter().map(|id| swap(*id)).collect()))
}

/// The median `u95` of the reachable points inside (or outside) the box.
fn median_u95(map: &[MapPoint], inside: bool) -> Option<f64> {
    let mut u: Vec<f64> = map
        .iter()
        .filter(|p| p.inside_box == inside)
        .filter_map(MapPoint::u95_mm)
        .collect();
    u.sort_by(f64::total_cmp);
    let n = u.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(u[n / 2]),
        _ => Some((u[n / 2 - 1] + u[n / 2]) / 2.0),
    }
}

/// The map's table (an arm's joint columns, `q7_deg` for a seventh joint); on
/// a track each point's carriage position in `e1_mm`.
fn map_frame(
    map: &[MapPoint],
    robot: &crate::robot::RobotSpec,
    on_track: bool,
) -> polars::prelude::DataFrame {
    let mut columns = vec![
        Column::new("point_id".into(), (0..map.len() as i64).collect::<Vec<_>>()),
        Column::new(
            "slice".into(),
            map.iter().map(|p| p.slice as i64).collect::<Vec<_>>(),
        ),
    ];
    for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
        let v: Vec<f64> = map.iter().map(|p| p.position_mm[axis]).collect();
        columns.push(Column::new((*name).into(), v));
    }
    columns.push(Column::new(
        "inside_box".into(),
        map.iter().map(|p| p.inside_box).collect::<Vec<_>>(),
    ));
    columns.push(Column::new(
        "status".into(),
        map.iter().map(|p| p.status.as_str()).collect::<Vec<_>>(),
    ));
    for (joint, name) in schema::joint_column_names(robot).iter().enumerate() {
        let v: Vec<Option<f64>> = map.iter().map(|p| p.q_deg.map(|q| q[joint])).collect();
        columns.push(Column::new((*name).into(), v));
    }
    if on_track {
        let e: Vec<Option<f64>> = map.iter().map(|p| p.q_deg.map(|_| p.track_mm)).collect();
        columns.push(Column::new(schema::TRACK_COLUMN.into(), e));
    }
    let covariances: Vec<_> = map.iter().map(|p| p.covariance_mm2).collect();
    columns.extend(covariance_columns(&covariances));
    columns.push(Column::new(
        "u95_mm".into(),
        map.iter().map(MapPoint::u95_mm).collect::<Vec<_>>(),
    ));
    frame(columns)
}
