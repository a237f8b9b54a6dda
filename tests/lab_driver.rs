//! `egcal lab-driver` against emulated devices on loopback (issue #18): the ATI
//! Net F/T (calibration over HTTP, RDT over UDP) and a cable-robot controller
//! over egcal's UDP protocol, served by `tests/lab/cell_emulator.py` (Python,
//! written from the vendors' protocol descriptions, independent of egcal's
//! clients). egcal's own external-driver client talks to the lab driver, so each
//! fault is checked as the measure stage sees it: the error's code and whether
//! the campaign retries the row, records it as failed or stops.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use egcal::rig::driver::ExternalDriver;
use egcal::rig::protocol::ErrorCode;
use egcal::rig::{Disposition, Rig, RigError};

/// The emulator process, killed when dropped.
struct Emulator {
    child: Child,
    ports: serde_json::Value,
    faults: PathBuf,
    _dir: tempfile::TempDir,
}

impl Emulator {
    fn start() -> Emulator {
        Emulator::start_rws(1)
    }

    /// The emulator with its ABB controller speaking RWS `version`.
    fn start_rws(version: u8) -> Emulator {
        Emulator::start_with(version, &[])
    }

    /// The emulator with RWS `version` and further arguments (`--sim-driver …`).
    fn start_with(version: u8, extra: &[String]) -> Emulator {
        let dir = tempfile::tempdir().unwrap();
        let ready = dir.path().join("ready.json");
        let faults = dir.path().join("faults.json");
        std::fs::write(&faults, "{}").unwrap();
        // Its log (a line per request and injected fault) stays beside the test's files.
        let log = std::fs::File::create(dir.path().join("emulator.log")).unwrap();
        let child = Command::new("python3")
            .arg(common::root().join("tests/lab/cell_emulator.py"))
            .arg("--ready-file")
            .arg(&ready)
            .arg("--faults")
            .arg(&faults)
            .args(["--rws-version", &version.to_string()])
            .args(extra)
            .stderr(log)
            .spawn()
            .expect("python3 runs the emulator");
        let deadline = Instant::now() + Duration::from_secs(20);
        while !ready.exists() {
            assert!(Instant::now() < deadline, "the emulator did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
        let ports = serde_json::from_str(&std::fs::read_to_string(&ready).unwrap()).unwrap();
        Emulator {
            child,
            ports,
            faults,
            _dir: dir,
        }
    }

    fn log(&self) -> String {
        std::fs::read_to_string(self._dir.path().join("emulator.log")).unwrap_or_default()
    }

    fn port(&self, name: &str) -> u64 {
        self.ports[name].as_u64().unwrap()
    }

    /// Replaces the fault file (atomically: the emulator re-reads it per request).
    fn inject(&self, faults: serde_json::Value) {
        let tmp = self.faults.with_extension("tmp");
        std::fs::write(&tmp, faults.to_string()).unwrap();
        std::fs::rename(&tmp, &self.faults).unwrap();
    }

    /// A cell file for this emulator's devices, with `extra` lines appended to
    /// the force sensor's table.
    fn cell(&self, dir: &Path, force_sensor_extra: &str) -> PathBuf {
        let path = dir.join("cell.toml");
        std::fs::write(
            &path,
            format!(
                r#"[cell]
name = "emulated"
timeout_s = 1.0

[robot]
kind = "abb_rws"
address = "127.0.0.1"
port = {rws}
rws_version = {rws_version}
move_timeout_s = 1.0
poll_ms = 5

[force_sensor]
kind = "ati_netft"
address = "127.0.0.1"
http_port = {http}
rdt_port = {rdt}
samples = 20
{force_sensor_extra}

[cable_robot]
kind = "egcal_udp"
address = "127.0.0.1"
port = {cable}
settle_timeout_s = 2.0
poll_ms = 5
"#,
                http = self.port("ati_http"),
                rdt = self.port("ati_rdt"),
                cable = self.port("cable_robot"),
                rws = self.port("rws"),
                rws_version = self.port("rws_version"),
            ),
        )
        .unwrap();
        path
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `egcal lab-driver` on the cell file, through egcal's driver client.
fn lab_driver(cell: &Path) -> ExternalDriver {
    let command = vec![
        env!("CARGO_BIN_EXE_egcal").to_string(),
        "lab-driver".to_string(),
        "--cell".to_string(),
        cell.display().to_string(),
    ];
    ExternalDriver::start(&command, cell.parent().unwrap(), Duration::from_secs(15))
        .expect("the lab driver starts")
}

/// The error with which `egcal lab-driver` on the cell file fails to start (its
/// `hello`), as the measure stage reports it.
fn failed_start(cell: &Path) -> String {
    let command = vec![
        env!("CARGO_BIN_EXE_egcal").to_string(),
        "lab-driver".to_string(),
        "--cell".to_string(),
        cell.display().to_string(),
    ];
    match ExternalDriver::start(&command, cell.parent().unwrap(), Duration::from_secs(15)) {
        Ok(_) => panic!("the lab driver answered hello"),
        Err(e) => {
            assert!(
                matches!(e, RigError::Fatal(_)) && e.disposition() == Disposition::Stop,
                "{e:?}"
            );
            e.to_string()
        }
    }
}

/// A loopback port nothing listens on.
fn closed_port() -> u16 {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.local_addr().unwrap().port()
}

fn code(result: Result<impl std::fmt::Debug, RigError>) -> (ErrorCode, Disposition, String) {
    let e = result.expect_err("an error");
    (
        e.code().expect("a coded error"),
        e.disposition(),
        e.to_string(),
    )
}

const WRENCH: [f64; 6] = [120.0, -40.0, 300.0, 5.0, -2.5, 1.25];

fn close(a: [f64; 6], b: [f64; 6]) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-3)
}

#[test]
fn a_wrench_applied_by_the_cable_robot_is_read_back_by_the_sensor() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    driver.apply_wrench(WRENCH).unwrap();
    let read = driver.read_wrench().unwrap();
    // Counts of 1e-6 N (cfgcpf = 1e6) with ±2 counts of noise, averaged.
    assert!(close(read, WRENCH), "{read:?}");
    driver.release_wrench().unwrap();
    assert!(close(driver.read_wrench().unwrap(), [0.0; 6]));
    // No tracker in this cell file: named, and the campaign stops.
    let (c, d, message) = code(driver.measure());
    assert_eq!((c, d), (ErrorCode::NotConnected, Disposition::Stop));
    assert!(
        message.contains("[tracker]") && message.contains("cell.toml"),
        "{message}"
    );
}

#[test]
fn the_bias_is_applied_on_request_and_verified() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    {
        // Load the sensor first, then start a driver that biases at start.
        let mut loader = lab_driver(&emulator.cell(dir.path(), ""));
        loader.apply_wrench(WRENCH).unwrap();
    }
    let mut driver = lab_driver(&emulator.cell(dir.path(), "bias_at_start = true"));
    assert!(
        close(driver.read_wrench().unwrap(), [0.0; 6]),
        "zeroed at the load"
    );
}

