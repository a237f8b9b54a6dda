//! `export_program` end to end through `egcal stage`: the RAPID and KRL files
//! read back by a small parser written here (string splitting, nothing shared
//! with egcal) give the commands to the printed precision; every Cartesian move
//! names the tool and base the program declares, and that tool's pose from the
//! commanded joints on the nominal arm is the move's target (so the program
//! moves the frame its targets were computed for); approach points lie back
//! along the tool axis; the quaternion and Z-Y-X Euler conventions on
//! hand-computed rotations; configuration bits recomputed from their
//! definitions; the CSV is plain CSV; the URDF's forward kinematics, composed
//! here from its xyz/rpy origins, equals egcal's rigid model, and its limits
//! are the robot file's; `on_failed`; the tool of several-target parameters;
//! and bad settings refused by `egcal check` with their key.

mod common;

use common::urdf::{attribute, chain, rx, ry, rz, urdf_joints, urdf_transform};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use egcal::robot::params::ParamId;
use egcal::robot::{MAX_JOINTS, ParamValues, Robot, RobotSpec};
use egcal::table::parameters::{self, ModelName, ParameterSet};
use nalgebra::{Matrix3, Matrix4, UnitQuaternion, Vector3};
use polars::prelude::*;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// One row of a `commands` table.
#[derive(Debug, Clone, Default)]
struct Row {
    id: i64,
    q: [f64; MAX_JOINTS],
    status: &'static str,
    p: [f64; 3],
    quat: [f64; 4],
    /// The optional `tool_id` column (written when a row has one).
    tool: Option<&'static str>,
    /// The optional spec §8 columns `envelope_distance`, `u95_mm` (written
    /// when a row has them).
    envelope: Option<[Option<f64>; 2]>,
}

fn robot_file() -> PathBuf {
    common::root().join("jobs/robots/irb1600_145.toml")
}

fn robot() -> Robot {
    Robot::new(RobotSpec::load(&robot_file()).unwrap())
}

/// `n` rows at random joint commands: the corrected Cartesian target is the
/// nominal FK with the nominal tool, as `compensate` writes it.
fn random_rows(robot: &Robot, n: usize, seed: u64) -> Vec<Row> {
    let mut rng = StdRng::seed_from_u64(seed);
    let nominal = ParamValues::nominal(robot.spec());
    (0..n)
        .map(|k| {
            let q: [f64; MAX_JOINTS] = robot.joint_vector(|i| {
                let [lo, hi] = robot.joint_limits(i);
                rng.random_range(lo..hi)
            });
            let (_, tool) = robot.frames_in_base(&nominal, &q);
            let uq = UnitQuaternion::from_matrix(&tool.rotation);
            Row {
                id: k as i64 + 1,
                q,
                status: "ok",
                p: [tool.origin_mm.x, tool.origin_mm.y, tool.origin_mm.z],
                quat: [uq.w, uq.i, uq.j, uq.k],
                ..Row::default()
            }
        })
        .collect()
}

fn commands_frame(rows: &[Row]) -> DataFrame {
    let mut columns = vec![Column::new(
        "target_id".into(),
        rows.iter().map(|r| r.id).collect::<Vec<_>>(),
    )];
    for j in 0..6 {
        columns.push(Column::new(
            format!("q{}_deg", j + 1).into(),
            rows.iter().map(|r| r.q[j]).collect::<Vec<_>>(),
        ));
    }
    columns.push(Column::new(
        "status".into(),
        rows.iter().map(|r| r.status).collect::<Vec<_>>(),
    ));
    for name in ["residual_mm", "correction_mm", "elastic_mm"] {
        columns.push(Column::new(name.into(), vec![0.25; rows.len()]));
    }
    for (k, name) in ["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"].iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            rows.iter().map(|r| r.p[k]).collect::<Vec<_>>(),
        ));
    }
    for (k, name) in ["qw_cmd", "qx_cmd", "qy_cmd", "qz_cmd"].iter().enumerate() {
        columns.push(Column::new(
            (*name).into(),
            rows.iter().map(|r| r.quat[k]).collect::<Vec<_>>(),
        ));
    }
    if rows.iter().any(|r| r.tool.is_some()) {
        columns.push(Column::new(
            "tool_id".into(),
            rows.iter().map(|r| r.tool).collect::<Vec<_>>(),
        ));
    }
    if rows.iter().any(|r| r.envelope.is_some()) {
        for (k, name) in ["envelope_distance", "u95_mm"].iter().enumerate() {
            columns.push(Column::new(
                (*name).into(),
                rows.iter()
                    .map(|r| r.envelope.and_then(|e| e[k]))
                    .collect::<Vec<_>>(),
            ));
        }
    }
    let df = DataFrame::new(rows.len(), columns).unwrap();
    egcal::table::schema::commands()
        .check(&df, Path::new("commands"))
        .unwrap();
    df
}

/// Runs `egcal stage export_program`; returns (exit code, stderr, output folder).
fn export(
    dir: &Path,
    rows: &[Row],
    parameters: Option<&Path>,
    settings: &str,
) -> (i32, String, PathBuf) {
    export_for(&robot_file(), dir, rows, parameters, settings)
}

/// [`export`] with another robot file.
fn export_for(
    robot_file: &Path,
    dir: &Path,
    rows: &[Row],
    parameters: Option<&Path>,
    settings: &str,
) -> (i32, String, PathBuf) {
    let commands = dir.join("commands.parquet");
    egcal::table::write_parquet(&mut commands_frame(rows), &commands, None).unwrap();
    let settings_file = dir.join("settings.toml");
    std::fs::write(&settings_file, settings).unwrap();
    let out = dir.join("out");
    let mut args: Vec<String> = [
        "stage",
        "export_program",
        "--robot",
        robot_file.to_str().unwrap(),
        "--settings",
        settings_file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--input",
    ]
    .map(String::from)
    .to_vec();
    args.push(format!("commands={}", commands.display()));
    if let Some(p) = parameters {
        args.push("--input".into());
        args.push(format!("parameters={}", p.display()));
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stdout, stderr) = common::run(&args, dir);
    (code, format!("{stdout}{stderr}"), out)
}

// ---- the independent reader ---------------------------------------------------

/// Numbers in `text` (split at anything that cannot be part of one).
fn numbers(text: &str) -> Vec<f64> {
    text.split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'E' || c == 'e'))
        .filter(|s| !s.is_empty() && s.chars().any(|c| c.is_ascii_digit()))
        .map(|s| s.parse::<f64>().unwrap_or_else(|_| panic!("number `{s}`")))
        .collect()
}

/// The id a data name ends with (`jt_12`, `pt_n3`, `XP_N3`).
fn id_of(name: &str, prefix: &str) -> i64 {
    let tail = name.strip_prefix(prefix).unwrap();
    match tail.strip_prefix(['n', 'N']) {
        Some(abs) => -abs.parse::<i64>().unwrap(),
        None => tail.parse().unwrap(),
    }
}

/// RAPID: `CONST <type> <name> := <value>;` and `PERS <type> <name> := <value>;`
/// lines by type, name → numbers.
fn rapid_data(text: &str, ty: &str) -> BTreeMap<String, Vec<f64>> {
    let leads = [format!("CONST {ty} "), format!("PERS {ty} ")];
    text.lines()
        .map(str::trim)
        .filter_map(|l| leads.iter().find_map(|lead| l.strip_prefix(lead.as_str())))
        .map(|rest| {
            let (name, value) = rest.split_once(":=").unwrap();
            (name.trim().to_string(), numbers(value))
        })
        .collect()
}

/// KRL: `DECL <type> <name>={K v,K v,...}` lines, name → key → value.
fn krl_data(text: &str, ty: &str) -> BTreeMap<String, BTreeMap<String, f64>> {
    let lead = format!("DECL {ty} ");
    text.lines()
        .filter_map(|l| l.trim().strip_prefix(lead.as_str()))
        .map(|rest| {
            let (name, value) = rest.split_once('=').unwrap();
            let inner = value.trim().trim_start_matches('{').trim_end_matches('}');
            let fields = inner
                .split(',')
                .map(|f| {
                    let (k, v) = f.trim().split_once(' ').unwrap();
                    (k.to_string(), v.trim().parse::<f64>().unwrap())
                })
                .collect();
            (name.trim().to_string(), fields)
        })
        .collect()
}

/// A RAPID move instruction as read back.
#[derive(Debug, Clone, PartialEq)]
struct RapidMove {
    instruction: String,
    target: String,
    zone: String,
    tool: String,
    wobj: String,
}

/// The move instructions of RAPID routine `routine`, in order.
fn rapid_moves(text: &str, routine: &str) -> Vec<RapidMove> {
    let start = format!("PROC {routine}()");
    text.lines()
        .map(str::trim)
        .skip_while(|l| *l != start)
        .take_while(|l| *l != "ENDPROC")
        .filter(|l| l.starts_with("Move"))
        .map(|l| {
            let (instruction, rest) = l.split_once(' ').unwrap();
            let fields: Vec<&str> = rest.trim_end_matches(';').split(", ").collect();
            assert_eq!(fields.len(), 4, "{l}");
            let (tool, wobj) = fields[3].split_once("\\WObj:=").unwrap();
            RapidMove {
                instruction: instruction.to_string(),
                target: fields[0].to_string(),
                zone: fields[2].to_string(),
                tool: tool.to_string(),
                wobj: wobj.to_string(),
            }
        })
        .collect()
}

