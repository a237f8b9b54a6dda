//! `iso_cube`: places the ISO 9283 test cube in the workspace and writes the
//! pose test's cycle plan as `targets` (spec §7 columns, plus `point` and
//! `cycle`), one row per visit in running order, so that a `compensate` stage
//! turns it into joint commands (compensated, or `model = "nominal"` for the
//! controller's own IK) and its `conf_wrenches` run on a `measure` stage as
//! they stand. The geometry is [`crate::iso9283`]; this file only builds the
//! table.
//!
//! Each visit is a target of its own (`target_id` = 10·cycle + point number),
//! so the measured rows' `cw_id` says which point and cycle they are, and no
//! stage has to expand commands into cycles: the same point has the same
//! target in every cycle, and `compensate` solves it to the same command.

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot,
};
use crate::design::poses::xyz_euler_deg;
use crate::iso9283::{CYCLE_ORDER, Cube, POINTS};
use crate::robot::ParamValues;
use crate::robot::frame::{Frame, rot_x, rot_y, rot_z};
use crate::table::frame;
use crate::table::schema::{self, ORIENTATION_COLUMNS, POSITION_COLUMNS, WRENCH_COLUMNS};

pub struct IsoCubeStage;

/// The frame the cube and the tool orientation are given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum CubeFrame {
    /// The robot base frame, mapped to the tracker's world frame with the robot
    /// file's nominal `[world]` (how a user places the cube in the robot's reach).
    Base,
    /// The tracker (world) frame, as `targets` are (when the robot file's
    /// `[world]` is absent or far off).
    World,
}

/// Settings of `iso_cube`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IsoCubeSettings {
    /// Frame of `centre_mm`, `orientation_deg` and `tool_orientation_deg`: base or world.
    pub frame: CubeFrame,
    /// Centre of the cube, P1 (mm).
    #[schemars(inner(range(min = -100_000.0, max = 100_000.0)))]
    pub centre_mm: [f64; 3],
    /// Edge of the cube (mm); the standard asks for the largest cube in the
    /// part of the workspace used most.
    #[schemars(range(min = 1.0, max = 10_000.0))]
    pub edge_mm: f64,
    /// Orientation of the cube, Rot(x, α)·Rot(y, β)·Rot(z, γ) (deg). The
    /// measuring plane holds the cube's edges along its x axis at (y, z) =
    /// (−edge/2, −edge/2) and (+edge/2, +edge/2).
    #[schemars(inner(range(min = -360.0, max = 360.0)))]
    pub orientation_deg: [f64; 3],
    /// Tool orientation at every point, Rot(x, rx)·Rot(y, ry)·Rot(z, rz) (deg):
    /// the standard keeps it the same at all five points. With one SMR it
    /// should face the tracker.
    #[schemars(inner(range(min = -360.0, max = 360.0)))]
    pub tool_orientation_deg: [f64; 3],
    /// Wrench on the robot at every point, tool axes, at the tool origin:
    /// fx, fy, fz (N), mx, my, mz (N·m). The robot file's payload loads the
    /// robot besides; the standard tests at the rated load.
    #[schemars(inner(range(min = -100_000.0, max = 100_000.0)))]
    pub wrench_n_nm: [f64; 6],
    /// Test cycles (the standard: 30).
    #[schemars(range(min = 2, max = 100_000))]
    pub cycles: usize,
    /// For a robot on a linear track: the carriage position the test runs
    /// at (mm, the targets' `e1_mm`; the standard tests at one base
    /// position). Required then, refused without a track. The `base` frame
    /// is the base with the carriage at 0, as `compensate`'s.
    pub track_mm: Option<f64>,
}