#[test]
fn sensor_faults_are_retried_recorded_or_stop_the_campaign() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    driver.apply_wrench(WRENCH).unwrap();
    let cases = [
        (
            serde_json::json!({"ati": [{"kind": "no_reply", "times": 1}]}),
            ErrorCode::Timeout,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"ati": [{"kind": "stolen", "after": 5, "times": 1}]}),
            ErrorCode::Timeout,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"ati": [{"kind": "stalled_sequence", "times": 1}]}),
            ErrorCode::StaleData,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"ati": [{"kind": "backward_sequence", "times": 1}]}),
            ErrorCode::StaleData,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"ati": [{"kind": "rdt_gap", "times": 1}]}),
            ErrorCode::SequenceGap,
            Disposition::Retry,
        ),
    ];
    for (faults, expected_code, expected_disposition) in cases {
        emulator.inject(faults.clone());
        let (c, d, message) = code(driver.read_wrench());
        assert_eq!(
            (c, d),
            (expected_code, expected_disposition),
            "{faults}: {message}"
        );
        // One faulty request: the next reading is right again.
        assert!(
            close(driver.read_wrench().unwrap(), WRENCH),
            "{faults}: recovered"
        );
    }
}

#[test]
fn malformed_packets_units_and_a_changed_calibration_stop_the_campaign() {
    let cases = [
        (
            serde_json::json!({"ati": [{"kind": "malformed"}]}),
            ErrorCode::Protocol,
            "36",
        ),
        (
            serde_json::json!({"ati_http": [{"kind": "torque_unit", "code": 4, "label": "Nmm"}]}),
            ErrorCode::UnitMismatch,
            "N-mm",
        ),
        (
            serde_json::json!({"ati_http": [{"kind": "calibration_changed", "after": 0}]}),
            ErrorCode::UnitMismatch,
            "calibration changed",
        ),
        (
            serde_json::json!({"ati_http": [{"kind": "malformed"}]}),
            ErrorCode::Protocol,
            "netft",
        ),
    ];
    for (faults, expected_code, words) in cases {
        let emulator = Emulator::start();
        let dir = tempfile::tempdir().unwrap();
        let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
        emulator.inject(faults.clone());
        let (c, d, message) = code(driver.read_wrench());
        assert_eq!(
            (c, d),
            (expected_code, Disposition::Stop),
            "{faults}: {message}"
        );
        assert!(message.contains(words), "{faults}: {message}");
    }
}