/// A tool or pose as a rotation and a translation (mm).
type Pose = (Matrix3<f64>, Vector3<f64>);

/// The flange pose at `q` on the robot file's nominal arm (egcal's model; the
/// URDF test checks that model independently).
fn nominal_flange(robot: &Robot, q: &[f64; MAX_JOINTS]) -> Pose {
    let (frames, _) = robot.frames_in_base(&ParamValues::nominal(robot.spec()), q);
    (
        frames[robot.joint_count()].rotation,
        frames[robot.joint_count()].origin_mm,
    )
}

/// `a · b`.
fn compose(a: &Pose, b: &Pose) -> Pose {
    (a.0 * b.0, a.1 + a.0 * b.1)
}

/// Half a unit of the last printed digit of each position component (√3 of
/// it for the distance), plus what the tool's printed orientation and the
/// arithmetic can add: the declared tool's pose from the commanded joints must
/// be the printed target to this.
const FK_POSITION_TOL_MM: f64 = 0.5e-4 * 1.7321 + 1e-6;

/// Asserts that every Cartesian move of a RAPID module names a tool and work
/// object the module declares (never `tool0`/`wobj0`), that the work object is
/// the base frame, and that the move's target is its tool's pose at the row's
/// joint command on the nominal arm; approach points (`pa_`) lie
/// `approach_mm` back along the tool axis from their target. Returns the tool
/// each target id is moved with.
fn assert_rapid_moves_its_tools(
    robot: &Robot,
    module: &str,
    rows: &[Row],
    approach_mm: Option<f64>,
) -> BTreeMap<i64, String> {
    let tools = rapid_data(module, "tooldata");
    let wobjs = rapid_data(module, "wobjdata");
    let targets = rapid_data(module, "robtarget");
    assert!(!tools.is_empty() && !wobjs.is_empty(), "{module}");
    for wobj in wobjs.values() {
        let identity = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        assert_eq!(wobj[..7], identity);
        assert_eq!(wobj[7..], identity);
    }
    let mut tool_of = BTreeMap::new();
    let moves: Vec<RapidMove> = ["path_joint", "path_linear"]
        .iter()
        .flat_map(|r| rapid_moves(module, r))
        .collect();
    assert!(!moves.is_empty());
    for m in &moves {
        assert!(
            tools.contains_key(&m.tool),
            "{m:?} names an undeclared tool"
        );
        assert!(
            wobjs.contains_key(&m.wobj),
            "{m:?} names an undeclared work object"
        );
        assert!(!m.tool.eq_ignore_ascii_case("tool0") && !m.wobj.eq_ignore_ascii_case("wobj0"));
        if !m.target.starts_with("pt_") {
            continue;
        }
        let id = id_of(&m.target, "pt_");
        let row = rows.iter().find(|r| r.id == id).unwrap();
        let t = &tools[&m.tool];
        let tool: Pose = (
            quat_matrix([t[3], t[4], t[5], t[6]]),
            Vector3::new(t[0], t[1], t[2]),
        );
        let (r, p) = compose(&nominal_flange(robot, &row.q), &tool);
        let printed = &targets[&m.target];
        let printed_p = Vector3::new(printed[0], printed[1], printed[2]);
        assert!(
            (p - printed_p).norm() <= FK_POSITION_TOL_MM,
            "{}: tool {} at the joint command is {} mm from the robtarget",
            m.target,
            m.tool,
            (p - printed_p).norm()
        );
        let printed_r = quat_matrix([printed[3], printed[4], printed[5], printed[6]]);
        assert!((r - printed_r).abs().max() < 1e-8, "{}", m.target);
        tool_of.insert(id, m.tool.clone());
        if let Some(a) = approach_mm {
            let approach = &targets[&m.target.replacen("pt_", "pa_", 1)];
            let expected = printed_p - printed_r.column(2) * a;
            let found = Vector3::new(approach[0], approach[1], approach[2]);
            assert!(
                (found - expected).norm() <= 2.0 * FK_POSITION_TOL_MM,
                "{}",
                m.target
            );
            assert_eq!(approach[3..7], printed[3..7]);
        }
    }
    // Every ok row's target is moved to.
    let ok = rows.iter().filter(|r| r.status == "ok").count();
    if moves.iter().any(|m| m.target.starts_with("pt_")) {
        assert_eq!(tool_of.len(), ok);
    }
    tool_of
}

/// KRL's Z-Y-X A, B, C (deg) as a rotation.
fn abc_matrix(f: &BTreeMap<String, f64>) -> Matrix3<f64> {
    rz(f["A"].to_radians()) * ry(f["B"].to_radians()) * rx(f["C"].to_radians())
}

/// The KRL counterpart of [`assert_rapid_moves_its_tools`]: `$BASE` and `$TOOL`
/// are set from frames the `.dat` declares before the first move, the base is
/// the identity, and every E6POS moved to is its active tool's pose at the
/// row's joint command. Returns the tool each target id is moved with.
fn assert_krl_moves_its_tools(
    robot: &Robot,
    src: &str,
    dat: &str,
    rows: &[Row],
    approach_mm: Option<f64>,
) -> BTreeMap<i64, String> {
    let frames = krl_data(dat, "FRAME");
    let poses = krl_data(dat, "E6POS");
    let mut base = None;
    let mut tool: Option<String> = None;
    let mut tool_of = BTreeMap::new();
    for line in src.lines().filter(|l| !l.starts_with(';')) {
        if let Some(name) = line.strip_prefix("$BASE = ") {
            base = Some(name.to_string());
        } else if let Some(name) = line.strip_prefix("$TOOL = ") {
            assert!(
                frames.contains_key(name),
                "{name} is not declared in the .dat"
            );
            tool = Some(name.to_string());
        } else if line.starts_with("PTP ") || line.starts_with("LIN ") {
            let base = base.as_ref().expect("$BASE set before the first move");
            assert!(frames[base].values().all(|v| *v == 0.0), "{base}");
            let tool = tool.as_ref().expect("$TOOL set before the first move");
            let name = line.split_whitespace().nth(1).unwrap();
            if !name.starts_with("XP_") {
                continue;
            }
            let id = id_of(name, "XP_");
            let row = rows.iter().find(|r| r.id == id).unwrap();
            let t = &frames[tool];
            let tool_pose: Pose = (abc_matrix(t), Vector3::new(t["X"], t["Y"], t["Z"]));
            let (r, p) = compose(&nominal_flange(robot, &row.q), &tool_pose);
            let e6 = &poses[name];
            let printed_p = Vector3::new(e6["X"], e6["Y"], e6["Z"]);
            // Euler angles printed to 1e-6 deg move a 200 mm tool by 2e-6 mm.
            assert!(
                (p - printed_p).norm() <= FK_POSITION_TOL_MM + 1e-5,
                "{name}: {tool} at the joint command is {} mm from the E6POS",
                (p - printed_p).norm()
            );
            assert!((r - abc_matrix(e6)).abs().max() < 1e-7, "{name}");
            tool_of.insert(id, tool.clone());
            if let Some(a) = approach_mm {
                let approach = &poses[&name.replacen("XP_", "XA_", 1)];
                let expected = printed_p - abc_matrix(e6).column(2) * a;
                let found = Vector3::new(approach["X"], approach["Y"], approach["Z"]);
                assert!(
                    (found - expected).norm() <= 2.0 * FK_POSITION_TOL_MM,
                    "{name}"
                );
            }
        } else {
            assert!(
                !line.contains("$NULLFRAME") && !line.contains("TOOL_DATA"),
                "{line}"
            );
        }
    }
    tool_of
}

