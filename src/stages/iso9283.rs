//! `iso9283`: ISO 9283 pose accuracy and repeatability per test point, and
//! distance accuracy and repeatability between pairs of points, positions
//! only (the maths is [`crate::iso9283`]; this file reads, checks and writes
//! tables).
//!
//! Its input is either the issue's `iso_measurements` table (point, cycle,
//! commanded and attained positions: the external interface, for a test
//! measured elsewhere), or what a job measures: the `targets` an `iso_cube`
//! stage wrote (which point and cycle each target_id is, and its commanded
//! position) with the `measurements` of the `compensate` commands of those
//! targets (cw_id = target_id). It writes the `iso_measurements` it computed
//! from either way, so a job's test can be inspected or recomputed elsewhere.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use nalgebra::Vector3;
use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{
    InputTable, SettingsContext, SettingsProblem, Stage, StageContext, StageError, StageInfo,
    StageOutputs, TableSlot,
};
use crate::calibration::row_checks::{MAX_POSITION_MM, compact};
use crate::iso9283::{self, POINTS, point_index};
use crate::table::schema::{
    self, COMMAND_POSITION_COLUMNS, POSITION_COLUMNS, f64_values, i64_values, str_values,
};
use crate::table::{TableError, frame};

pub struct Iso9283Stage;

/// Settings of `iso9283`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Iso9283Settings {
    /// Pairs of points whose distance accuracy and repeatability to compute
    /// (the standard: P2 and P4, the farthest apart).
    pub distances: Vec<[String; 2]>,
}