#[test]
fn a_box_configured_for_other_units_is_refused_when_the_driver_starts() {
    let emulator = Emulator::start();
    emulator.inject(
        serde_json::json!({"ati_http": [{"kind": "torque_unit", "code": 4, "label": "Nmm"}]}),
    );
    let dir = tempfile::tempdir().unwrap();
    // `hello` fails, naming the device, its address and the units.
    let message = failed_start(&emulator.cell(dir.path(), ""));
    assert!(
        message.contains("configured for N and N-mm, the cell file declares N and N-m")
            && message.contains("[force_sensor] ati_netft at 127.0.0.1")
            && message.contains("cell.toml"),
        "{message}"
    );
    // Declared as the box is configured: accepted, and converted to N·m.
    let mut driver = lab_driver(&emulator.cell(dir.path(), "torque_unit = \"N-mm\""));
    driver.apply_wrench(WRENCH).unwrap();
    let read = driver.read_wrench().unwrap();
    assert!((read[3] - WRENCH[3] / 1000.0).abs() < 1e-6, "{read:?}");
}

#[test]
fn cable_robot_faults_are_retried_recorded_or_stop_the_campaign() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    let cases = [
        (
            serde_json::json!({"cable_robot": [{"kind": "no_reply", "times": 1}]}),
            ErrorCode::Timeout,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"cable_robot": [{"kind": "never_holds"}]}),
            ErrorCode::Timeout,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"cable_robot": [{"kind": "infeasible", "times": 1}]}),
            ErrorCode::OutOfRange,
            Disposition::FailRow,
        ),
        (
            serde_json::json!({"cable_robot": [{"kind": "tension_limit"}]}),
            ErrorCode::OutOfRange,
            Disposition::FailRow,
        ),
        (
            serde_json::json!({"cable_robot": [{"kind": "malformed", "times": 1}]}),
            ErrorCode::Protocol,
            Disposition::Stop,
        ),
        (
            serde_json::json!({"cable_robot": [{"kind": "estop"}]}),
            ErrorCode::Estop,
            Disposition::Stop,
        ),
    ];
    for (faults, expected_code, expected_disposition) in cases {
        emulator.inject(faults.clone());
        let (c, d, message) = code(driver.apply_wrench(WRENCH));
        assert_eq!(
            (c, d),
            (expected_code, expected_disposition),
            "{faults}: {message}"
        );
        emulator.inject(serde_json::json!({}));
        driver.release_wrench().unwrap();
    }
    // An infeasible set-point beyond the emulated controller's limits.
    let (c, d, _) = code(driver.apply_wrench([5000.0, 0.0, 0.0, 0.0, 0.0, 0.0]));
    assert_eq!((c, d), (ErrorCode::OutOfRange, Disposition::FailRow));
}

#[test]
fn a_device_that_dies_mid_command_stops_the_campaign_cleanly() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    driver.apply_wrench(WRENCH).unwrap();
    emulator.inject(serde_json::json!({"ati": [{"kind": "die"}]}));
    let (c, d, _) = code(driver.read_wrench());
    // The box is gone: no records (retried by the campaign) …
    assert_eq!((c, d), (ErrorCode::Timeout, Disposition::Retry));
    // … and its web server with it: the retry cannot reconnect.
    let e = driver.read_wrench().unwrap_err();
    assert!(
        matches!(e.disposition(), Disposition::Retry | Disposition::Stop),
        "{e}"
    );
}

#[test]
fn bad_cell_files_name_the_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let cell = dir.path().join("cell.toml");
    std::fs::write(
        &cell,
        "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"ati_netft\"\naddress = \"127.0.0.1\"\nsamples = 0\n",
    )
    .unwrap();
    let (code, _, stderr) = common::run(
        &["lab-driver", "--cell", cell.to_str().unwrap()],
        dir.path(),
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("cell.toml") && stderr.contains("force_sensor.samples"),
        "{stderr}"
    );
}

const Q: [f64; 6] = [10.0, -20.0, 30.0, 5.0, 40.0, -15.0];