/// Rotation of a quaternion (w, x, y, z), written out.
fn quat_matrix([w, x, y, z]: [f64; 4]) -> Matrix3<f64> {
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

/// Quaternion of `Rot(z, a)·Rot(y, b)·Rot(x, c)` by the half-angle formula.
fn zyx_quaternion(a_deg: f64, b_deg: f64, c_deg: f64) -> [f64; 4] {
    let (sy, cy) = (a_deg.to_radians() / 2.0).sin_cos();
    let (sp, cp) = (b_deg.to_radians() / 2.0).sin_cos();
    let (sr, cr) = (c_deg.to_radians() / 2.0).sin_cos();
    [
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ]
}

// ---- tests --------------------------------------------------------------------

#[test]
fn rapid_and_krl_read_back_give_the_commands_to_the_printed_precision() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let mut rows = random_rows(&robot, 60, 11);
    rows[3].status = "unreachable";
    rows[7].status = "joint_limit";
    rows[9].id = -4;
    let (code, log, out) = export(dir.path(), &rows, None, "motion = \"both\"\n");
    assert_eq!(code, 0, "{log}");
    let module = std::fs::read_to_string(out.join("EGCAL_PROGRAM.mod")).unwrap();
    let dat = std::fs::read_to_string(out.join("EGCAL_PROGRAM.dat")).unwrap();
    let src = std::fs::read_to_string(out.join("EGCAL_PROGRAM.src")).unwrap();
    let csv = std::fs::read_to_string(out.join("commands.csv")).unwrap();
    let notes = std::fs::read_to_string(out.join("commands.csv.txt")).unwrap();
    assert!(!out.join("robot.urdf").exists(), "no parameters, no URDF");
    // The robot file's tool (no parameters), the tool the rows were computed for.
    assert!(
        module.contains("  PERS tooldata egcal_tool := [TRUE, [[22.0000, 50.0000, 150.0000], [1.000000000, 0.000000000, 0.000000000, 0.000000000]], [0.001, [0, 0, 0.001], [1, 0, 0, 0], 0, 0, 0]];"),
        "{module}"
    );
    assert!(!module.contains("WARNING: the commands table"), "{module}");
    assert_rapid_moves_its_tools(&robot, &module, &rows, None);
    assert_krl_moves_its_tools(&robot, &src, &dat, &rows, None);

    let joints = rapid_data(&module, "jointtarget");
    let targets = rapid_data(&module, "robtarget");
    let axes = krl_data(&dat, "E6AXIS");
    let poses = krl_data(&dat, "E6POS");
    let ok: Vec<&Row> = rows.iter().filter(|r| r.status == "ok").collect();
    for data in [joints.len(), targets.len(), axes.len(), poses.len()] {
        assert_eq!(data, ok.len());
    }
    // Half a unit of the last printed digit, plus rounding.
    let (joint_tol, pos_tol, quat_tol, euler_tol): (f64, f64, f64, f64) = (
        0.5e-6 + 1e-12,
        0.5e-4 + 1e-9,
        0.5e-9 + 1e-15,
        0.5e-6 + 1e-12,
    );
    for (name, v) in &joints {
        let row = ok.iter().find(|r| r.id == id_of(name, "jt_")).unwrap();
        for (j, (printed, q)) in v.iter().zip(&row.q[..6]).enumerate() {
            assert!((printed - q).abs() <= joint_tol, "{name} q{}", j + 1);
        }
        assert!(v[6..].iter().all(|e| *e == 9e9));
    }
    for (name, v) in &targets {
        let row = ok.iter().find(|r| r.id == id_of(name, "pt_")).unwrap();
        for (printed, p) in v.iter().zip(row.p) {
            assert!((printed - p).abs() <= pos_tol, "{name} pos");
        }
        // q and −q are the same rotation; the files print w ≥ 0.
        let sign = if row.quat[0] < 0.0 { -1.0 } else { 1.0 };
        assert!(v[3] >= 0.0, "{name}");
        for (printed, q) in v[3..].iter().zip(row.quat) {
            assert!((printed - sign * q).abs() <= quat_tol, "{name} quaternion");
        }
        // confdata: quadrants ⌊q/90⌋ of axes 1, 4, 6; cfx's last bit is axis 5's sign.
        let quadrant = |q: f64| (q / 90.0).floor();
        assert_eq!(v[7], quadrant(row.q[0]), "{name} cf1");
        assert_eq!(v[8], quadrant(row.q[3]), "{name} cf4");
        assert_eq!(v[9], quadrant(row.q[5]), "{name} cf6");
        assert!((0.0..=7.0).contains(&v[10]));
        assert_eq!(v[10] as i64 % 2, i64::from(row.q[4] < 0.0), "{name} cfx");
    }
    for (name, f) in &axes {
        let row = ok.iter().find(|r| r.id == id_of(name, "XJ_")).unwrap();
        for j in 0..6 {
            assert!((f[&format!("A{}", j + 1)] - row.q[j]).abs() <= joint_tol);
        }
    }
    for (name, f) in &poses {
        let row = ok.iter().find(|r| r.id == id_of(name, "XP_")).unwrap();
        for (k, key) in ["X", "Y", "Z"].iter().enumerate() {
            assert!((f[*key] - row.p[k]).abs() <= pos_tol, "{name} {key}");
        }
        // A, B, C rebuild the quaternion's rotation (to the printed precision).
        let r = rz(f["A"].to_radians()) * ry(f["B"].to_radians()) * rx(f["C"].to_radians());
        assert!(
            (r - quat_matrix(row.quat)).abs().max() <= 3.0 * euler_tol.to_radians() + 1e-12,
            "{name}: ABC"
        );
        assert!(f["B"].abs() <= 90.0 && f["A"].abs() <= 180.0 && f["C"].abs() <= 180.0);
        // Turn: bit i−1 set for a negative axis i.
        let turn: u32 = (0..6).filter(|&j| row.q[j] < 0.0).map(|j| 1 << j).sum();
        assert_eq!(f["T"], f64::from(turn), "{name} T");
        let s = f["S"] as u32;
        assert!(s < 8, "{name} S");
        let a5_negative = row.q[4] < 0.0;
        assert_eq!(s & 4 != 0, a5_negative, "{name} S bit 2");
    }
    // Motions: every ok row once per path, failed rows nowhere but in the comments.
    let moves = |text: &str, word: &str| {
        text.lines()
            .filter(|l| l.trim_start().starts_with(word))
            .count()
    };
    assert_eq!(moves(&module, "MoveAbsJ"), ok.len());
    assert_eq!(moves(&module, "MoveJ") + moves(&module, "MoveL"), ok.len());
    assert_eq!(moves(&src, "PTP"), ok.len() + 1);
    assert_eq!(moves(&src, "LIN"), ok.len() - 1);
    for text in [&module, &dat, &src, &notes] {
        assert!(text.contains("target_id 4: unreachable"), "{text}");
        assert!(text.contains("target_id 8: joint_limit"));
        assert!(text.contains("NOMINAL kinematic model"));
        assert!(text.contains("ABB Absolute Accuracy"));
        assert!(text.contains("generated by egcal"));
        assert!(text.contains("from the robot file's [tool]"), "{text}");
    }
    assert!(!module.contains("jt_4 ") && !module.contains("jt_4,"));
    // Plain CSV: a header line, then one line per ok row, every line the same
    // number of fields; the values are the rows'.
    let lines: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(lines.len(), ok.len() + 1, "{csv}");
    assert_eq!(lines[0][..2], ["target_id", "q1_deg"]);
    assert!(lines.iter().all(|l| l.len() == lines[0].len()), "{csv}");
    for (line, row) in lines[1..].iter().zip(&ok) {
        assert_eq!(line[0].parse::<i64>().unwrap(), row.id);
        let column = |name: &str| lines[0].iter().position(|c| *c == name).unwrap();
        assert!((line[column("q3_deg")].parse::<f64>().unwrap() - row.q[2]).abs() <= joint_tol);
        assert!((line[column("y_cmd_mm")].parse::<f64>().unwrap() - row.p[1]).abs() <= pos_tol);
    }
}

