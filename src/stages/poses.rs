//! `poses`: robot configurations for the campaign (paper §IV.A steps (a)–(b)):
//! target points in the cable robot's workspace box, SMR orientations facing the
//! tracker within its acceptance angle (platform upright within a roll range, the
//! orientation the cable robot is designed for), all inverse-kinematics solutions filtered
//! by joint limits, singularity distance, collisions (links, pulleys, cables,
//! platform, floor) and line of sight; one survivor per point drawn at random.
//!
//! With the optional input `targets` (the work, spec §7), points are added
//! around each target's tool position whose configurations must be in the IK
//! branch the work uses there (issue #28): a campaign designed for the work
//! can then measure the arm where and how it works, not only in the box.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

use nalgebra::Vector3;
use polars::prelude::Column;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::compensate::{WORLD_FRAME, nominal_target_commands, target_frame_problems};
use super::{
    SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo, StageOutputs,
    TableSlot, budget,
};
use crate::compensation::Status;
use crate::design::collision::{CapsuleMm, Cell};
use crate::design::poses::{
    BranchPoint, PoseOutcome, PoseProblem, Sampling, SingularityLimits, generate, xyz_euler_deg,
};
use crate::robot::{MAX_JOINTS, ParamValues, ik};
use crate::table::frame;
use crate::table::schema;

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
    /// With `targets`: points added around each work target's tool position
    /// (nominal IK), whose configurations must be in the target's IK branch,
    /// so that the campaign can measure the arm where and how it works; on a
    /// track, with the carriage at the target's `e1_mm`.
    #[schemars(range(min = 0, max = 10_000))]
    pub near_work_points: usize,
    /// With `targets`: radius (mm) of the ball around each target's tool
    /// position the added points are drawn from.
    #[schemars(range(max = 10_000.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub near_work_radius_mm: f64,
    /// With `targets`: the frame of targets whose `frame` column is null or
    /// absent, as `compensate` reads it (`world`, `base` or a name of `frames`).
    pub frame: String,
    /// With `targets`: user frames, as `compensate`'s setting `frames`.
    pub frames: BTreeMap<String, [f64; 6]>,
    /// For a robot on a linear track: the carriage stations, evenly spread
    /// over the travel ends included, at each of which the whole box is
    /// sampled (default 5). The box, the floor and the cable robot are in
    /// the base frame, so they ride with the carriage; the tracker stays in
    /// the world. At least the track's polynomial order + 1.
    #[schemars(range(min = 2, max = 1000))]
    pub track_stations: Option<usize>,
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
            near_work_points: 4,
            near_work_radius_mm: 100.0,
            frame: WORLD_FRAME.to_string(),
            frames: BTreeMap::new(),
            track_stations: None,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "poses",
    uses_cable_robot: true,
    updates_input: None,
    summary: "Robot configurations in the workspace box, SMR facing the tracker, collision-free",
    code_version: 7,
    inputs: &[TableSlot {
        name: "targets",
        schema: schema::targets,
        required: false,
        meaning: "the work (spec §7 targets): `near_work_points` points are added around each target's tool position, in its IK branch",
    }],
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
        if ctx.bound_inputs.contains(&"targets") {
            problems.extend(target_frame_problems(&settings.frame, &settings.frames));
        }
        problems.extend(track_problems(settings, ctx));
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
                ctx.robot
                    .spec()
                    .joints
                    .get(i)
                    .and_then(|joint| joint.capsule.as_ref())
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
        let near_work = match ctx.inputs.get("targets") {
            Some(input) => near_work_points(ctx, settings, input, &nominal)?,
            None => Vec::new(),
        };
        let stations = track_stations_mm(ctx.robot.spec(), settings);
        let near_work_count = near_work.len();
        let passes = passes(&stations, near_work);
        let points: usize = passes
            .iter()
            .map(|p| {
                p.near_work.len()
                    + if p.with_box {
                        settings.target_points()
                    } else {
                        0
                    }
            })
            .sum();
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
        let mut outcome = PoseOutcome::default();
        let mut station_of_pose = Vec::new();
        let mut id_offset = 0;
        for (s, pass) in passes.iter().enumerate() {
            // At a station the carriage stands at `e` (nominally a translation
            // along the base's x axis), so the tracker is `e` nearer in x.
            let mut at_station = problem.clone();
            if !pass.with_box {
                at_station.sampling = Sampling::Random { count: 0 };
            }
            let seed = match pass.station_mm {
                Some(e_mm) => {
                    at_station.cell.tracker -= Vector3::new(e_mm, 0.0, 0.0);
                    ctx.seed ^ (s as u64 + 1).wrapping_mul(TRACK_STATION_SEED)
                }
                None => ctx.seed,
            };
            let station = generate(
                ctx.robot,
                &nominal,
                &at_station,
                &pass.near_work,
                seed,
                &on_point,
            );
            for mut pose in station.poses {
                pose.config_id += id_offset;
                outcome.poses.push(pose);
                station_of_pose.push(pass.station_mm);
            }
            id_offset += station.targets as i64;
            for (reason, count) in station.rejections {
                *outcome.rejections.entry(reason).or_default() += count;
            }
            outcome.dropped_points += station.dropped_points;
            outcome.targets += station.targets;
        }
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
        for (joint, name) in schema::joint_column_names(ctx.robot.spec())
            .iter()
            .enumerate()
        {
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
        if stations.iter().any(Option::is_some) {
            let values: Vec<f64> = station_of_pose.iter().map(|e| e.unwrap_or(0.0)).collect();
            columns.push(Column::new(schema::TRACK_COLUMN.into(), values));
        }

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
        if stations.iter().any(Option::is_some) {
            outputs
                .facts
                .insert("track_stations".into(), stations.len().to_string());
        }
        if near_work_count > 0 {
            outputs
                .facts
                .insert("near_work_points".into(), near_work_count.to_string());
        }
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

/// Seed offset of each track station's draws, apart from the others'.
const TRACK_STATION_SEED: u64 = 0x7472_6163_6b73_7461;

/// One call of the pose generator: the box (or not) and points near the
/// work, at one carriage position (`None` without a track).
struct Pass {
    station_mm: Option<f64>,
    with_box: bool,
    near_work: Vec<BranchPoint>,
}

/// The generator's calls: without a track, the box and every point near the
/// work at once; on a track, the box at each station, then the points near
/// the work at each target's own carriage position (in position order).
fn passes(stations: &[Option<f64>], near_work: Vec<(BranchPoint, f64)>) -> Vec<Pass> {
    if stations.iter().all(Option::is_none) {
        return vec![Pass {
            station_mm: None,
            with_box: true,
            near_work: near_work.into_iter().map(|(p, _)| p).collect(),
        }];
    }
    let mut passes: Vec<Pass> = stations
        .iter()
        .map(|station_mm| Pass {
            station_mm: *station_mm,
            with_box: true,
            near_work: Vec::new(),
        })
        .collect();
    let mut by_position: BTreeMap<i64, (f64, Vec<BranchPoint>)> = BTreeMap::new();
    for (point, e_mm) in near_work {
        // Keyed by the position in µm: exact for the positions a table holds.
        let key = (e_mm * 1000.0).round() as i64;
        by_position
            .entry(key)
            .or_insert((e_mm, Vec::new()))
            .1
            .push(point);
    }
    passes.extend(by_position.into_values().map(|(e_mm, near_work)| Pass {
        station_mm: Some(e_mm),
        with_box: false,
        near_work,
    }));
    passes
}

/// Carriage stations a track campaign uses by default: enough for the
/// highest polynomial order (3) with one to spare.
const DEFAULT_TRACK_STATIONS: usize = 5;

/// The carriage positions (mm) the box is sampled at: evenly over the
/// travel, ends included; one `None` for a robot without a track.
fn track_stations_mm(
    robot: &crate::robot::RobotSpec,
    settings: &PosesSettings,
) -> Vec<Option<f64>> {
    let Some(track) = robot.track else {
        return vec![None];
    };
    let n = settings
        .track_stations
        .unwrap_or(DEFAULT_TRACK_STATIONS)
        .max(2);
    let [lo, hi] = track.travel_mm;
    (0..n)
        .map(|s| Some(lo + (hi - lo) * s as f64 / (n - 1) as f64))
        .collect()
}

/// `track_stations` only with a track, and enough of them for its
/// polynomials.
fn track_problems(settings: &PosesSettings, ctx: &SettingsContext) -> Vec<SettingsProblem> {
    let robot = ctx.robot;
    let mut problems = Vec::new();
    match (robot.track, settings.track_stations) {
        (None, Some(_)) => problems.push(SettingsProblem::new(
            "track_stations",
            format!(
                "the robot file {} has no [track]: remove `track_stations`, or use the robot file of the arm on its track",
                robot.path.display()
            ),
        )),
        (Some(track), stations) => {
            let n = stations.unwrap_or(DEFAULT_TRACK_STATIONS);
            if n < track.polynomial_order + 1 {
                problems.push(SettingsProblem::new(
                    "track_stations",
                    format!(
                        "{n} stations cannot separate polynomials of order {} along the track (robot file {}): give at least {}",
                        track.polynomial_order,
                        robot.path.display(),
                        track.polynomial_order + 1
                    ),
                ));
            }
        }
        (None, None) => {}
    }
    problems
}

/// Seed offset of the points drawn around the work targets, apart from the box's.
const NEAR_WORK_SEED: u64 = 0x6e65_6172_776f_726b;

/// `near_work_points` points in a ball of `near_work_radius_mm` around each
/// `ok` target's tool position (base frame, nominal loaded IK as `compensate`
/// with `model = "nominal"`), each wanting that configuration's IK branch,
/// with the target's carriage position (0 without a track).
fn near_work_points(
    ctx: &StageContext,
    settings: &PosesSettings,
    input: &super::InputTable,
    nominal: &ParamValues,
) -> Result<Vec<(BranchPoint, f64)>, StageError> {
    let (ids, targets, commands) =
        nominal_target_commands(ctx.robot, &settings.frame, &settings.frames, input)?;
    let ok: Vec<(&[f64; MAX_JOINTS], f64)> = commands
        .iter()
        .zip(&targets)
        .filter(|(c, _)| c.status == Status::Ok)
        .map(|(c, t)| (&c.q_deg, t.track_mm))
        .collect();
    if ok.is_empty() {
        return Err(StageError::Invalid(format!(
            "{}: none of the {} targets has a configuration on the nominal robot; no point to add near the work",
            input.path.display(),
            ids.len()
        )));
    }
    if ok.len() < ids.len() {
        ctx.progress.note(&format!(
            "{} of {} targets have no configuration on the nominal robot; points are added near the other {}",
            ids.len() - ok.len(),
            ids.len(),
            ok.len()
        ));
    }
    let mut rng = StdRng::seed_from_u64(ctx.seed ^ NEAR_WORK_SEED);
    let radius = settings.near_work_radius_mm;
    let mut points = Vec::with_capacity(ok.len() * settings.near_work_points);
    for (q, track_mm) in ok {
        let (_, tool) = ctx.robot.frames_in_base(nominal, q);
        let branch = ik::branch_of(ctx.robot, q);
        for _ in 0..settings.near_work_points {
            // Uniform in the ball: a uniform direction, radius ∝ u^(1/3).
            let direction = loop {
                let v = Vector3::from_fn(|_, _| rng.random_range(-1.0..=1.0));
                let norm: f64 = v.norm();
                if norm > 1e-9 && norm <= 1.0 {
                    break v / norm;
                }
            };
            let distance = radius * rng.random_range(0.0..=1.0f64).cbrt();
            points.push((
                BranchPoint {
                    position_mm: tool.origin_mm + direction * distance,
                    branch,
                },
                track_mm,
            ));
        }
    }
    Ok(points)
}