#[test]
fn the_robot_moves_through_the_rapid_loop_over_rws_1_and_2_and_logs_out() {
    for version in [1, 2] {
        let emulator = Emulator::start_rws(version);
        let dir = tempfile::tempdir().unwrap();
        let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
        driver
            .move_joints(7, egcal::robot::joint_array(&Q))
            .unwrap();
        let q = driver.read_joints().unwrap();
        assert!(
            q.iter().zip(Q).all(|(a, b)| (a - b).abs() < 1e-4),
            "RWS {version}: {q:?}"
        );
        drop(driver); // shutdown: mastership released, logged out
        let deadline = Instant::now() + Duration::from_secs(5);
        while !emulator.log().contains("/logout") {
            assert!(
                Instant::now() < deadline,
                "RWS {version}: no logout\n{}",
                emulator.log()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

#[test]
fn controller_faults_are_retried_recorded_or_stop_the_campaign() {
    for version in [1, 2] {
        let emulator = Emulator::start_rws(version);
        let dir = tempfile::tempdir().unwrap();
        let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
        let cases = [
            (
                serde_json::json!({"rws": [{"kind": "no_reply", "hold_s": 3, "times": 1}]}),
                ErrorCode::Timeout,
                Disposition::Retry,
            ),
            (
                serde_json::json!({"rws": [{"kind": "never_done"}]}),
                ErrorCode::Timeout,
                Disposition::Retry,
            ),
            (
                serde_json::json!({"rws": [{"kind": "mastership_held", "times": 1}]}),
                ErrorCode::ExclusiveOwner,
                Disposition::Stop,
            ),
            (
                serde_json::json!({"rws": [{"kind": "motors_off"}]}),
                ErrorCode::NotReady,
                Disposition::Stop,
            ),
            (
                serde_json::json!({"rws": [{"kind": "guard_stop"}]}),
                ErrorCode::Estop,
                Disposition::Stop,
            ),
            (
                serde_json::json!({"rws": [{"kind": "emergency_stop"}]}),
                ErrorCode::Estop,
                Disposition::Stop,
            ),
            (
                serde_json::json!({"rws": [{"kind": "manual_mode"}]}),
                ErrorCode::NotReady,
                Disposition::Stop,
            ),
            (
                serde_json::json!({"rws": [{"kind": "execution_stopped"}]}),
                ErrorCode::NotReady,
                Disposition::Stop,
            ),
        ];
        for (faults, expected_code, expected_disposition) in cases {
            emulator.inject(faults.clone());
            let (c, d, message) = code(driver.move_joints(1, egcal::robot::joint_array(&Q)));
            assert_eq!(
                (c, d),
                (expected_code, expected_disposition),
                "RWS {version} {faults}: {message}"
            );
            emulator.inject(serde_json::json!({}));
            // Cleared: the next move goes through.
            driver
                .move_joints(2, egcal::robot::joint_array(&Q))
                .unwrap();
        }
        // A target beyond the controller's joint limits: RAPID refuses it, the row fails.
        let (c, d, message) = code(driver.move_joints(3, [200.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0]));
        assert_eq!(
            (c, d),
            (ErrorCode::OutOfRange, Disposition::FailRow),
            "{message}"
        );
        assert!(message.contains("ERRNO"), "{message}");
    }
}

#[test]
fn an_exhausted_session_pool_is_retried_until_a_session_is_free() {
    let emulator = Emulator::start();
    emulator.inject(serde_json::json!({"rws": [{"kind": "pool_exhausted"}]}));
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    let (c, d, message) = code(driver.read_joints());
    assert_eq!((c, d), (ErrorCode::Busy, Disposition::Retry), "{message}");
    assert!(message.contains("503"), "{message}");
    emulator.inject(serde_json::json!({}));
    driver.read_joints().unwrap();
}

#[test]
fn a_controller_that_dies_stops_the_campaign() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    driver
        .move_joints(1, egcal::robot::joint_array(&Q))
        .unwrap();
    emulator.inject(serde_json::json!({"rws": [{"kind": "die"}]}));
    let e = driver
        .move_joints(2, egcal::robot::joint_array(&Q))
        .unwrap_err();
    assert!(
        matches!(e.code(), Some(ErrorCode::NotConnected | ErrorCode::Timeout)),
        "{e}"
    );
    // Gone for good: reconnecting fails and the campaign stops.
    let (c, d, _) = code(driver.move_joints(3, egcal::robot::joint_array(&Q)));
    assert_eq!((c, d), (ErrorCode::NotConnected, Disposition::Stop));
}

/// The simulator backend of the emulated devices: egcal's own `sim-driver` on
/// the spec's truth robot, seeded as the in-process campaign below.
fn backed_emulator(seed: u64) -> Emulator {
    let root = common::root();
    let backend = serde_json::json!([
        env!("CARGO_BIN_EXE_egcal"),
        "sim-driver",
        "--robot",
        root.join("jobs/robots/irb1600_145.toml"),
        "--truth",
        root.join("jobs/truth/irb1600_paper.parquet"),
        "--seed",
        seed.to_string(),
    ]);
    // The controller's joint limits: the robot file's.
    let spec = egcal::robot::RobotSpec::load(&root.join("jobs/robots/irb1600_145.toml")).unwrap();
    let limits: Vec<[f64; 2]> = spec.joints.iter().map(|j| j.limits()).collect();
    Emulator::start_with(
        2,
        &[
            "--sim-driver".to_string(),
            backend.to_string(),
            "--joint-limits".to_string(),
            serde_json::to_string(&limits).unwrap(),
        ],
    )
}

/// The cell file of all four emulated devices.
fn full_cell(emulator: &Emulator, dir: &Path) -> PathBuf {
    let cell = emulator.cell(dir, "");
    let mut text = std::fs::read_to_string(&cell).unwrap();
    text += &format!(
        "\n[tracker]\nkind = \"leica_emscon\"\naddress = \"127.0.0.1\"\nport = {}\nreflector_id = 1\nstationary_time_ms = 10\n",
        emulator.port("tracker")
    );
    std::fs::write(&cell, text).unwrap();
    cell
}

fn column(path: &Path, name: &str) -> Vec<f64> {
    let df = egcal::table::read_parquet(path).unwrap();
    egcal::table::schema::f64_values(&df, name, path).unwrap()
}

#[test]
fn a_campaign_through_the_lab_driver_gives_the_simulators_rows() {
    const SEED: u64 = 11;
    let emulator = backed_emulator(SEED);
    let lab = tempfile::tempdir().unwrap();
    let cell = full_cell(&emulator, lab.path());
    let job = common::measure_job(
        lab.path(),
        &format!(
            "driver = \"external\"\ncommand = [\"{}\", \"lab-driver\", \"--cell\", \"{}\"]\ntimeout_s = 20.0\n",
            env!("CARGO_BIN_EXE_egcal"),
            cell.display()
        ),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], lab.path());
    assert_eq!(code, 0, "{stderr}\n{}", emulator.log());
    let simulated = tempfile::tempdir().unwrap();
    let job = common::measure_job(
        simulated.path(),
        &format!("driver = \"simulator\"\nseed = {SEED}\n"),
    );
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], simulated.path());
    assert_eq!(code, 0, "{stderr}");
    let lab_rows = lab.path().join("out/measure/measurements.parquet");
    let sim_rows = simulated.path().join("out/measure/measurements.parquet");
    let failures = lab.path().join("out/measure/measurement_failures.parquet");
    let df = egcal::table::read_parquet(&failures).unwrap();
    let reasons = egcal::table::schema::str_values(&df, "reason", &failures).unwrap();
    assert!(reasons.is_empty(), "{reasons:?}");
    assert_eq!(column(&lab_rows, "x_mm").len(), 15);
    // Within the emulated devices' quantisation: RWS reports joints with 4
    // decimals, the ATI box counts 1e-6 N and N·m (±2 counts of noise), and the
    // commanded joints reach the robot as a RAPID literal with 6 decimals (5e-7°,
    // about 2e-5 mm at the IRB 1600's reach), which the tracker then sees.
    for (names, tolerance) in [
        (&egcal::table::schema::JOINT_COLUMNS[..], 6e-5),
        (&egcal::table::schema::WRENCH_COLUMNS[..], 3e-6),
        (&egcal::table::schema::POSITION_COLUMNS[..], 1e-4),
    ] {
        for name in names {
            for (a, b) in column(&lab_rows, name).iter().zip(column(&sim_rows, name)) {
                assert!((a - b).abs() <= tolerance, "{name}: {a} vs {b}");
            }
        }
    }
    // The tracker's own standard deviations are stored with each point.
    assert!(column(&lab_rows, "sigma_z_mm").iter().all(|s| *s > 0.0));
}