/// A robot file whose six axes all turn about one vertical line through
/// (1000, 0) mm at height 800.25 mm, so that its tool pose is hand-computed:
/// position (1000, 0, 800.25), rotation Rot(z, Σq)·(the tool's
/// Rot(x, α)·Rot(y, β)), no tool translation.
fn one_axis_robot_file(dir: &Path, tool_alpha_deg: f64, tool_beta_deg: f64) -> PathBuf {
    let mut text = String::from("name = \"one axis\"\n");
    for (a, d) in [
        (1000.0, 800.25),
        (0.0, 0.0),
        (0.0, 0.0),
        (0.0, 0.0),
        (0.0, 0.0),
        (0.0, 0.0),
    ] {
        text.push_str(&format!(
            "[[joints]]\nalpha_deg = 0.0\na_mm = {a}\ntheta_offset_deg = 0.0\nd_mm = {d}\nlimits_deg = [-400.0, 400.0]\nlink_mass_kg = 1.0\nlink_cog_mm = [0.0, 0.0, 0.0]\n\n"
        ));
    }
    text.push_str(&format!(
        "[tool]\nx_mm = 0.0\ny_mm = 0.0\nz_mm = 0.0\nalpha_deg = {tool_alpha_deg}\nbeta_deg = {tool_beta_deg}\ngamma_deg = 0.0\n"
    ));
    let path = dir.join("one_axis.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn conventions_on_hand_computed_rotations() {
    // Axes 3 and 5 at -30 and -45 deg (Turn 4 + 16 = 20), axis 1 making up
    // the sum Σq; the table's own Cartesian columns are those of the tool.
    let row = |id: i64, sum_deg: f64, quat: [f64; 4]| Row {
        id,
        q: [sum_deg + 75.0, 0.0, -30.0, 0.0, -45.0, 0.0, 0.0],
        status: "ok",
        p: [1000.0, 0.0, 800.25],
        quat,
        ..Row::default()
    };
    // Tool Rot(y, 40): Rot(z, 90)·Rot(y, 40) is A 90, B 40, C 0; Rot(y, 40)
    // alone B 40; Rot(z, 30)·Rot(y, 40) A 30, B 40.
    let rows = [
        row(1, 90.0, zyx_quaternion(90.0, 40.0, 0.0)),
        row(2, 0.0, zyx_quaternion(0.0, 40.0, 0.0)),
        row(3, 30.0, zyx_quaternion(30.0, 40.0, 0.0)),
    ];
    let dir = tempfile::tempdir().unwrap();
    let robot_file = one_axis_robot_file(dir.path(), 0.0, 40.0);
    let (code, log, out) = export_for(
        &robot_file,
        dir.path(),
        &rows,
        None,
        "motion = \"linear\"\nformats = [\"rapid\", \"krl\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let module = std::fs::read_to_string(out.join("EGCAL_PROGRAM.mod")).unwrap();
    let dat = std::fs::read_to_string(out.join("EGCAL_PROGRAM.dat")).unwrap();
    // ABB's quaternion order [w, x, y, z], and confdata's cf1 = ⌊165/90⌋.
    assert!(
        module.contains("CONST robtarget pt_1 := [[1000.0000, 0.0000, 800.2500], ["),
        "{module}"
    );
    assert!(module.contains("], [1, 0, 0, "), "{module}");
    let printed = zyx_quaternion(90.0, 40.0, 0.0)
        .map(|v| format!("{v:.9}"))
        .join(", ");
    assert!(module.contains(&printed), "{printed}\n{module}");
    // The tool itself: Rot(y, 40) = (cos 20°, 0, sin 20°, 0).
    let tool = [20f64.to_radians().cos(), 0.0, 20f64.to_radians().sin(), 0.0]
        .map(|v| format!("{v:.9}"))
        .join(", ");
    assert!(
        module.contains(&format!(
            "PERS tooldata egcal_tool := [TRUE, [[0.0000, 0.0000, 0.0000], [{tool}]]"
        )),
        "{module}"
    );
    assert!(
        dat.contains(
            "DECL E6POS XP_1={X 1000.0000,Y 0.0000,Z 800.2500,A 90.000000,B 40.000000,C 0.000000,"
        ),
        "{dat}"
    );
    assert!(
        dat.contains("XP_2={X 1000.0000,Y 0.0000,Z 800.2500,A 0.000000,B 40.000000,C 0.000000,"),
        "{dat}"
    );
    assert!(
        dat.contains("XP_3={X 1000.0000,Y 0.0000,Z 800.2500,A 30.000000,B 40.000000,C 0.000000,"),
        "{dat}"
    );
    assert!(
        dat.contains(
            "DECL FRAME XTOOL={X 0.0000,Y 0.0000,Z 0.0000,A 0.000000,B 40.000000,C 0.000000}"
        ),
        "{dat}"
    );
    // T: axes 3 and 5 negative = 4 + 16.
    assert!(dat.contains(",T 20,"), "{dat}");
    // The joint path is not written.
    assert!(!module.contains("jointtarget") && !dat.contains("E6AXIS"));

    // C: tool Rot(x, 10) at Σq = 30 is A 30, B 0, C 10.
    let dir = tempfile::tempdir().unwrap();
    let robot_file = one_axis_robot_file(dir.path(), 10.0, 0.0);
    let rows = [row(1, 30.0, zyx_quaternion(30.0, 0.0, 10.0))];
    let (code, log, out) = export_for(
        &robot_file,
        dir.path(),
        &rows,
        None,
        "motion = \"linear\"\nformats = [\"krl\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let dat = std::fs::read_to_string(out.join("EGCAL_PROGRAM.dat")).unwrap();
    assert!(
        dat.contains("XP_1={X 1000.0000,Y 0.0000,Z 800.2500,A 30.000000,B 0.000000,C 10.000000,"),
        "{dat}"
    );
}

#[test]
fn on_failed_skip_names_the_rows_and_fail_refuses_them() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let mut rows = random_rows(&robot, 6, 3);
    rows[1].status = "singular";
    rows[4].status = "not_converged";
    // Spec §8: `outside_envelope`, with the two columns that go with it.
    rows[5].status = "outside_envelope";
    rows[5].envelope = Some([Some(41.5), Some(0.875)]);
    rows[0].envelope = Some([Some(3.0), None]);
    let (code, log, out) = export(dir.path(), &rows, None, "on_failed = \"skip\"\n");
    assert_eq!(code, 0, "{log}");
    let module = std::fs::read_to_string(out.join("EGCAL_PROGRAM.mod")).unwrap();
    let csv = std::fs::read_to_string(out.join("commands.csv")).unwrap();
    assert!(module.contains("3 row(s) not exported as motion"));
    assert!(
        module.contains("target_id 6: outside_envelope (envelope_distance 41.5, u95_mm 0.875)"),
        "{module}"
    );
    assert!(!module.contains("jt_6 "));
    assert!(log.contains("skipped = 3"), "{log}");
    // The CSV keeps the optional columns, empty where null.
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .ends_with(",qz_cmd,envelope_distance,u95_mm"),
        "{csv}"
    );
    assert!(csv.lines().nth(1).unwrap().ends_with(",3,"), "{csv}");
    assert_eq!(csv.lines().count(), 4);

    let dir = tempfile::tempdir().unwrap();
    let (code, log, out) = export(dir.path(), &rows, None, "on_failed = \"fail\"\n");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("target_id 2 (singular), 5 (not_converged), 6 (outside_envelope)"),
        "{log}"
    );
    assert!(!out.join("EGCAL_PROGRAM.mod").exists());
}

/// A parameters table with one elasto-geometric set of `values`, targets
/// `targets` (several-target set when more than one).
fn parameters_file(dir: &Path, robot: &Robot, values: ParamValues, targets: &[&str]) -> PathBuf {
    let mut set = ParameterSet::fixed(ModelName::Elastogeometric, values);
    if targets.len() > 1 {
        set.targets = targets.iter().map(|t| t.to_string()).collect();
    }
    let path = dir.join("parameters.parquet");
    egcal::table::write_parquet(&mut parameters::to_frame(robot.spec(), &[set]), &path, None)
        .unwrap();
    path
}