impl Default for IsoCubeSettings {
    fn default() -> Self {
        IsoCubeSettings {
            frame: CubeFrame::Base,
            centre_mm: [900.0, 0.0, 900.0],
            edge_mm: 500.0,
            orientation_deg: [0.0; 3],
            tool_orientation_deg: [0.0; 3],
            wrench_n_nm: [0.0; 6],
            cycles: 30,
            track_mm: None,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "iso_cube",
    uses_cable_robot: false,
    updates_input: None,
    summary: "ISO 9283 test cube: P1–P5 and the pose test's cycles (P5, P4, P3, P2, P1 each) as targets for compensate",
    code_version: 2,
    inputs: &[],
    outputs: &[TableSlot {
        name: "targets",
        schema: schema::iso_targets,
        required: true,
        meaning: "one row per visit in running order: target_id = 10·cycle + point number, tool pose in the world frame, wrench, point, cycle",
    }],
};

impl Stage for IsoCubeStage {
    type Settings = IsoCubeSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &IsoCubeSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let robot = ctx.robot;
        match (robot.track, settings.track_mm) {
            (None, Some(_)) => vec![SettingsProblem::new(
                "track_mm",
                format!(
                    "the robot file {} has no [track]: remove `track_mm`, or use the robot file of the arm on its track",
                    robot.path.display()
                ),
            )],
            (Some(track), None) => vec![SettingsProblem::new(
                "track_mm",
                format!(
                    "the robot file {} has a [track] (travel {} to {} mm): give the carriage position the test runs at, `track_mm`, since compensate needs each target's e1_mm",
                    robot.path.display(),
                    track.travel_mm[0],
                    track.travel_mm[1]
                ),
            )],
            (Some(track), Some(e_mm)) => {
                let [lo, hi] = track.travel_mm;
                if e_mm.is_finite() && (lo..=hi).contains(&e_mm) {
                    Vec::new()
                } else {
                    vec![SettingsProblem::new(
                        "track_mm",
                        format!(
                            "{e_mm} mm is outside the track's travel [{lo}, {hi}] mm (robot file {})",
                            robot.path.display()
                        ),
                    )]
                }
            }
            (None, None) => Vec::new(),
        }
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &IsoCubeSettings,
    ) -> Result<StageOutputs, StageError> {
        let world_from_frame = match settings.frame {
            CubeFrame::Base => ctx
                .robot
                .world_from_base(&ParamValues::nominal(ctx.robot.spec())),
            CubeFrame::World => Frame::identity(),
        };
        let cube = Cube::new(
            settings.centre_mm,
            settings.edge_mm,
            settings.orientation_deg,
        );
        let points_world: Vec<Vector3<f64>> = cube
            .points_mm()
            .iter()
            .map(|p| world_from_frame.transform_point(p))
            .collect();
        let [a, b, c] = settings.tool_orientation_deg.map(f64::to_radians);
        let tool_world =
            xyz_euler_deg(&(world_from_frame.rotation * rot_x(a) * rot_y(b) * rot_z(c)));

        let cycles = settings.cycles;
        let visits: Vec<(i64, usize)> = (1..=cycles as i64)
            .flat_map(|cycle| CYCLE_ORDER.iter().map(move |&k| (cycle, k)))
            .collect();
        let mut columns = vec![Column::new(
            "target_id".into(),
            visits
                .iter()
                .map(|&(cycle, k)| 10 * cycle + k as i64 + 1)
                .collect::<Vec<_>>(),
        )];
        for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                visits
                    .iter()
                    .map(|&(_, k)| points_world[k][axis])
                    .collect::<Vec<_>>(),
            ));
        }
        for (axis, name) in ORIENTATION_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                vec![tool_world[axis]; visits.len()],
            ));
        }
        for (i, name) in WRENCH_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                vec![settings.wrench_n_nm[i]; visits.len()],
            ));
        }
        if let Some(e_mm) = settings.track_mm {
            columns.push(Column::new(
                schema::TRACK_COLUMN.into(),
                vec![e_mm; visits.len()],
            ));
        }
        columns.push(Column::new(
            "point".into(),
            visits.iter().map(|&(_, k)| POINTS[k]).collect::<Vec<_>>(),
        ));
        columns.push(Column::new(
            "cycle".into(),
            visits.iter().map(|&(cycle, _)| cycle).collect::<Vec<_>>(),
        ));
        let mut outputs = StageOutputs::default();
        outputs.tables.insert("targets".into(), frame(columns));
        outputs
            .facts
            .insert("visits".into(), visits.len().to_string());
        let p = &points_world;
        outputs
            .facts
            .insert("p2_p4_mm".into(), format!("{:.3}", (p[1] - p[3]).norm()));
        Ok(outputs)
    }
}