#[test]
fn tracker_faults_are_retried_recorded_or_stop_the_campaign() {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&full_cell(&emulator, dir.path()));
    let (position, sigma) = {
        let p = driver.measure().unwrap();
        (p, driver.measured_sigma_mm())
    };
    assert!(position.iter().any(|v| *v != 0.0));
    assert!(
        sigma.is_some_and(|s| s.iter().all(|v| *v > 0.0)),
        "{sigma:?}"
    );
    let cases = [
        (
            serde_json::json!({"tracker": [{"kind": "beam_lost", "times": 1}]}),
            ErrorCode::BeamLost,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"tracker": [{"kind": "beam_lost_zeros", "times": 1}]}),
            ErrorCode::BeamLost,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"tracker": [{"kind": "beam_lost_nan", "times": 1}]}),
            ErrorCode::BeamLost,
            Disposition::Retry,
        ),
        (
            serde_json::json!({"tracker": [{"kind": "not_warmed_up", "times": 1}]}),
            ErrorCode::NotReady,
            Disposition::Retry,
        ),
    ];
    for (faults, expected_code, expected_disposition) in cases {
        emulator.inject(faults.clone());
        let (c, d, message) = code(driver.measure());
        assert_eq!(
            (c, d),
            (expected_code, expected_disposition),
            "{faults}: {message}"
        );
        assert_eq!(driver.measure().unwrap(), position, "{faults}: recovered");
    }
    emulator.inject(serde_json::json!({"tracker": [{"kind": "wrong_units", "times": 1}]}));
    let (c, d, message) = code(driver.measure());
    assert_eq!(
        (c, d),
        (ErrorCode::UnitMismatch, Disposition::Stop),
        "{message}"
    );
    emulator.inject(serde_json::json!({"tracker": [{"kind": "malformed", "times": 1}]}));
    let (c, d, message) = code(driver.measure());
    assert_eq!(
        (c, d),
        (ErrorCode::Protocol, Disposition::Stop),
        "{message}"
    );
}