/// Issue 26 part 6: the robtargets were computed for a 22/50/150 mm tool and
/// moved with `tool0`. Now the module declares the calibrated tool and every
/// move uses it; the table's Cartesian columns, computed (as `compensate` does
/// today) for the robot file's tool, are not those of the calibrated tool, so
/// the files say so and use the calibrated tool's poses, which give the same
/// joint commands.
#[test]
fn programs_declare_and_move_the_calibrated_tool() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let values = ParamValues::load_overrides(
        robot.spec(),
        &common::root().join("jobs/truth/irb1600_paper.toml"),
    )
    .unwrap();
    let parameters = parameters_file(dir.path(), &robot, values, &[]);
    let rows = random_rows(&robot, 12, 8);
    let (code, log, out) = export(
        dir.path(),
        &rows,
        Some(&parameters),
        "motion = \"both\"\nformats = [\"rapid\", \"krl\", \"csv\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let read = |name: &str| std::fs::read_to_string(out.join(name)).unwrap();
    let (module, src, dat, notes) = (
        read("EGCAL_PROGRAM.mod"),
        read("EGCAL_PROGRAM.src"),
        read("EGCAL_PROGRAM.dat"),
        read("commands.csv.txt"),
    );
    // The truth's x_t, y_t, z_t = 22.193, 50.024, 148.905 mm.
    assert!(
        module.contains("PERS tooldata egcal_tool := [TRUE, [[22.1930, 50.0240, 148.9050], [1.000000000, 0.000000000, 0.000000000, 0.000000000]]"),
        "{module}"
    );
    assert!(
        dat.contains("DECL FRAME XTOOL={X 22.1930,Y 50.0240,Z 148.9050,"),
        "{dat}"
    );
    assert_rapid_moves_its_tools(&robot, &module, &rows, None);
    assert_krl_moves_its_tools(&robot, &src, &dat, &rows, None);
    for text in [&module, &src, &dat, &notes] {
        assert!(
            text.contains("WARNING: the commands table's Cartesian targets"),
            "{text}"
        );
        assert!(
            text.contains("calibrated tool of model elastogeometric in parameters.parquet"),
            "{text}"
        );
    }
    assert!(
        log.contains("warning = the commands table's Cartesian targets"),
        "{log}"
    );

    // Rows computed for the calibrated tool: the same program, no warning.
    let calibrated = robot.flange_from_tool(&values, 0);
    let rows: Vec<Row> = rows
        .iter()
        .map(|r| {
            let (frames, _) = robot.frames_in_base(&ParamValues::nominal(robot.spec()), &r.q);
            let tool = frames[robot.joint_count()].compose(&calibrated);
            let uq = UnitQuaternion::from_matrix(&tool.rotation);
            Row {
                p: tool.origin_mm.into(),
                quat: [uq.w, uq.i, uq.j, uq.k],
                ..r.clone()
            }
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let parameters = parameters_file(dir.path(), &robot, values, &[]);
    let (code, log, out) = export(dir.path(), &rows, Some(&parameters), "motion = \"both\"\n");
    assert_eq!(code, 0, "{log}");
    let again = std::fs::read_to_string(out.join("EGCAL_PROGRAM.mod")).unwrap();
    assert!(!again.contains("WARNING: the commands table"), "{again}");
    assert!(!log.contains("warning"), "{log}");
    let strip = |t: &str| {
        t.lines()
            .filter(|l| !l.contains("!"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(strip(&again), strip(&module));
}

/// Issue 26 part 7 (export): each row's target tool, and a target the
/// parameters do not know is an error naming it.
#[test]
fn several_targets_each_row_moves_its_own_tool() {
    let robot = robot();
    let mut values = ParamValues::nominal(robot.spec());
    for (target, t) in [[10.0, 20.0, 100.0], [-30.0, 40.0, 180.0]]
        .iter()
        .enumerate()
    {
        for (axis, value) in t.iter().enumerate() {
            values.set(ParamId::target_translation(target, axis), *value);
        }
    }
    let run = |rows: &[Row], settings: &str| {
        let dir = tempfile::tempdir().unwrap();
        let parameters = parameters_file(dir.path(), &robot, values, &["nest_a", "nest_b"]);
        let (code, log, out) = export(dir.path(), rows, Some(&parameters), settings);
        let files = (code == 0).then(|| {
            [
                "EGCAL_PROGRAM.mod",
                "EGCAL_PROGRAM.src",
                "EGCAL_PROGRAM.dat",
                "commands.csv",
            ]
            .map(|f| std::fs::read_to_string(out.join(f)).unwrap())
        });
        (code, log, files)
    };
    let rows = random_rows(&robot, 6, 17);

    // No tool_id column and no setting: which tool is unknown.
    let (code, log, _) = run(&rows, "motion = \"linear\"\n");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("several targets (nest_a, nest_b)") && log.contains("tool_target"),
        "{log}"
    );

    // The setting names it.
    let (code, log, files) = run(&rows, "motion = \"linear\"\ntool_target = \"nest_b\"\n");
    assert_eq!(code, 0, "{log}");
    let [module, src, dat, _] = files.unwrap();
    assert!(
        module.contains("PERS tooldata egcal_tool := [TRUE, [[-30.0000, 40.0000, 180.0000],"),
        "{module}"
    );
    assert!(
        module.contains("Tool egcal_tool (target nest_b)"),
        "{module}"
    );
    assert_rapid_moves_its_tools(&robot, &module, &rows, None);
    assert_krl_moves_its_tools(&robot, &src, &dat, &rows, None);

    let (code, log, _) = run(&rows, "tool_target = \"nest_c\"\n");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("target `nest_c`") && log.contains("nest_a, nest_b"),
        "{log}"
    );

    // A tool_id column: each row its own tool.
    let mut rows = rows;
    for (k, row) in rows.iter_mut().enumerate() {
        row.tool = Some(if k % 3 == 0 { "nest_a" } else { "nest_b" });
    }
    let (code, log, files) = run(&rows, "motion = \"both\"\n");
    assert_eq!(code, 0, "{log}");
    let [module, src, dat, csv] = files.unwrap();
    assert!(
        module.contains("PERS tooldata egcal_tool_1 := [TRUE, [[10.0000, 20.0000, 100.0000],"),
        "{module}"
    );
    assert!(
        module.contains("PERS tooldata egcal_tool_2 := [TRUE, [[-30.0000, 40.0000, 180.0000],"),
        "{module}"
    );
    let expected = |tools: [&str; 2]| -> BTreeMap<i64, String> {
        rows.iter()
            .map(|r| {
                (
                    r.id,
                    tools[usize::from(r.tool == Some("nest_b"))].to_string(),
                )
            })
            .collect()
    };
    assert_eq!(
        assert_rapid_moves_its_tools(&robot, &module, &rows, None),
        expected(["egcal_tool_1", "egcal_tool_2"])
    );
    assert_eq!(
        assert_krl_moves_its_tools(&robot, &src, &dat, &rows, None),
        expected(["XTOOL_1", "XTOOL_2"])
    );
    assert!(csv.lines().next().unwrap().ends_with(",tool_id"), "{csv}");
    assert!(csv.lines().nth(1).unwrap().ends_with(",nest_a"), "{csv}");

    // Both the column and the setting: refused.
    let (code, log, _) = run(&rows, "tool_target = \"nest_a\"\n");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("tool_target") && log.contains("tool_id"),
        "{log}"
    );

    // A target the parameters do not know, even on a row that is not ok.
    rows[4].tool = Some("nest_c");
    rows[4].status = "unreachable";
    let (code, log, _) = run(&rows, "");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("`nest_c`") && log.contains("nest_a, nest_b"),
        "{log}"
    );
}

/// Rows at random joint commands in the middle of each joint's range, with the
/// robot file's tool.
fn middle_rows(robot: &Robot, n: usize, seed: u64) -> Vec<Row> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut rows = random_rows(robot, n, seed);
    let nominal = ParamValues::nominal(robot.spec());
    for row in &mut rows {
        row.q = robot.joint_vector(|i| {
            let [lo, hi] = robot.joint_limits(i);
            let margin = 0.25 * (hi - lo);
            rng.random_range(lo + margin..hi - margin)
        });
        // Away from the wrist singularity at q5 = 0.
        if row.q[4].abs() < 20.0 {
            row.q[4] = 20.0f64.copysign(row.q[4]);
        }
        let (_, tool) = robot.frames_in_base(&nominal, &row.q);
        let uq = UnitQuaternion::from_matrix(&tool.rotation);
        row.p = tool.origin_mm.into();
        row.quat = [uq.w, uq.i, uq.j, uq.k];
    }
    rows
}

#[test]
fn approach_moves_go_back_along_the_tool_axis() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let rows = middle_rows(&robot, 8, 31);
    let (code, log, out) = export(
        dir.path(),
        &rows,
        None,
        "motion = \"linear\"\napproach_mm = 50.0\nzone = \"z10\"\n",
    );
    assert_eq!(code, 0, "{log}");
    let module = std::fs::read_to_string(out.join("EGCAL_PROGRAM.mod")).unwrap();
    let src = std::fs::read_to_string(out.join("EGCAL_PROGRAM.src")).unwrap();
    let dat = std::fs::read_to_string(out.join("EGCAL_PROGRAM.dat")).unwrap();
    assert_rapid_moves_its_tools(&robot, &module, &rows, Some(50.0));
    assert_krl_moves_its_tools(&robot, &src, &dat, &rows, Some(50.0));
    // Approach (blended), the target (exact stop), retract, per row.
    let moves = rapid_moves(&module, "path_linear");
    assert_eq!(moves.len(), 3 * rows.len());
    for (k, three) in moves.chunks(3).enumerate() {
        let id = rows[k].id;
        let instruction = if k == 0 { "MoveJ" } else { "MoveL" };
        assert_eq!(three[0].instruction, instruction);
        assert_eq!(three[0].target, format!("pa_{id}"));
        assert_eq!(three[0].zone, "z10");
        assert_eq!(
            (three[1].target.as_str(), three[1].zone.as_str()),
            (format!("pt_{id}").as_str(), "fine")
        );
        assert_eq!(three[2].target, format!("pa_{id}"));
        let last = k + 1 == rows.len();
        assert_eq!(three[2].zone, if last { "fine" } else { "z10" });
    }
    let krl_moves: Vec<&str> = src
        .lines()
        .filter(|l| l.starts_with("PTP") || l.starts_with("LIN"))
        .collect();
    assert_eq!(
        krl_moves[..4],
        ["PTP XA_1", "LIN XP_1", "LIN XA_1 C_DIS", "LIN XA_2 C_DIS"]
    );
    assert_eq!(*krl_moves.last().unwrap(), format!("LIN XA_{}", rows.len()));
}

#[test]
fn urdf_forward_kinematics_equals_the_rigid_calibrated_model() {
    let robot = robot();
    let spec = robot.spec();
    let mut values =
        ParamValues::load_overrides(spec, &common::root().join("jobs/truth/irb1600_paper.toml"))
            .unwrap();
    // Parameters the truth leaves nominal, so that every kind reaches the URDF.
    for (name, value) in [
        ("dtheta1", 0.05),
        ("dtheta6", -0.08),
        ("dalpha1", 0.03),
        ("da1", 0.4),
        ("dd1", -0.7),
        ("dd3", 0.2),
        ("dd6", 0.3),
        ("alpha_t", 1.5),
        ("beta_t", -2.0),
        ("gamma_t", 30.0),
        ("k2", 1e-4),
    ] {
        values.set(ParamId::from_name(name).unwrap(), value);
    }
    let text = urdf_matches_the_model(&robot, &values);
    assert!(text.contains("Compliance (joint stiffness) cannot be expressed in URDF"));
    assert!(text.contains("k2 = 0.0001"), "{text}");
    assert!(!text.contains("EGCAL_PROGRAM"));

    // Joint 2 (α = −90°, θ_offset = −90°) a hair away from gimbal lock in its
    // URDF rpy: a tiny identified Δθ2 and no Δα2, then exactly nominal.
    for dtheta2 in [1e-9, 0.0] {
        values.set(ParamId::from_name("dtheta2").unwrap(), dtheta2);
        values.set(ParamId::from_name("dalpha2").unwrap(), 0.0);
        urdf_matches_the_model(&robot, &values);
    }
}