impl Default for Iso9283Settings {
    fn default() -> Self {
        Iso9283Settings {
            distances: vec![["P2".into(), "P4".into()]],
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "iso9283",
    uses_cable_robot: false,
    updates_input: None,
    summary: "ISO 9283 pose accuracy AP and repeatability RP per point, distance accuracy AD and repeatability RD per pair (positions only)",
    code_version: 3,
    inputs: &[
        TableSlot {
            name: "iso_measurements",
            schema: schema::iso_measurements,
            required: false,
            meaning: "point, cycle, commanded and attained positions; or give targets and measurements instead",
        },
        TableSlot {
            name: "targets",
            schema: schema::iso_targets,
            required: false,
            meaning: "an iso_cube stage's targets: point, cycle and commanded position of each target_id",
        },
        TableSlot {
            name: "measurements",
            schema: schema::measurements,
            required: false,
            meaning: "the attained positions of those targets (cw_id = target_id), e.g. a measure stage of compensate's conf_wrenches",
        },
    ],
    outputs: &[
        TableSlot {
            name: "iso9283",
            schema: schema::iso9283,
            required: true,
            meaning: "per measured point: n, AP and its components, RP",
        },
        TableSlot {
            name: "iso9283_distances",
            schema: schema::iso9283_distances,
            required: true,
            meaning: "per pair of the `distances` setting: n, commanded and mean distance, AD, RD",
        },
        TableSlot {
            name: "iso_measurements",
            schema: schema::iso_measurements,
            required: true,
            meaning: "the rows the statistics were computed from",
        },
    ],
};

impl Stage for Iso9283Stage {
    type Settings = Iso9283Settings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn check_settings(
        &self,
        settings: &Iso9283Settings,
        ctx: &SettingsContext,
    ) -> Vec<SettingsProblem> {
        let mut problems = Vec::new();
        for (k, [from, to]) in settings.distances.iter().enumerate() {
            for name in [from, to] {
                if point_index(name).is_none() {
                    problems.push(SettingsProblem::new(
                        &format!("distances[{k}]"),
                        format!("`{name}` is no ISO 9283 point (P1 … P5)"),
                    ));
                }
            }
            if from == to {
                problems.push(SettingsProblem::new(
                    &format!("distances[{k}]"),
                    format!("a distance needs two different points, found `{from}` twice"),
                ));
            }
        }
        let bound = |name: &str| ctx.bound_inputs.contains(&name);
        let joined = bound("targets") || bound("measurements");
        if bound("iso_measurements") == joined
            || (joined && !(bound("targets") && bound("measurements")))
        {
            problems.push(SettingsProblem::new(
                "inputs",
                "give either `iso_measurements`, or both `targets` (an iso_cube stage's) and `measurements`",
            ));
        }
        problems
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &Iso9283Settings,
    ) -> Result<StageOutputs, StageError> {
        let rows = match ctx.inputs.get("iso_measurements") {
            Some(table) => iso_rows(table)?,
            None => {
                let targets = ctx.input("targets")?;
                super::compensate::world_frame_rows_only(targets, "iso9283")?;
                joined_rows(targets, ctx.input("measurements")?)?
            }
        };
        if rows.visits.is_empty() {
            return Err(StageError::Invalid(format!(
                "{}: no measured rows; the test has nothing to compute",
                rows.file.display()
            )));
        }
        let by_point = rows.by_point()?;

        let mut points = PointColumns::default();
        let mut short = Vec::new();
        let mut missing = Vec::new();
        for (k, visits) in by_point.iter().enumerate() {
            let Some(first) = visits.first() else {
                missing.push(POINTS[k]);
                continue;
            };
            let attained: Vec<Vector3<f64>> = visits.iter().map(|v| v.attained_mm).collect();
            let c = iso9283::pose_characteristics(&first.commanded_mm, &attained)
                .map_err(|e| iso_error(&rows.file, &format!("point {}", POINTS[k]), e))?;
            if c.n < STANDARD_CYCLES {
                short.push(format!("{} ({})", POINTS[k], c.n));
            }
            points.push(POINTS[k], &c);
        }
        let mut distances = DistanceColumns::default();
        for [from, to] in &settings.distances {
            let (a, b) = match (point_index(from), point_index(to)) {
                (Some(a), Some(b)) => (&by_point[a], &by_point[b]),
                _ => {
                    return Err(StageError::Invalid(format!(
                        "setting `distances`: `{from}`–`{to}` names no ISO 9283 point pair"
                    )));
                }
            };
            let b_by_cycle: HashMap<i64, &Visit> = b.iter().map(|v| (v.cycle, v)).collect();
            let attained: Vec<f64> = a
                .iter()
                .filter_map(|v| {
                    b_by_cycle
                        .get(&v.cycle)
                        .map(|w| (v.attained_mm - w.attained_mm).norm())
                })
                .collect();
            let commanded = match (a.first(), b.first()) {
                (Some(v), Some(w)) => (v.commanded_mm - w.commanded_mm).norm(),
                _ => f64::NAN,
            };
            let c = iso9283::distance_characteristics(commanded, &attained).map_err(|e| {
                iso_error(
                    &rows.file,
                    &format!(
                        "distance {from}–{to} (setting `distances`): cycles measuring both points"
                    ),
                    e,
                )
            })?;
            distances.push(from, to, commanded, &c);
        }

        let mut outputs = StageOutputs::default();
        for (point, ap, rp) in points.summary() {
            outputs
                .facts
                .insert(point.to_string(), format!("AP {ap:.4} mm, RP {rp:.4} mm"));
        }
        outputs
            .facts
            .insert("rows".into(), rows.visits.len().to_string());
        let mut warnings = Vec::new();
        if !missing.is_empty() {
            warnings.push(format!(
                "no rows for {} (the test has P1 … P5)",
                missing.join(", ")
            ));
        }
        if !short.is_empty() {
            warnings.push(format!(
                "fewer cycles than the {STANDARD_CYCLES} ISO 9283 asks for: {}",
                short.join(", ")
            ));
        }
        if !warnings.is_empty() {
            outputs.facts.insert("warning".into(), warnings.join("; "));
        }
        outputs.tables.insert("iso9283".into(), points.into_frame());
        outputs
            .tables
            .insert("iso9283_distances".into(), distances.into_frame());
        outputs
            .tables
            .insert("iso_measurements".into(), rows.into_frame());
        Ok(outputs)
    }
}

/// One attained position of a point in a cycle.
#[derive(Debug, Clone)]
struct Visit {
    point: usize,
    cycle: i64,
    commanded_mm: Vector3<f64>,
    attained_mm: Vector3<f64>,
    /// Row in `Rows::file`, for messages.
    row: usize,
}

/// The checked rows of a test and the file they are named by in messages.
struct Rows {
    file: std::path::PathBuf,
    visits: Vec<Visit>,
}

/// How far a point's commanded position may differ between cycles: the
/// standard commands the same pose in every cycle, so more than rounding means
/// the rows belong to different tests.
const COMMANDED_TOLERANCE_MM: f64 = 1e-6;

/// The length of `v` without overflow: a component of 1e300 gives 1e300,
/// not inf, so a message shows the value read.
fn norm(v: &Vector3<f64>) -> f64 {
    v.iter().fold(0.0_f64, |n, c| n.hypot(*c))
}

/// How far an attained position may lie from its commanded one (mm): a robot
/// misses a pose by millimetres, uncalibrated by tens; a reading farther off is
/// of another pose, in another frame or unit (metres, inches), or corrupt.
const MAX_POSE_ERROR_MM: f64 = 500.0;

/// How far one reading of a point may lie from the median of that point's
/// readings (mm, with three or more): repeatability is a fraction of a
/// millimetre, so a reading this far from the others is a tracker that locked
/// onto something else, not a cycle of the test.
const MAX_SPREAD_MM: f64 = 100.0;

/// Fewer cycles than ISO 9283 §7.2.1 asks for (30): the statistics are still
/// computed (at least 2 are needed, [`iso9283::IsoError::TooFewCycles`]), with
/// a warning, since a shorter test is useful while setting a cell up.
const STANDARD_CYCLES: usize = 30;

impl Rows {
    /// Refuses, naming the row and the column, a position that is not a
    /// reading of its pose: farther than [`MAX_POSITION_MM`] from the frame's
    /// origin, than [`MAX_POSE_ERROR_MM`] from its commanded position, or
    /// than [`MAX_SPREAD_MM`] from the median of its point's readings.
    fn check_positions(&self, by_point: &[Vec<Visit>]) -> Result<(), StageError> {
        for visit in &self.visits {
            let attained = norm(&visit.attained_mm);
            if !(0.0..=MAX_POSITION_MM).contains(&attained) {
                return Err(self.bad(
                    "x_mm",
                    visit.row,
                    format!(
                        "the attained position (x_mm, y_mm, z_mm) of {} is {} mm from the origin (more than {MAX_POSITION_MM} mm)",
                        POINTS[visit.point],
                        compact(attained)
                    ),
                ));
            }
            let error = norm(&(visit.attained_mm - visit.commanded_mm));
            if !(0.0..=MAX_POSE_ERROR_MM).contains(&error) {
                return Err(self.bad(
                    "x_mm",
                    visit.row,
                    format!(
                        "the attained position of {} (cycle {}) is {} mm from its commanded position (more than {MAX_POSE_ERROR_MM} mm): not a reading of this pose (another pose, frame or unit?)",
                        POINTS[visit.point],
                        visit.cycle,
                        compact(error)
                    ),
                ));
            }
        }
        for visits in by_point.iter().filter(|v| v.len() >= 3) {
            let median = Vector3::from_fn(|axis, _| {
                let mut values: Vec<f64> = visits.iter().map(|v| v.attained_mm[axis]).collect();
                values.sort_by(f64::total_cmp);
                values[values.len() / 2]
            });
            for visit in visits {
                let spread = norm(&(visit.attained_mm - median));
                if !(0.0..=MAX_SPREAD_MM).contains(&spread) {
                    return Err(self.bad(
                        "x_mm",
                        visit.row,
                        format!(
                            "the attained position of {} (cycle {}) is {} mm from the median of its {} readings (more than {MAX_SPREAD_MM} mm): not a reading of this pose",
                            POINTS[visit.point],
                            visit.cycle,
                            compact(spread),
                            visits.len()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The visits per point (index into [`POINTS`]), in row order. Refuses a
    /// (point, cycle) given twice and a commanded position that changes
    /// between cycles, naming the row.
    fn by_point(&self) -> Result<Vec<Vec<Visit>>, StageError> {
        let mut by_point: Vec<Vec<Visit>> = vec![Vec::new(); POINTS.len()];
        let mut seen: HashMap<(usize, i64), usize> = HashMap::new();
        for visit in &self.visits {
            if let Some(first) = seen.insert((visit.point, visit.cycle), visit.row) {
                return Err(self.bad(
                    "cycle",
                    visit.row,
                    format!(
                        "point {} cycle {} appears twice (first at row {first}); keep one row per point and cycle",
                        POINTS[visit.point], visit.cycle
                    ),
                ));
            }
            let list = &mut by_point[visit.point];
            if let Some(first) = list.first() {
                let moved = (visit.commanded_mm - first.commanded_mm).norm();
                if moved > COMMANDED_TOLERANCE_MM {
                    return Err(self.bad(
                        "x_cmd_mm",
                        visit.row,
                        format!(
                            "the commanded position of {} is {moved:.6} mm from the one at row {} (cycle {}); a point is commanded to the same position in every cycle",
                            POINTS[visit.point], first.row, first.cycle
                        ),
                    ));
                }
            }
            list.push(visit.clone());
        }
        self.check_positions(&by_point)?;
        Ok(by_point)
    }

    fn bad(&self, column: &str, row: usize, message: String) -> StageError {
        bad_value(&self.file, column, row, message)
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        let v = &self.visits;
        let mut columns = vec![
            Column::new(
                "point".into(),
                v.iter().map(|v| POINTS[v.point]).collect::<Vec<_>>(),
            ),
            Column::new(
                "cycle".into(),
                v.iter().map(|v| v.cycle).collect::<Vec<_>>(),
            ),
        ];
        for (axis, name) in COMMAND_POSITION_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                v.iter().map(|v| v.commanded_mm[axis]).collect::<Vec<_>>(),
            ));
        }
        for (axis, name) in POSITION_COLUMNS.iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                v.iter().map(|v| v.attained_mm[axis]).collect::<Vec<_>>(),
            ));
        }
        frame(columns)
    }
}

/// A statistic that cannot be computed: too few cycles is the input's fault
/// (exit 2); a non-finite result, after the checks of the positions, is a
/// failure of the stage (exit 3), never a number in the tables.
fn iso_error(file: &Path, what: &str, e: iso9283::IsoError) -> StageError {
    let message = format!("{}: {what}: {e}", file.display());
    match e {
        iso9283::IsoError::TooFewCycles { .. } => StageError::Invalid(message),
        iso9283::IsoError::NonFinite { .. } => StageError::Failed(message),
    }
}

fn bad_value(file: &Path, column: &str, row: usize, message: String) -> StageError {
    StageError::Table(TableError::BadValue {
        file: file.to_path_buf(),
        column: column.into(),
        row,
        message,
    })
}

/// The point index of each row's `point`, refusing a name that is no test point.
fn point_indices(table: &InputTable) -> Result<Vec<usize>, StageError> {
    str_values(&table.df, "point", &table.path)?
        .iter()
        .enumerate()
        .map(|(row, name)| {
            let name = name.as_deref().unwrap_or_default();
            point_index(name).ok_or_else(|| {
                bad_value(
                    &table.path,
                    "point",
                    row,
                    format!("`{name}` is no ISO 9283 point (P1 … P5)"),
                )
            })
        })
        .collect()
}

/// The positions of columns `names`, each refused (naming its row and first
/// column) when farther than [`MAX_POSITION_MM`] from the frame's origin.
fn xyz(table: &InputTable, names: &[&str; 3]) -> Result<Vec<Vector3<f64>>, StageError> {
    let axes = names
        .iter()
        .map(|c| f64_values(&table.df, c, &table.path))
        .collect::<Result<Vec<_>, _>>()?;
    (0..table.df.height())
        .map(|k| {
            let p = Vector3::new(axes[0][k], axes[1][k], axes[2][k]);
            let distance = norm(&p);
            if distance <= MAX_POSITION_MM {
                Ok(p)
            } else {
                Err(bad_value(
                    &table.path,
                    names[0],
                    k,
                    format!(
                        "the position ({}) is {} mm from the origin (more than {MAX_POSITION_MM} mm)",
                        names.join(", "),
                        compact(distance)
                    ),
                ))
            }
        })
        .collect()
}

/// The rows of an `iso_measurements` table.
fn iso_rows(table: &InputTable) -> Result<Rows, StageError> {
    let points = point_indices(table)?;
    let cycles = i64_values(&table.df, "cycle", &table.path)?;
    let commanded = xyz(table, &COMMAND_POSITION_COLUMNS)?;
    let attained = xyz(table, &POSITION_COLUMNS)?;
    let visits = (0..points.len())
        .map(|row| Visit {
            point: points[row],
            cycle: cycles[row],
            commanded_mm: commanded[row],
            attained_mm: attained[row],
            row,
        })
        .collect();
    Ok(Rows {
        file: table.path.clone(),
        visits,
    })
}

/// The rows of a job's test: each measured row's target (cw_id = target_id)
/// gives its point, cycle and commanded position. A measured row of no target
/// is refused (the run was not of this test); a target without a measured row
/// (a failed command or reading) is left out.
fn joined_rows(targets: &InputTable, measured: &InputTable) -> Result<Rows, StageError> {
    let points = point_indices(targets)?;
    let cycles = i64_values(&targets.df, "cycle", &targets.path)?;
    let ids = i64_values(&targets.df, "target_id", &targets.path)?;
    let positions = xyz(targets, &POSITION_COLUMNS)?;
    let by_id: BTreeMap<i64, usize> = ids.iter().enumerate().map(|(k, id)| (*id, k)).collect();
    let cw = i64_values(&measured.df, "cw_id", &measured.path)?;
    let attained = xyz(measured, &POSITION_COLUMNS)?;
    let visits = cw
        .iter()
        .enumerate()
        .map(|(row, id)| {
            let k = *by_id.get(id).ok_or_else(|| {
                bad_value(
                    &measured.path,
                    "cw_id",
                    row,
                    format!("{id} is no target_id of {}", targets.path.display()),
                )
            })?;
            Ok(Visit {
                point: points[k],
                cycle: cycles[k],
                commanded_mm: positions[k],
                attained_mm: attained[row],
                row,
            })
        })
        .collect::<Result<Vec<_>, StageError>>()?;
    Ok(Rows {
        file: measured.path.clone(),
        visits,
    })
}

#[derive(Default)]
struct PointColumns {
    point: Vec<&'static str>,
    n: Vec<i64>,
    ap: Vec<f64>,
    apx: Vec<f64>,
    apy: Vec<f64>,
    apz: Vec<f64>,
    rp: Vec<f64>,
}

impl PointColumns {
    fn push(&mut self, point: &'static str, c: &iso9283::PoseCharacteristics) {
        self.point.push(point);
        self.n.push(c.n as i64);
        self.ap.push(c.ap_mm);
        self.apx.push(c.ap_xyz_mm.x);
        self.apy.push(c.ap_xyz_mm.y);
        self.apz.push(c.ap_xyz_mm.z);
        self.rp.push(c.rp_mm);
    }

    fn summary(&self) -> Vec<(&'static str, f64, f64)> {
        (0..self.point.len())
            .map(|k| (self.point[k], self.ap[k], self.rp[k]))
            .collect()
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("point".into(), self.point),
            Column::new("n".into(), self.n),
            Column::new("ap_mm".into(), self.ap),
            Column::new("apx_mm".into(), self.apx),
            Column::new("apy_mm".into(), self.apy),
            Column::new("apz_mm".into(), self.apz),
            Column::new("rp_mm".into(), self.rp),
        ])
    }
}

#[derive(Default)]
struct DistanceColumns {
    from: Vec<String>,
    to: Vec<String>,
    n: Vec<i64>,
    d_cmd: Vec<f64>,
    d_mean: Vec<f64>,
    ad: Vec<f64>,
    rd: Vec<f64>,
}

impl DistanceColumns {
    fn push(
        &mut self,
        from: &str,
        to: &str,
        commanded_mm: f64,
        c: &iso9283::DistanceCharacteristics,
    ) {
        self.from.push(from.to_string());
        self.to.push(to.to_string());
        self.n.push(c.n as i64);
        self.d_cmd.push(commanded_mm);
        self.d_mean.push(c.mean_mm);
        self.ad.push(c.ad_mm);
        self.rd.push(c.rd_mm);
    }

    fn into_frame(self) -> polars::prelude::DataFrame {
        frame(vec![
            Column::new("from".into(), self.from),
            Column::new("to".into(), self.to),
            Column::new("n".into(), self.n),
            Column::new("d_cmd_mm".into(), self.d_cmd),
            Column::new("d_mean_mm".into(), self.d_mean),
            Column::new("ad_mm".into(), self.ad),
            Column::new("rd_mm".into(), self.rd),
        ])
    }
}