/// A measure job of the fixture's 15 rows through the lab driver on `cell`.
fn lab_job(dir: &Path, cell: &Path) -> PathBuf {
    common::measure_job(
        dir,
        &format!(
            "driver = \"external\"\ncommand = [\"{}\", \"lab-driver\", \"--cell\", \"{}\"]\ntimeout_s = 20.0\nretries = 2\n",
            env!("CARGO_BIN_EXE_egcal"),
            cell.display()
        ),
    )
}

#[test]
fn a_campaign_retries_records_and_resumes_as_the_faults_say() {
    let emulator = backed_emulator(5);
    let dir = tempfile::tempdir().unwrap();
    let cell = full_cell(&emulator, dir.path());
    let job = lab_job(dir.path(), &cell);
    // Joints in radians where degrees are declared, a beam break: caught, retried,
    // recovered. An infeasible wrench: that row recorded as failed. Then an
    // emergency stop on the cable robot: the campaign stops with the rows before kept.
    emulator.inject(serde_json::json!({
        "rws": [{"kind": "radians", "times": 1}],
        "tracker": [{"kind": "beam_lost", "times": 1}],
        "cable_robot": [{"kind": "infeasible", "times": 1}],
    }));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("retrying"), "{stderr}");
    let failures = dir.path().join("out/measure/measurement_failures.parquet");
    let df = egcal::table::read_parquet(&failures).unwrap();
    let reasons = egcal::table::schema::str_values(&df, "reason", &failures).unwrap();
    assert_eq!(reasons.len(), 1, "{reasons:?}");
    assert!(
        reasons[0]
            .as_deref()
            .unwrap()
            .starts_with("out_of_range: cable robot"),
        "{reasons:?}"
    );
    let rows = dir.path().join("out/measure/measurements.parquet");
    assert_eq!(column(&rows, "x_mm").len(), 14);

    // Again from the start, with an emergency stop a few rows in (after 20 of
    // the cable robot's requests: a row takes about seven).
    let dir = tempfile::tempdir().unwrap();
    let cell = full_cell(&emulator, dir.path());
    let job = lab_job(dir.path(), &cell);
    emulator.inject(serde_json::json!({"cable_robot": [{"kind": "estop", "after": 20}]}));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 3, "{stderr}");
    assert!(
        stderr.contains("estop: cable robot") && stderr.contains("rows measured so far are kept"),
        "{stderr}"
    );
    emulator.inject(serde_json::json!({}));
    let (code, _, stderr) = common::run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "resumed: {stderr}");
    assert_eq!(
        column(&dir.path().join("out/measure/measurements.parquet"), "x_mm").len(),
        15
    );
}

#[test]
fn the_shipped_example_cell_file_is_valid() {
    let cell = egcal::lab::CellFile::load(&common::root().join("jobs/lab/cell.toml")).unwrap();
    assert!(cell.robot.is_some() && cell.tracker.is_some());
    assert!(cell.force_sensor.is_some() && cell.cable_robot.is_some());
}

