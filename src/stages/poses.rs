//! `poses`: robot configurations for the campaign (paper §IV.A steps (a)–(b)):
//! target points in the cable robot's workspace box, SMR orientations facing the
//! tracker within its acceptance angle (platform upright within a roll range, the
//! orientation the cable robot is designed for), all inverse-kinematics solutions filtered
//! by joint limits, singularity distance, collisions (links, pulleys, cables,
//! platform, floor) and line of sight; one survivor per point drawn at random.

use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, budget,
};
use crate::design::collision::{CapsuleMm, Cell};
use crate::design::poses::{PoseProblem, Sampling, SingularityLimits, generate, xyz_euler_deg};
use crate::robot::ParamValues;
use crate::table::frame;
use crate::table::schema::{self, JOINT_COLUMNS};

pub struct PosesStage;

/// A 1.5-inch spherically mounted retroreflector.
const SMR_RADIUS_MM: f64 = 19.05;

/// How target points fill the box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SamplingKind {
    Grid,
    Random,
    LatinHypercube,
}

/// Settings of `poses`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct PosesSettings {
    /// How target points fill the box: grid, random or latin_hypercube.
    pub sampling: SamplingKind,
    /// Grid points per axis (grid sampling).
    #[schemars(range(min = 1, max = 1000))]
    pub points_per_axis: usize,
    /// Number of points (random and Latin-hypercube sampling).
    #[schemars(range(min = 1, max = 100_000_000))]
    pub count: usize,
    /// Centre of the workspace box in the base frame (mm).
    #[schemars(inner(range(min = -100_000.0, max = 100_000.0)))]
    pub centre_mm: [f64; 3],
    /// Edge of the (cubic) workspace box (mm).
    #[schemars(range(max = 100_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub edge_mm: f64,
    /// Tracker head in the base frame (mm); default: the robot file's nominal world origin.
    #[schemars(inner(range(min = -100_000.0, max = 100_000.0)))]
    pub tracker_mm: Option<[f64; 3]>,
    /// Largest angle between the SMR axis (tool z) and the direction to the tracker.
    #[schemars(range(min = 0.0, max = 90.0))]
    pub acceptance_half_angle_deg: f64,
    /// Tool roll about the SMR axis: uniform within ± this of the upright roll (tool
    /// x horizontal, y up). Kept small because the cable robot's wrench-feasible set
    /// depends strongly on the platform's orientation, and the default cable robot
    /// is designed for the upright platform; 180 allows any roll.
    #[schemars(range(min = 0.0, max = 180.0))]
    pub roll_half_range_deg: f64,
    /// Orientations tried per point before it is dropped.
    #[schemars(range(min = 1, max = 1_000_000))]
    pub orientation_attempts: usize,
    /// Smallest angle between axes 4 and 6, i.e. |q5| on the usual arms (wrist singularity).
    #[schemars(range(min = 0.0, max = 180.0))]
    pub min_wrist_deg: f64,
    /// Smallest distance of the wrist point from the plane of axes 1 and 2, i.e. from axis 1 on arms without a lateral offset (shoulder singularity).
    #[schemars(range(min = 0.0, max = 100_000.0))]
    pub min_shoulder_mm: f64,
    /// Smallest elbow bend from straight, seen along axis 3 (elbow singularity).
    #[schemars(range(min = 0.0, max = 180.0))]
    pub min_elbow_deg: f64,
    /// Links 2–6 stay above this height in the base frame (mm).
    #[schemars(range(min = -100_000.0, max = 100_000.0))]
    pub floor_z_mm: f64,
    /// Smallest allowed clearance between any two checked shapes (mm).
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub safety_margin_mm: f64,
    /// Pulley (anchor) ball radius of the cable robot's frame (mm).
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub pulley_radius_mm: f64,
    /// Cable radius (mm).
    #[schemars(range(min = 0.0, max = 100.0))]
    pub cable_radius_mm: f64,
}