/// Writes the URDF of `values` (as an elasto-geometric model of a parameters
/// table), composes its forward kinematics here from the xyz/rpy origins, and
/// asserts that it equals egcal's rigid model at 1000 random configurations to
/// 1e-9 mm (positions) and 1e-12 (rotation elements). Returns the URDF text.
fn urdf_matches_the_model(robot: &Robot, values: &ParamValues) -> String {
    let set = ParameterSet::fixed(ModelName::Elastogeometric, *values);
    let dir = tempfile::tempdir().unwrap();
    let parameters_file = dir.path().join("parameters.parquet");
    egcal::table::write_parquet(
        &mut parameters::to_frame(robot.spec(), &[set]),
        &parameters_file,
        None,
    )
    .unwrap();
    let rows = random_rows(robot, 2, 5);
    let (code, log, out) = export(
        dir.path(),
        &rows,
        Some(&parameters_file),
        "formats = [\"urdf\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let text = std::fs::read_to_string(out.join("robot.urdf")).unwrap();

    let joints = urdf_joints(&text);
    assert_eq!(joints.len(), 8);
    // The chain from `world` to `tool`, in order.
    let chain = chain(&joints, "world", "tool");
    assert_eq!(
        chain.iter().filter(|j| j.kind == "revolute").count(),
        robot.joint_count()
    );

    let mut rng = StdRng::seed_from_u64(99);
    let mut worst = 0.0f64;
    for _ in 0..1000 {
        let q: [f64; MAX_JOINTS] = robot.joint_vector(|i| {
            let [lo, hi] = robot.joint_limits(i);
            rng.random_range(lo..hi)
        });
        let mut t = Matrix4::identity();
        let mut joint = 0;
        for j in &chain {
            t *= j.origin;
            if j.kind == "revolute" {
                assert_eq!(j.axis, Some([0.0, 0.0, 1.0]));
                t *= urdf_transform([0.0; 3], [0.0, 0.0, q[joint].to_radians()]);
                joint += 1;
            }
        }
        let urdf_mm = Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)]) * 1000.0;
        let (_, tool) = robot.frames_in_base(values, &q);
        let egcal_mm = robot
            .world_from_base(values)
            .transform_point(&tool.origin_mm);
        worst = worst.max((urdf_mm - egcal_mm).norm());
        let rotation = robot.world_from_base(values).rotation * tool.rotation;
        assert!((t.fixed_view::<3, 3>(0, 0) - rotation).abs().max() < 1e-12);
    }
    assert!(
        worst <= 1e-9,
        "URDF FK differs from egcal's rigid model by {worst} mm"
    );
    text
}

/// `(lower, upper, effort, velocity)` of each revolute joint's `<limit>`.
fn urdf_limits(text: &str) -> Vec<[f64; 4]> {
    text.split("<limit ")
        .skip(1)
        .map(|element| {
            ["lower", "upper", "effort", "velocity"].map(|a| attribute(element, a).parse().unwrap())
        })
        .collect()
}