/// A reading whose records carry the status word `word`: its outcome, and the
/// next reading (without the fault) is right again.
fn reading_with_status(word: u32) -> Result<(), (ErrorCode, Disposition, String)> {
    let emulator = Emulator::start();
    let dir = tempfile::tempdir().unwrap();
    let mut driver = lab_driver(&emulator.cell(dir.path(), ""));
    driver.apply_wrench(WRENCH).unwrap();
    emulator.inject(serde_json::json!({"ati": [{"kind": "status", "word": word, "times": 1}]}));
    let outcome = match driver.read_wrench() {
        Ok(read) => {
            assert!(close(read, WRENCH), "0x{word:08x}: {read:?}");
            Ok(())
        }
        Err(e) => Err(code(Err::<(), _>(e))),
    };
    assert!(
        close(driver.read_wrench().unwrap(), WRENCH),
        "0x{word:08x}: recovered"
    );
    outcome
}

/// One test per status word of the ATI manual (9620-05, system status code):
/// the code, what the campaign does, and the bit's name in the message.
macro_rules! status_word {
    ($name:ident, $word:expr, ok) => {
        #[test]
        fn $name() {
            assert_eq!(reading_with_status($word), Ok(()));
        }
    };
    ($name:ident, $word:expr, $code:expr, $disposition:expr, $words:expr) => {
        #[test]
        fn $name() {
            let word: u32 = $word;
            let (c, d, message) = reading_with_status(word).unwrap_err();
            assert_eq!((c, d), ($code, $disposition), "{message}");
            assert!(
                message.contains($words) && message.contains(&format!("0x{word:08x}")),
                "{message}"
            );
        }
    };
}

status_word!(
    status_0x00010000_a_latched_monitor_condition_is_a_reading,
    0x0001_0000,
    ok
);
status_word!(
    status_0x88000000_gage_out_of_range_records_the_row,
    0x8800_0000,
    ErrorCode::OutOfRange,
    Disposition::FailRow,
    "gage out of range"
);
status_word!(
    status_0xc0000000_ft_out_of_range_records_the_row,
    0xC000_0000,
    ErrorCode::OutOfRange,
    Disposition::FailRow,
    "F/T out of range"
);
status_word!(
    status_0xa0000000_calibration_checksum_error_stops,
    0xA000_0000,
    ErrorCode::NotReady,
    Disposition::Stop,
    "calibration checksum error"
);
status_word!(
    status_0x80000004_broken_gage_stops,
    0x8000_0004,
    ErrorCode::NotReady,
    Disposition::Stop,
    "broken gage"
);
status_word!(
    status_0x90000000_simulated_error_is_retried,
    0x9000_0000,
    ErrorCode::NotReady,
    Disposition::Retry,
    "simulated error"
);
status_word!(
    status_0x80000008_busy_is_retried,
    0x8000_0008,
    ErrorCode::Busy,
    Disposition::Retry,
    "busy"
);
status_word!(
    status_0x80000002_supply_out_of_range_is_retried,
    0x8000_0002,
    ErrorCode::NotReady,
    Disposition::Retry,
    "supply voltage out of range"
);
status_word!(
    status_0x80000001_temperature_out_of_range_is_retried,
    0x8000_0001,
    ErrorCode::NotReady,
    Disposition::Retry,
    "temperature out of range"
);
status_word!(
    status_0x80000020_other_error_is_retried,
    0x8000_0020,
    ErrorCode::NotReady,
    Disposition::Retry,
    "other error"
);

#[test]
fn a_reading_waits_for_its_samples_at_the_boxs_rdt_rate() {
    // 150 records at comrdtrate 100 Hz take 1.5 s, beyond the cell's 1 s limit
    // of an exchange: the wait is samples / comrdtrate plus that limit.
    let emulator = Emulator::start_with(1, &["--rdt-rate".to_string(), "100".to_string()]);
    let dir = tempfile::tempdir().unwrap();
    let cell = emulator.cell(dir.path(), "");
    let text = std::fs::read_to_string(&cell)
        .unwrap()
        .replace("samples = 20", "samples = 150");
    std::fs::write(&cell, text).unwrap();
    let mut driver = lab_driver(&cell);
    driver.apply_wrench(WRENCH).unwrap();
    let started = Instant::now();
    let read = driver.read_wrench().unwrap();
    assert!(close(read, WRENCH), "{read:?}");
    assert!(started.elapsed() >= Duration::from_millis(1400));
    // Records that stop coming still time out, the message saying what was waited for.
    emulator.inject(serde_json::json!({"ati": [{"kind": "stolen", "after": 10, "times": 1}]}));
    let (c, d, message) = code(driver.read_wrench());
    assert_eq!(
        (c, d),
        (ErrorCode::Timeout, Disposition::Retry),
        "{message}"
    );
    assert!(
        message.contains("10 of 150") && message.contains("comrdtrate 100 Hz"),
        "{message}"
    );
}