impl Default for PosesSettings {
    fn default() -> Self {
        PosesSettings {
            sampling: SamplingKind::Grid,
            points_per_axis: 5,
            count: 125,
            centre_mm: [900.0, 0.0, 900.0],
            edge_mm: 500.0,
            tracker_mm: None,
            acceptance_half_angle_deg: 40.0,
            roll_half_range_deg: 30.0,
            orientation_attempts: 200,
            min_wrist_deg: 5.0,
            min_shoulder_mm: 100.0,
            min_elbow_deg: 5.0,
            floor_z_mm: 0.0,
            safety_margin_mm: 5.0,
            pulley_radius_mm: 40.0,
            cable_radius_mm: 3.0,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "poses",
    uses_cable_robot: true,
    updates_input: None,
    summary: "Robot configurations in the workspace box, SMR facing the tracker, collision-free",
    code_version: 4,
    inputs: &[],
    outputs: &[TableSlot {
        name: "poses",
        schema: schema::poses,
        required: true,
        meaning: "config_id, target, tool orientation, q1..q6, branch, clearance, incidence",
    }],
};

/// Bytes a target point may cost: the point (24), its per-point result while
/// the points run in parallel (the pose with its joint angles, frames and
/// rejection counts, a few hundred bytes) and its row of the output table (17
/// columns of 8 bytes), rounded up.
const BYTES_PER_POINT: f64 = 1024.0;

/// Target points from which a run is announced as long (each point tries up to
/// `orientation_attempts` inverse kinematics).
const LONG_RUN_POINTS: usize = 100_000;

impl PosesSettings {
    /// Target points the settings ask for (before unreachable points are dropped).
    fn target_points(&self) -> usize {
        match self.sampling {
            SamplingKind::Grid => self.points_per_axis.saturating_pow(3),
            SamplingKind::Random | SamplingKind::LatinHypercube => self.count,
        }
    }
}

/// The target points must fit in memory.
fn budget_problems(settings: &PosesSettings) -> Vec<SettingsProblem> {
    let (key, asked) = match settings.sampling {
        SamplingKind::Grid => (
            "points_per_axis",
            format!("points_per_axis = {} (cubed)", settings.points_per_axis),
        ),
        SamplingKind::Random | SamplingKind::LatinHypercube => {
            ("count", format!("count = {}", settings.count))
        }
    };
    let points = settings.target_points() as f64;
    budget::over_budget(
        points * BYTES_PER_POINT,
        &format!("{points:.0} target points"),
    )
    .map(|why| SettingsProblem::new(key, format!("{asked}: {why}")))
    .into_iter()
    .collect()
}

impl Stage for PosesStage {
    type Settings = PosesSettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    /// The tracker must be placed, and the target points must fit in memory:
    /// checked before the grid is allocated.
    fn check_settings(
        &self,
        settings: &PosesSettings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems = Vec::new();
        if settings.tracker_mm.is_none() && !ctx.robot.has_world {
            problems.push(SettingsProblem::new(
                "tracker_mm",
                format!(
                    "not set, and the robot file {} has no `[world]` table to place the tracker from: give `tracker_mm = [x, y, z]` (the tracker head in the base frame, mm), or add `[world]` (the nominal tracker ← base transform: x_mm, y_mm, z_mm, rx_deg, ry_deg, rz_deg) to the robot file",
                    ctx.robot.path.display()
                ),
            ));
        }
        problems.extend(budget_problems(settings));
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &PosesSettings,
    ) -> Result<StageOutputs, StageError> {
        let nominal = ParamValues::nominal(ctx.robot.spec());
        let tracker = match settings.tracker_mm {
            Some(t) => Vector3::from(t),
            None => ctx.robot.world_from_base(&nominal).inverse().origin_mm,
        };
        let cable = ctx.cable_robot;
        let attachments: Vec<Vector3<f64>> = cable
            .attachments_tool_mm
            .iter()
            .map(|a| Vector3::from(*a))
            .collect();
        // The platform is the box spanned by the cable attachment points (cube corners).
        let lower = attachments
            .iter()
            .fold(Vector3::repeat(f64::INFINITY), |m, a| m.inf(a));
        let upper = attachments
            .iter()
            .fold(Vector3::repeat(f64::NEG_INFINITY), |m, a| m.sup(a));
        let cell = Cell {
            link_capsules: std::array::from_fn(|i| {
                ctx.robot.spec().joints[i]
                    .capsule
                    .as_ref()
                    .map(|c| CapsuleMm {
                        from: Vector3::from(c.from_mm),
                        to: Vector3::from(c.to_mm),
                        radius: c.radius_mm,
                    })
            }),
            anchors: cable
                .anchors_base_mm
                .iter()
                .map(|a| Vector3::from(*a))
                .collect(),
            pulley_radius_mm: settings.pulley_radius_mm,
            attachments,
            cable_radius_mm: settings.cable_radius_mm,
            platform_centre: (lower + upper) / 2.0,
            platform_half_extents_mm: (upper - lower) / 2.0,
            smr_radius_mm: SMR_RADIUS_MM,
            floor_z_mm: settings.floor_z_mm,
            tracker,
            safety_margin_mm: settings.safety_margin_mm,
        };
        let sampling = match settings.sampling {
            SamplingKind::Grid => Sampling::Grid {
                per_axis: settings.points_per_axis,
            },
            SamplingKind::Random => Sampling::Random {
                count: settings.count,
            },
            SamplingKind::LatinHypercube => Sampling::LatinHypercube {
                count: settings.count,
            },
        };
        let problem = PoseProblem {
            centre_mm: Vector3::from(settings.centre_mm),
            edge_mm: settings.edge_mm,
            sampling,
            acceptance_half_angle_deg: settings.acceptance_half_angle_deg,
            roll_half_range_deg: settings.roll_half_range_deg,
            orientation_attempts: settings.orientation_attempts,
            singularity: SingularityLimits {
                min_wrist_deg: settings.min_wrist_deg,
                min_shoulder_mm: settings.min_shoulder_mm,
                min_elbow_deg: settings.min_elbow_deg,
            },
            cell,
        };
        let points = settings.target_points();
        if points >= LONG_RUN_POINTS {
            ctx.progress.note(&format!(
                "{points} target points with up to {} orientation attempts each: this takes a while",
                settings.orientation_attempts
            ));
        }
        ctx.progress.start(points as u64, "target points");
        let done = AtomicU64::new(0);
        let on_point = || {
            ctx.progress
                .advance(done.fetch_add(1, Ordering::Relaxed) + 1)
        };
        let outcome = generate(ctx.robot, &nominal, &problem, ctx.seed, &on_point);
        if outcome.poses.is_empty() {
            // The settings put the box where this robot cannot work: bad input.
            return Err(StageError::Invalid(format!(
                "no reachable collision-free pose at any of the {} target points of the box at centre_mm = {:?}, edge_mm = {}; rejections: {:?}; move the box into the robot's reach or loosen the filter that rejects most",
                outcome.targets, settings.centre_mm, settings.edge_mm, outcome.rejections
            )));
        }
        let poses = &outcome.poses;
        let mut columns = vec![Column::new(
            "config_id".into(),
            poses.iter().map(|p| p.config_id).collect::<Vec<_>>(),
        )];
        for (axis, name) in ["target_x_mm", "target_y_mm", "target_z_mm"]
            .iter()
            .enumerate()
        {
            columns.push(Column::new(
                (*name).into(),
                poses.iter().map(|p| p.target_mm[axis]).collect::<Vec<_>>(),
            ));
        }
        let angles: Vec<[f64; 3]> = poses
            .iter()
            .map(|p| xyz_euler_deg(&p.tool_rotation))
            .collect();
        for (axis, name) in ["tool_alpha_deg", "tool_beta_deg", "tool_gamma_deg"]
            .iter()
            .enumerate()
        {
            columns.push(Column::new(
                (*name).into(),
                angles.iter().map(|a| a[axis]).collect::<Vec<_>>(),
            ));
        }
        for (joint, name) in JOINT_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                poses.iter().map(|p| p.q_deg[joint]).collect::<Vec<_>>(),
            ));
        }
        columns.push(Column::new(
            "branch".into(),
            poses
                .iter()
                .map(|p| i64::from(p.branch))
                .collect::<Vec<_>>(),
        ));
        columns.push(Column::new(
            "clearance_mm".into(),
            poses.iter().map(|p| p.clearance_mm).collect::<Vec<_>>(),
        ));
        columns.push(Column::new(
            "incidence_deg".into(),
            poses.iter().map(|p| p.incidence_deg).collect::<Vec<_>>(),
        ));

        let mut outputs = StageOutputs::default();
        outputs.tables.insert("poses".into(), frame(columns));
        outputs
            .facts
            .insert("targets".into(), outcome.targets.to_string());
        outputs
            .facts
            .insert("poses".into(), poses.len().to_string());
        outputs
            .facts
            .insert("dropped_points".into(), outcome.dropped_points.to_string());
        for (reason, count) in &outcome.rejections {
            outputs
                .facts
                .insert(format!("rejected_{reason}"), count.to_string());
        }
        if outcome.dropped_points > 0 {
            ctx.progress.note(&format!(
                "{} of {} target points dropped after {} orientation attempts each",
                outcome.dropped_points, outcome.targets, settings.orientation_attempts
            ));
        }
        Ok(outputs)
    }
}