#[test]
fn urdf_limits_are_the_robot_file_s_or_marked_placeholders() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let nominal = ParamValues::nominal(robot.spec());
    let parameters = parameters_file(dir.path(), &robot, nominal, &[]);
    let rows = random_rows(&robot, 2, 5);
    // The IRB 1600's file gives joint speeds, no torques.
    let (code, log, out) = export(
        dir.path(),
        &rows,
        Some(&parameters),
        "formats = [\"urdf\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let text = std::fs::read_to_string(out.join("robot.urdf")).unwrap();
    let limits = urdf_limits(&text);
    assert_eq!(limits.len(), 6);
    for (i, [lower, upper, effort, velocity]) in limits.iter().enumerate() {
        let joint = &robot.spec().joints[i];
        assert_eq!(*lower, joint.limits()[0].to_radians());
        assert_eq!(*upper, joint.limits()[1].to_radians());
        let speed = joint.max_velocity_deg_s.unwrap();
        assert!(
            (velocity - speed.to_radians()).abs() < 1e-12,
            "joint{}",
            i + 1
        );
        assert!(
            *velocity > 0.0 && *effort > 0.0,
            "0 would read as a joint that cannot move"
        );
    }
    assert_eq!(limits[0][3], 150f64.to_radians());
    assert!(text.contains("WARNING: the robot file gives no max_torque_nm for joint1, joint2, joint3, joint4, joint5, joint6"), "{text}");
    assert!(!text.contains("no max_velocity_deg_s"), "{text}");

    // A file with torques and without speeds.
    let file_text = std::fs::read_to_string(robot_file()).unwrap();
    let torques = [900.0, 800.0, 400.0, 60.0, 50.0, 40.0];
    let mut k = 0;
    let edited: String = file_text
        .lines()
        .map(|l| {
            if l.starts_with("max_velocity_deg_s") {
                k += 1;
                format!("max_torque_nm = {}", torques[k - 1])
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let robot_file = dir.path().join("robot.toml");
    std::fs::write(&robot_file, edited).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (code, log, out) = export_for(
        &robot_file,
        dir.path(),
        &rows,
        Some(&parameters),
        "formats = [\"urdf\"]\n",
    );
    assert_eq!(code, 0, "{log}");
    let text = std::fs::read_to_string(out.join("robot.urdf")).unwrap();
    let limits = urdf_limits(&text);
    for (limit, torque) in limits.iter().zip(torques) {
        assert_eq!(limit[2], torque);
        assert_eq!(limit[3], 0.5, "the slow placeholder");
    }
    assert!(text.contains("WARNING: the robot file gives no max_velocity_deg_s for joint1, joint2, joint3, joint4, joint5, joint6"), "{text}");
    assert!(!text.contains("no max_torque_nm"), "{text}");
}

#[test]
fn check_refuses_bad_settings_with_their_key() {
    let dir = tempfile::tempdir().unwrap();
    let robot = robot();
    let commands = dir.path().join("commands.parquet");
    egcal::table::write_parquet(
        &mut commands_frame(&random_rows(&robot, 3, 1)),
        &commands,
        None,
    )
    .unwrap();
    let root = common::root();
    let job = |settings: &str| {
        format!(
            "[job]\nname = \"export\"\nseed = 1\nrobot = \"{}\"\noutput = \"out\"\n\n[[stages]]\nid = \"program\"\nkind = \"export_program\"\ninputs = {{ commands = \"{}\" }}\n{settings}\n",
            root.join("jobs/robots/irb1600_145.toml").display(),
            commands.display()
        )
    };
    std::fs::write(dir.path().join("good.toml"), job("")).unwrap();
    let (code, stdout, stderr) = common::run(&["check", "good.toml"], dir.path());
    assert_eq!(code, 0, "{stdout}{stderr}");
    for (setting, key, expected) in [
        (
            "module_name = \"1program\"",
            "stages[0].module_name",
            "not a RAPID identifier",
        ),
        (
            "module_name = \"A_PROGRAM_NAME_LONGER_THAN_24\"",
            "stages[0].module_name",
            "KRL allows at most 24",
        ),
        (
            "module_name = \"MODULE\"",
            "stages[0].module_name",
            "reserved word",
        ),
        (
            "tool_name = \"my tool\"",
            "stages[0].tool_name",
            "not a RAPID identifier",
        ),
        ("zone = \"z7\"", "stages[0].zone", "unknown zone `z7`"),
        (
            "tool_name = \"main\"",
            "stages[0].tool_name",
            "name the exported programs declare",
        ),
        (
            "wobj_name = \"pt_base\"",
            "stages[0].wobj_name",
            "prefix of the exported target data",
        ),
        (
            "speed_mm_s = 0.0",
            "stages[0].speed_mm_s",
            "range [1, 7000]",
        ),
        ("tool_name = \"tool0\"", "stages[0].tool_name", "predefined"),
        ("wobj_name = \"wobj0\"", "stages[0].wobj_name", "predefined"),
        (
            "wobj_name = \"EGCAL_TOOL\"",
            "stages[0].wobj_name",
            "also `tool_name`",
        ),
        ("tool_name = \"pt\"", "stages[0].tool_name", "`pt_1`"),
        (
            "approach_mm = 50.0\nmotion = \"joint\"",
            "stages[0].approach_mm",
            "approach moves are linear",
        ),
        (
            "approach_mm = -1.0",
            "stages[0].approach_mm",
            "range [0, 1000]",
        ),
        (
            "tool_target = \"nest2\"",
            "stages[0].tool_target",
            "input `parameters`",
        ),
        ("krl_tool = 1", "krl_tool", "unknown"),
        (
            "formats = [\"urdf\"]",
            "stages[0].formats[0]",
            "needs the input `parameters`",
        ),
        ("formats = []", "stages[0].formats", "no format given"),
        (
            "formats = [\"fanuc\"]\nzone = \"z10\"",
            "stages[0].zone",
            "not radii",
        ),
        (
            "formats = [\"yaskawa\"]\nzone = \"z10\"",
            "stages[0].zone",
            "not radii",
        ),
        (
            "formats = [\"fanuc\"]\nmodule_name = \"Cell_a\"",
            "stages[0].module_name",
            "upper case",
        ),
        (
            "fanuc_user_tool = 11",
            "stages[0].fanuc_user_tool",
            "range [1, 10]",
        ),
        ("motion = \"circular\"", "stages[0].motion", "circular"),
        ("on_failed = \"ignore\"", "stages[0].on_failed", "ignore"),
    ] {
        std::fs::write(dir.path().join("bad.toml"), job(setting)).unwrap();
        let (code, stdout, stderr) = common::run(&["check", "bad.toml"], dir.path());
        assert_eq!(code, 2, "`{setting}`: {stdout}{stderr}");
        assert!(
            stderr.contains(key) && stderr.contains(expected),
            "`{setting}`: expected `{key}` and `{expected}` in\n{stderr}"
        );
    }
}

#[test]
fn export_program_runs_in_a_job_and_publishes_its_files() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let mut rows = random_rows(&robot, 4, 21);
    rows[2].status = "singular";
    egcal::table::write_parquet(
        &mut commands_frame(&rows),
        &dir.path().join("commands.parquet"),
        None,
    )
    .unwrap();
    let nominal = ParamValues::nominal(robot.spec());
    let set = ParameterSet::fixed(ModelName::Elastogeometric, nominal);
    egcal::table::write_parquet(
        &mut parameters::to_frame(robot.spec(), &[set]),
        &dir.path().join("parameters.parquet"),
        None,
    )
    .unwrap();
    let job = format!(
        "[job]\nname = \"cell\"\nseed = 1\nrobot = \"{}\"\noutput = \"out\"\n\n\
         [[stages]]\nid = \"program\"\nkind = \"export_program\"\n\
         inputs = {{ commands = \"commands.parquet\", parameters = \"parameters.parquet\" }}\n\
         module_name = \"CELL_A\"\nmotion = \"both\"\nzone = \"z10\"\n",
        common::root()
            .join("jobs/robots/irb1600_145.toml")
            .display()
    );
    std::fs::write(dir.path().join("job.toml"), job).unwrap();
    let (code, stdout, stderr) = common::run(&["run", "job.toml"], dir.path());
    assert_eq!(code, 0, "{stdout}{stderr}");
    let log = format!("{stdout}{stderr}");
    assert!(
        log.contains("exported=3") && log.contains("skipped=1"),
        "{log}"
    );
    let out = dir.path().join("out/program");
    let read = |name: &str| {
        std::fs::read_to_string(out.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
    };
    let (module, src, dat, csv, notes, urdf) = (
        read("CELL_A.mod"),
        read("CELL_A.src"),
        read("CELL_A.dat"),
        read("commands.csv"),
        read("commands.csv.txt"),
        read("robot.urdf"),
    );
    assert!(module.starts_with("MODULE CELL_A\n  ! ABB RAPID module generated by egcal"));
    assert!(src.starts_with("DEF CELL_A( )\n; KUKA KRL program generated by egcal"));
    assert!(dat.starts_with("DEFDAT CELL_A\n; KUKA KRL data list generated by egcal"));
    assert!(csv.starts_with("target_id,q1_deg,"));
    assert!(notes.starts_with("commands.csv generated by egcal"));
    assert!(urdf.starts_with("<?xml version=\"1.0\"?>\n<!--\n  URDF generated by egcal"));
    for text in [&module, &src, &dat, &notes] {
        assert!(text.contains("NOMINAL kinematic model"), "{text}");
        assert!(text.contains("target_id 3: singular"), "{text}");
    }
    assert!(urdf.contains("cannot be expressed in URDF"));
    // Corner zones between moves, an exact stop at the end of each path.
    assert!(module.contains(", z10, egcal_tool\\WObj:=egcal_wobj;"));
    assert!(module.contains("MoveAbsJ jt_4, egcal_speed, fine, egcal_tool\\WObj:=egcal_wobj;"));
    assert!(module.contains("MoveL pt_4, egcal_speed, fine, egcal_tool\\WObj:=egcal_wobj;"));
    assert!(src.contains("$APO.CDIS = 10 ; mm\n") && src.contains("LIN XP_2 C_DIS\n"));
    assert!(src.contains("LIN XP_4\n"));

    // A second run finds everything cached and leaves the files in place.
    let (code, stdout, stderr) = common::run(&["run", "job.toml"], dir.path());
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(
        format!("{stdout}{stderr}").contains("program: cached"),
        "{stdout}{stderr}"
    );
    assert_eq!(read("CELL_A.mod"), module);
}

// ---- FANUC TP and Yaskawa INFORM, read back by their own small readers ------

/// The IRB 1600 robot file with a FANUC-style J3 (`j3_from_j2 = 1`) and
/// signed pulse ratios on every axis.
const PULSES_PER_DEG: [f64; 6] = [1234.5, -1100.25, 987.0, 700.0, -650.5, 400.0];

fn controller_robot_file(dir: &Path) -> PathBuf {
    let mut text = std::fs::read_to_string(robot_file()).unwrap();
    for (speed, pulses) in ["150.0", "160.0", "170.0", "320.0", "400.0", "450.0"]
        .iter()
        .zip(PULSES_PER_DEG)
    {
        let line = format!("max_velocity_deg_s = {speed}");
        assert_eq!(text.matches(&line).count(), 1, "{line}");
        text = text.replace(&line, &format!("{line}\npulses_per_deg = {pulses}"));
    }
    text.push_str("\n[controller]\nj3_from_j2 = 1.0\n");
    let path = dir.join("fanuc_like.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The `(index, body)` of every `P[i…]{ … };` block of an `.ls` file's `/POS`.
fn ls_positions(text: &str) -> BTreeMap<usize, String> {
    let pos = text.split("/POS\n").nth(1).unwrap();
    pos.split("};")
        .filter(|block| block.contains("P["))
        .map(|block| {
            let start = block.find("P[").unwrap() + 2;
            let index: String = block[start..]
                .chars()
                .take_while(char::is_ascii_digit)
                .collect();
            (index.parse().unwrap(), block.to_string())
        })
        .collect()
}

/// `KEY = value` fields of a position block (`J1= 10.000 deg`, `X = 1.0 mm`).
fn ls_fields(block: &str) -> BTreeMap<String, f64> {
    block
        .split([',', '\n', '\t'])
        .filter_map(|part| part.split_once('='))
        .filter_map(|(key, value)| {
            let number = value.split_whitespace().next()?.parse::<f64>().ok()?;
            Some((key.trim().to_string(), number))
        })
        .collect()
}

/// Rotation of fixed angles about x, y, z (deg): `Rot(z, c)·Rot(y, b)·Rot(x, a)`.
fn xyz_fixed(a_deg: f64, b_deg: f64, c_deg: f64) -> Matrix3<f64> {
    rz(c_deg.to_radians()) * ry(b_deg.to_radians()) * rx(a_deg.to_radians())
}

/// The IRB 1600's wrist centre (d6 = 65 mm back along the flange's z axis)
/// in its arm plane: (distance in front of axis 1, height), mm.
fn wrist_in_arm_plane(robot: &Robot, q: &[f64; MAX_JOINTS]) -> (f64, f64) {
    let (r, p) = nominal_flange(robot, q);
    let wrist = p - r * Vector3::new(0.0, 0.0, 65.0);
    let (s, c) = q[0].to_radians().sin_cos();
    (wrist.x * c + wrist.y * s, wrist.z)
}

fn wrist_in_front(robot: &Robot, q: &[f64; MAX_JOINTS]) -> bool {
    wrist_in_arm_plane(robot, q).0 >= 0.0
}

/// Whether the IRB 1600's elbow (axis 3, 700 mm up the lower arm from axis
/// 2 at (150, 486.5) mm, tilted forward by q2) lies on the side of the line
/// from axis 2 to the wrist centre where it is at zero (above it).
fn elbow_up(robot: &Robot, q: &[f64; MAX_JOINTS]) -> bool {
    let (shoulder_x, shoulder_z) = (150.0, 486.5);
    let (s2, c2) = q[1].to_radians().sin_cos();
    let elbow = (700.0 * s2, 700.0 * c2);
    let (wx, wz) = wrist_in_arm_plane(robot, q);
    let to_wrist = (wx - shoulder_x, wz - shoulder_z);
    to_wrist.0 * elbow.1 - to_wrist.1 * elbow.0 >= 0.0
}

#[test]
fn fanuc_and_yaskawa_read_back_give_the_commands_to_the_printed_precision() {
    let dir = tempfile::tempdir().unwrap();
    let file = controller_robot_file(dir.path());
    let robot = Robot::new(RobotSpec::load(&file).unwrap());
    let mut rows = random_rows(&robot, 40, 17);
    rows[5].status = "unreachable";
    let ok: Vec<&Row> = rows.iter().filter(|r| r.status == "ok").collect();
    let tool = (Matrix3::identity(), Vector3::new(22.0, 50.0, 150.0));
    let (code, log, out) = export_for(
        &file,
        dir.path(),
        &rows,
        None,
        "formats = [\"fanuc\", \"yaskawa\"]\nmotion = \"both\"\n",
    );
    assert_eq!(code, 0, "{log}");
    assert!(!out.join("EGCAL_PROGRAM.mod").exists());

    // ---- FANUC .ls
    let ls = std::fs::read_to_string(out.join("EGCAL_PROGRAM.ls")).unwrap();
    assert!(ls.starts_with("/PROG  EGCAL_PROGRAM\n/ATTR\n") && ls.ends_with("/END\n"));
    let main: Vec<&str> = ls
        .split("/MN\n")
        .nth(1)
        .unwrap()
        .split("/POS\n")
        .next()
        .unwrap()
        .lines()
        .collect();
    assert!(ls.contains(&format!("LINE_COUNT\t= {};", main.len())));
    let mut motions = Vec::new();
    let mut remarks = Vec::new();
    let mut register = [f64::NAN; 6];
    let mut tool_set_before_move = false;
    for (k, line) in main.iter().enumerate() {
        let (number, body) = line.split_once(':').unwrap();
        assert_eq!(number.trim().parse::<usize>().unwrap(), k + 1, "{line}");
        assert!(body.ends_with(" ;"), "{line}");
        let body = body.trim_end_matches(" ;");
        if let Some(remark) = body.strip_prefix("  !") {
            assert!(remark.len() <= 32, "{remark}");
            remarks.push(remark);
        } else if let Some(rest) = body.strip_prefix("  PR[100,") {
            let (element, value) = rest.split_once("]=").unwrap();
            register[element.parse::<usize>().unwrap() - 1] = value.parse().unwrap();
        } else if body == "  UTOOL[10]=PR[100]" {
            tool_set_before_move = motions.is_empty();
        } else if body.starts_with('J') || body.starts_with('L') {
            let words: Vec<&str> = body.split_whitespace().collect();
            assert_eq!(words.len(), 4, "{line}");
            assert_eq!(words[3], "FINE");
            motions.push((words[0], words[1].to_string(), words[2].to_string()));
        }
    }
    assert!(tool_set_before_move);
    assert!(main.iter().any(|l| l.ends_with(":  UTOOL_NUM=10 ;")));
    assert_eq!(register, [22.0, 50.0, 150.0, 0.0, 0.0, 0.0]);
    let remarks = remarks.join(" ");
    for expected in [
        "target_id 6: unreachable",
        "NOMINAL kinematic model",
        "UFRAME_NUM=0",
    ] {
        assert!(remarks.contains(expected), "`{expected}` in {remarks}");
    }
    let positions = ls_positions(&ls);
    assert_eq!(motions.len(), 2 * ok.len());
    assert_eq!(positions.len(), motions.len());
    let joint_tol = 0.5e-3 + 1e-9;
    let position_tol = 0.5e-3 * 1.7321 + 1e-6;
    for (k, (kind, p, speed)) in motions.iter().enumerate() {
        assert_eq!(*p, format!("P[{}]", k + 1));
        let row = ok[k % ok.len()];
        let block = &positions[&(k + 1)];
        assert!(block.contains("UF : 0, UT : 10,"), "{block}");
        let f = ls_fields(block);
        if k < ok.len() {
            // Joint path: the controller's J3 is q3 + q2.
            assert_eq!((*kind, speed.as_str()), ("J", "20%"));
            let q: [f64; 6] = std::array::from_fn(|j| f[&format!("J{}", j + 1)]);
            let q_file = [q[0], q[1], q[2] - q[1], q[3], q[4], q[5]];
            for (j, (printed, q)) in q_file.iter().zip(row.q).enumerate() {
                let tol = if j == 2 { 2.0 * joint_tol } else { joint_tol };
                assert!((printed - q).abs() <= tol, "P[{}] J{}", k + 1, j + 1);
            }
        } else {
            // Linear path: the tool's pose at the command, W P R fixed angles.
            let expected_kind = if k == ok.len() { "J" } else { "L" };
            assert_eq!(*kind, expected_kind);
            if *kind == "L" {
                assert_eq!(speed, "100mm/sec");
            }
            let (r, p) = compose(&nominal_flange(&robot, &row.q), &tool);
            for (axis, key) in ["X", "Y", "Z"].iter().enumerate() {
                assert!(
                    (f[*key] - p[axis]).abs() <= position_tol,
                    "P[{}] {key}",
                    k + 1
                );
            }
            let printed = xyz_fixed(f["W"], f["P"], f["R"]);
            assert!((printed - r).abs().max() <= 3.0 * 0.5e-3_f64.to_radians() + 1e-9);
            let config = block.split("CONFIG : '").nth(1).unwrap();
            let config = &config[..config.find('\'').unwrap()];
            let flags: Vec<&str> = config.split([' ', ',']).filter(|s| !s.is_empty()).collect();
            let flip = if row.q[4] > 0.0 { "F" } else { "N" };
            let front = if wrist_in_front(&robot, &row.q) {
                "T"
            } else {
                "B"
            };
            assert_eq!(flags[0], flip, "{config}");
            let up = if elbow_up(&robot, &row.q) { "U" } else { "D" };
            assert_eq!(flags[1], up, "{config}");
            assert_eq!(flags[2], front, "{config}");
            for (flag, j) in flags[3..].iter().zip([3, 4, 5]) {
                let turn = ((row.q[j] + 180.0) / 360.0).ceil() - 1.0;
                assert_eq!(flag.parse::<f64>().unwrap(), turn, "{config} J{}", j + 1);
            }
        }
    }

    // ---- Yaskawa .jbi
    let jbi = std::fs::read_to_string(out.join("EGCAL_PROGRAM.jbi")).unwrap();
    let lines: Vec<&str> = jbi.lines().collect();
    assert_eq!(lines[..3], ["/JOB", "//NAME EGCAL_PROGRAM", "//POS"]);
    assert_eq!(lines.last(), Some(&"END"));
    let npos = lines[3].strip_prefix("///NPOS ").unwrap();
    assert_eq!(npos, format!("{},0,0,0,0,0", 2 * ok.len()));
    assert!(lines.contains(&"///TOOL 1"));
    let mut pulse_data = true;
    let mut rconf: Option<Vec<u8>> = None;
    let mut data = BTreeMap::new();
    for line in &lines[..lines.iter().position(|l| *l == "//INST").unwrap()] {
        match *line {
            "///POSTYPE PULSE" | "///PULSE" => pulse_data = true,
            "///POSTYPE ROBOT" | "///RECTAN" => pulse_data = false,
            l if l.starts_with("///RCONF ") => {
                rconf = Some(l[9..].split(',').map(|b| b.parse().unwrap()).collect());
            }
            l if l.starts_with('C') => {
                let (name, values) = l.split_once('=').unwrap();
                let values: Vec<f64> = values.split(',').map(|v| v.parse().unwrap()).collect();
                data.insert(name.to_string(), (pulse_data, rconf.clone(), values));
            }
            _ => {}
        }
    }
    let inst = &lines[lines.iter().position(|l| *l == "NOP").unwrap() + 1..lines.len() - 1];
    let comments: Vec<&str> = inst.iter().filter_map(|l| l.strip_prefix('\'')).collect();
    assert!(comments.iter().all(|c| c.len() <= 32));
    assert!(comments.join(" ").contains("target_id 6: unreachable"));
    assert!(
        comments
            .join(" ")
            .contains("WARNING: a job cannot set a tool file")
    );
    let moves: Vec<&str> = inst
        .iter()
        .copied()
        .filter(|l| !l.starts_with('\''))
        .collect();
    assert_eq!(moves.len(), 2 * ok.len());
    for (k, line) in moves.iter().enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let name = format!("C{k:05}");
        assert_eq!(words[1], name);
        assert_eq!(words[3], "PL=0");
        let (pulses, conf, values) = &data[&name];
        let row = ok[k % ok.len()];
        if k < ok.len() {
            assert_eq!(words[..1], ["MOVJ"]);
            assert_eq!(words[2], "VJ=20.00");
            assert!(*pulses);
            // Whole pulses: within half a pulse, then J3 from U − L.
            let controller: Vec<f64> = values
                .iter()
                .zip(PULSES_PER_DEG)
                .map(|(p, r)| p / r)
                .collect();
            let q_file = [
                controller[0],
                controller[1],
                controller[2] - controller[1],
                controller[3],
                controller[4],
                controller[5],
            ];
            for j in 0..6 {
                let half_pulse = 0.5 / PULSES_PER_DEG[j].abs();
                let tol = if j == 2 {
                    half_pulse + 0.5 / PULSES_PER_DEG[1].abs()
                } else {
                    half_pulse
                };
                assert!(
                    (q_file[j] - row.q[j]).abs() <= tol + 1e-9,
                    "{name} axis {}",
                    j + 1
                );
            }
        } else {
            assert_eq!(words[0], if k == ok.len() { "MOVJ" } else { "MOVL" });
            if words[0] == "MOVL" {
                assert_eq!(words[2], "V=100.0");
            }
            assert!(!*pulses);
            let (r, p) = compose(&nominal_flange(&robot, &row.q), &tool);
            for axis in 0..3 {
                assert!((values[axis] - p[axis]).abs() <= position_tol, "{name}");
            }
            let printed = xyz_fixed(values[3], values[4], values[5]);
            assert!((printed - r).abs().max() <= 3.0 * 0.5e-4_f64.to_radians() + 1e-9);
            let conf = conf.as_ref().unwrap();
            assert_eq!(conf.len(), 8);
            assert_eq!(conf[0], u8::from(row.q[4] <= 0.0), "{name} flip");
            assert_eq!(
                conf[1],
                u8::from(!elbow_up(&robot, &row.q)),
                "{name} upper arm"
            );
            assert_eq!(
                conf[2],
                u8::from(!wrist_in_front(&robot, &row.q)),
                "{name} front"
            );
            for (bit, j) in [(3, 3), (4, 5), (5, 0)] {
                assert_eq!(
                    conf[bit],
                    u8::from(row.q[j].abs() >= 180.0),
                    "{name} axis {}",
                    j + 1
                );
            }
        }
    }
}

#[test]
fn a_yaskawa_job_without_pulse_ratios_is_refused_for_joint_moves() {
    let robot = robot();
    let dir = tempfile::tempdir().unwrap();
    let rows = random_rows(&robot, 3, 5);
    let (code, log, _) = export(dir.path(), &rows, None, "formats = [\"yaskawa\"]\n");
    assert_eq!(code, 2, "{log}");
    assert!(
        log.contains("joints[0].pulses_per_deg") && log.contains("motion = \"linear\""),
        "{log}"
    );
    // Cartesian moves need none.
    let (code, log, out) = export(
        dir.path(),
        &rows,
        None,
        "formats = [\"yaskawa\"]\nmotion = \"linear\"\n",
    );
    assert_eq!(code, 0, "{log}");
    assert!(out.join("EGCAL_PROGRAM.jbi").exists());
}