#[test]
fn the_reflector_list_is_read_in_each_layout_a_server_answers() {
    // The header's answer (the GetReflectorsRT records alone), and a status-only
    // BasicCommandRT before or after them.
    for answer in ["records", "status_first", "records_first"] {
        let emulator =
            Emulator::start_with(1, &["--reflectors-answer".to_string(), answer.to_string()]);
        let dir = tempfile::tempdir().unwrap();
        let cell = full_cell(&emulator, dir.path());
        let started = Instant::now();
        let mut driver = lab_driver(&cell);
        // No wait for an answer that never comes: the cell's 1 s limit is not reached.
        assert!(
            started.elapsed() < Duration::from_millis(900),
            "{answer}: {:?}",
            started.elapsed()
        );
        let p = driver.measure().unwrap();
        assert!(p.iter().any(|v| *v != 0.0), "{answer}: {p:?}");
        // An id that is not in the list is refused at start, with the list named.
        let text = std::fs::read_to_string(&cell)
            .unwrap()
            .replace("reflector_id = 1", "reflector_id = 7");
        std::fs::write(&cell, text).unwrap();
        drop(driver);
        let message = failed_start(&cell);
        assert!(
            message.contains("reflector_id = 7")
                && message.contains("1 (RRR 1.5in), 2 (RRR 0.5in)")
                && message.contains("[tracker] leica_emscon at 127.0.0.1"),
            "{answer}: {message}"
        );
    }
}

#[test]
fn hello_fails_naming_a_device_that_cannot_be_reached() {
    let dir = tempfile::tempdir().unwrap();
    let cell = dir.path().join("cell.toml");
    for (table, port) in [
        (
            "[robot]\nkind = \"abb_rws\"\naddress = \"127.0.0.1\"\nrws_version = 1\n",
            "",
        ),
        (
            "[tracker]\nkind = \"leica_emscon\"\naddress = \"127.0.0.1\"\nreflector_id = 1\n",
            "",
        ),
        (
            "[force_sensor]\nkind = \"ati_netft\"\naddress = \"127.0.0.1\"\n",
            "http_port",
        ),
    ] {
        let closed = closed_port();
        let key = if port.is_empty() { "port" } else { port };
        std::fs::write(
            &cell,
            format!("[cell]\nname = \"c\"\ntimeout_s = 1.0\n{table}{key} = {closed}\n"),
        )
        .unwrap();
        let message = failed_start(&cell);
        let device = table.lines().next().unwrap();
        assert!(
            message.contains("starting driver")
                && message.contains(device)
                && message.contains(&format!(
                    "127.0.0.1{}{closed}",
                    if port.is_empty() { ":" } else { " (HTTP " }
                ))
                && message.contains("cell.toml"),
            "{message}"
        );
    }
}

#[test]
fn shutdown_logs_out_of_the_controller_before_it_is_answered() {
    use std::io::{BufRead, BufReader, Write};
    for version in [1, 2] {
        let emulator = Emulator::start_rws(version);
        let dir = tempfile::tempdir().unwrap();
        let cell = emulator.cell(dir.path(), "");
        let mut child = Command::new(env!("CARGO_BIN_EXE_egcal"))
            .args(["lab-driver", "--cell"])
            .arg(&cell)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut stdin = child.stdin.take().unwrap();
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        use egcal::rig::protocol::{Call, PROTOCOL_VERSION, Request};
        for (id, call) in [
            Call::Hello {
                protocol: PROTOCOL_VERSION,
            },
            Call::ReadJoints {},
            Call::Shutdown {},
        ]
        .into_iter()
        .enumerate()
        {
            let request = serde_json::to_string(&Request {
                id: id as u64 + 1,
                call,
            })
            .unwrap();
            writeln!(stdin, "{request}").unwrap();
            stdin.flush().unwrap();
            line.clear();
            stdout.read_line(&mut line).unwrap();
            assert!(!line.contains("error"), "RWS {version}: {request}: {line}");
        }
        // Answered: the session is already gone, whatever happens to the driver now.
        assert!(line.contains("\"id\":3"), "{line}");
        let _ = child.kill();
        let _ = child.wait();
        let log = emulator.log();
        assert!(
            log.contains("GET /logout") && log.contains("logged out (0 open)"),
            "RWS {version}: no logout before the shutdown reply\n{log}"
        );
    }
}
