//! `egcal test` and `egcal test record` from the command line (issue #19): the
//! shipped fixtures pass and their JUnit report parses back; a changed expected
//! value, a malformed case file, a hung stage and a missing folder are reported
//! as such; a recorded case passes, then fails when its stage's output changes.

mod common;

use std::path::{Path, PathBuf};

use polars::prelude::*;

/// Copies a shipped case folder to `to` (a case keeps working elsewhere once its
/// robot path is made absolute).
fn copy_case(case: &str, to: &Path) {
    let from = common::root().join("fixtures").join(case);
    copy_dir(&from, to);
    let file = to.join("case.toml");
    let text = std::fs::read_to_string(&file).unwrap().replace(
        "robot = \"../../../jobs/robots/irb1600_145.toml\"",
        &format!(
            "robot = \"{}\"",
            common::root()
                .join("jobs/robots/irb1600_145.toml")
                .display()
        ),
    );
    std::fs::write(file, text).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap().flatten() {
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

fn egcal_test(args: &[&str], dir: &Path) -> (i32, String, String) {
    let mut all = vec!["test"];
    all.extend_from_slice(args);
    common::run(&all, dir)
}

/// An XML element: name, attributes, text.
type Element = (String, Vec<(String, String)>, String);

/// (name, attributes) of every element of an XML document, in document order,
/// and the text of `failure`/`error` elements; panics on malformed XML.
fn parse_xml(text: &str) -> Vec<Element> {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_str(text);
    let mut elements: Vec<Element> = Vec::new();
    let mut open: Vec<usize> = Vec::new();
    loop {
        match reader.read_event().expect("well-formed XML") {
            event @ (Event::Start(_) | Event::Empty(_)) => {
                let (Event::Start(e) | Event::Empty(e)) = &event else {
                    unreachable!()
                };
                let attributes = e
                    .attributes()
                    .map(|a| {
                        let a = a.expect("well-formed attribute");
                        (
                            String::from_utf8(a.key.as_ref().to_vec()).unwrap(),
                            a.unescape_value().expect("escaped value").into_owned(),
                        )
                    })
                    .collect();
                let name = String::from_utf8(e.name().as_ref().to_vec()).unwrap();
                elements.push((name, attributes, String::new()));
                if matches!(event, Event::Start(_)) {
                    open.push(elements.len() - 1);
                }
            }
            Event::Text(t) => {
                if let Some(&i) = open.last() {
                    elements[i].2.push_str(&t.decode().unwrap());
                }
            }
            Event::GeneralRef(r) => {
                if let Some(&i) = open.last() {
                    let name = String::from_utf8(r.to_vec()).unwrap();
                    let resolved =
                        quick_xml::escape::resolve_xml_entity(&name).expect("a predefined entity");
                    elements[i].2.push_str(resolved);
                }
            }
            Event::End(_) => {
                open.pop();
            }
            Event::Eof => break,
            _ => {}
        }
    }
    elements
}

fn attribute<'a>(element: &'a Element, key: &str) -> &'a str {
    element
        .1
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
        .unwrap_or_else(|| panic!("<{}> lacks {key}", element.0))
}

#[test]
fn the_shipped_fixtures_pass_and_their_junit_report_parses_back() {
    let tmp = tempfile::tempdir().unwrap();
    let junit = tmp.path().join("report.xml");
    let (code, stdout, stderr) = egcal_test(
        &["fixtures", "--junit", junit.to_str().unwrap()],
        &common::root(),
    );
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let cases = std::fs::read_dir(common::root().join("fixtures"))
        .unwrap()
        .flatten()
        .flat_map(|kind| {
            std::fs::read_dir(kind.path())
                .into_iter()
                .flatten()
                .flatten()
        })
        .filter(|case| case.path().join("case.toml").is_file())
        .count();
    assert!(
        stdout.contains(&format!("{cases} passed, 0 failed")),
        "{stdout}"
    );
    assert!(
        stdout.contains("ok        fixtures/identify/noiseless_truth ("),
        "{stdout}"
    );

    let elements = parse_xml(&std::fs::read_to_string(&junit).unwrap());
    let root = &elements[0];
    assert_eq!(root.0, "testsuites");
    assert_eq!(attribute(root, "tests"), cases.to_string());
    assert_eq!(attribute(root, "failures"), "0");
    assert_eq!(attribute(root, "errors"), "0");
    let testcases: Vec<_> = elements.iter().filter(|e| e.0 == "testcase").collect();
    assert_eq!(testcases.len(), cases);
    let suites: Vec<_> = elements.iter().filter(|e| e.0 == "testsuite").collect();
    let in_suites: usize = suites
        .iter()
        .map(|s| attribute(s, "tests").parse::<usize>().unwrap())
        .sum();
    assert_eq!(in_suites, cases);
    assert!(testcases.iter().any(
        |t| attribute(t, "name") == "fixtures/identify/noiseless_truth"
            && attribute(t, "classname") == "identify"
    ));
    assert!(!elements.iter().any(|e| e.0 == "failure" || e.0 == "error"));
}

#[test]
fn a_changed_expected_value_fails_naming_table_column_row_and_values() {
    let tmp = tempfile::tempdir().unwrap();
    let case = tmp.path().join("cases/identify/noiseless_truth");
    copy_case("identify/noiseless_truth", &case);
    let expected = case.join("expected/parameters.parquet");
    let mut table = egcal::table::read_parquet(&expected).unwrap();
    let row = 4;
    let values: Vec<Option<f64>> = table
        .column("value")
        .unwrap()
        .f64()
        .unwrap()
        .iter()
        .collect();
    let was = values[row].unwrap();
    let changed: Vec<Option<f64>> = values
        .iter()
        .enumerate()
        .map(|(i, v)| if i == row { Some(was + 0.5) } else { *v })
        .collect();
    table
        .replace("value", Column::new("value".into(), changed))
        .unwrap();
    let name = table
        .column("name")
        .unwrap()
        .str()
        .unwrap()
        .get(row)
        .unwrap()
        .to_string();
    let model = table
        .column("model")
        .unwrap()
        .str()
        .unwrap()
        .get(row)
        .unwrap()
        .to_string();
    egcal::table::write_parquet(&mut table, &expected, None).unwrap();

    let junit = tmp.path().join("junit.xml");
    let (code, stdout, _) = egcal_test(&["cases", "--junit", junit.to_str().unwrap()], tmp.path());
    assert_eq!(code, 1, "{stdout}");
    assert!(
        stdout.contains("FAILED    cases/identify/noiseless_truth"),
        "{stdout}"
    );
    let named = format!(
        "table `parameters`, column `value`, row {row} (model = \"{model}\", name = \"{name}\"): expected {:?}, actual {was:?}",
        was + 0.5
    );
    assert!(stdout.contains(&named), "{named}\nnot in\n{stdout}");
    assert!(stdout.contains("0 passed, 1 failed"), "{stdout}");
    let elements = parse_xml(&std::fs::read_to_string(&junit).unwrap());
    let failure = elements
        .iter()
        .find(|e| e.0 == "failure")
        .expect("a failure");
    assert!(attribute(failure, "message").contains(&named));
    assert_eq!(attribute(&elements[0], "failures"), "1");
}

#[test]
fn a_malformed_case_file_exits_2_naming_line_and_key() {
    let tmp = tempfile::tempdir().unwrap();
    copy_case(
        "split/halves_third",
        &tmp.path().join("cases/split/halves_third"),
    );
    let typo = tmp.path().join("cases/split/typo");
    copy_case("split/halves_third", &typo);
    let file = typo.join("case.toml");
    let text = std::fs::read_to_string(&file).unwrap();
    let line = text
        .lines()
        .position(|l| l.starts_with("tolerance"))
        .unwrap()
        + 1;
    std::fs::write(&file, text.replace("tolerance =", "tolerence =")).unwrap();
    let junit = tmp.path().join("junit.xml");
    let (code, stdout, _) = egcal_test(&["cases", "--junit", junit.to_str().unwrap()], tmp.path());
    assert_eq!(code, 2, "{stdout}");
    assert!(stdout.contains("MALFORMED cases/split/typo"), "{stdout}");
    assert!(
        stdout.contains("ok        cases/split/halves_third"),
        "{stdout}"
    );
    assert!(
        stdout.contains(&format!(
            "cases/split/typo/case.toml: line {line}, key `expect"
        )),
        "{stdout}"
    );
    assert!(stdout.contains("tolerence"), "{stdout}");
    assert!(
        stdout.contains("1 passed, 0 failed, 1 malformed"),
        "{stdout}"
    );
    let elements = parse_xml(&std::fs::read_to_string(&junit).unwrap());
    assert_eq!(attribute(&elements[0], "errors"), "1");
    let error = elements
        .iter()
        .find(|e| e.0 == "error")
        .expect("an error element");
    assert_eq!(attribute(error, "type"), "malformed case file");

    // Not TOML at all, and a folder that does not exist.
    std::fs::write(&file, "robot = \"x\nexpect = 1\n").unwrap();
    let (code, stdout, _) = egcal_test(&["cases/split/typo"], tmp.path());
    assert_eq!(code, 2, "{stdout}");
    assert!(
        stdout.contains("invalid TOML") && stdout.contains("line 1"),
        "{stdout}"
    );
    let (code, stdout, stderr) = egcal_test(&["cases", "--junit", "cases"], tmp.path());
    assert_eq!(code, 2);
    assert!(stdout.is_empty(), "nothing ran: {stdout}");
    assert!(stderr.contains("--junit cases: is a folder"), "{stderr}");
    let (code, _, stderr) = egcal_test(&["nowhere"], tmp.path());
    assert_eq!(code, 2);
    assert!(
        stderr.contains("nowhere: no such folder of fixture cases"),
        "{stderr}"
    );
}

#[test]
fn only_selects_cases_and_selecting_none_is_an_error() {
    let root = common::root();
    let (code, stdout, _) = egcal_test(&["--only", "fixtures/split/*"], &root);
    assert_eq!(code, 0, "{stdout}");
    let split_cases = std::fs::read_dir(root.join("fixtures/split"))
        .unwrap()
        .count();
    assert!(
        stdout.contains(&format!("{split_cases} passed, 0 failed")),
        "{stdout}"
    );
    let (code, stdout, _) = egcal_test(&["--only", "halves", "--only", "alternate"], &root);
    assert_eq!(code, 0);
    assert!(stdout.contains("2 passed"), "{stdout}");
    // A glob below the searched folder, and a case run from inside its folder.
    let (code, stdout, _) = egcal_test(&["fixtures", "--only", "split/*"], &root);
    assert_eq!(code, 0);
    assert!(
        stdout.contains(&format!("{split_cases} passed")),
        "{stdout}"
    );
    let (code, stdout, _) = egcal_test(&["."], &root.join("fixtures/split/halves_third"));
    assert_eq!(code, 0, "{stdout}");
    assert!(stdout.contains("1 passed"), "{stdout}");
    let (code, _, stderr) = egcal_test(&["--only", "no_such_case"], &root);
    assert_eq!(code, 2);
    assert!(stderr.contains("matches --only no_such_case"), "{stderr}");
}

#[test]
fn a_stage_that_hangs_fails_after_the_timeout() {
    let tmp = tempfile::tempdir().unwrap();
    let case = tmp.path().join("measure/hangs");
    copy_case("measure/noiseless_simulator", &case);
    let file = case.join("case.toml");
    let text = std::fs::read_to_string(&file).unwrap().replace(
        "[settings]\n",
        "[settings]\ndriver = \"external\"\ncommand = [\"sleep\", \"61.25\"]\n",
    );
    std::fs::write(&file, text).unwrap();
    let (code, stdout, _) = egcal_test(&["measure", "--timeout-s", "2"], tmp.path());
    assert_eq!(code, 1, "{stdout}");
    assert!(
        stdout.contains("still running after 2 s (--timeout-s): killed"),
        "{stdout}"
    );
    // The stage's driver went with it (the stage's process group was killed).
    std::thread::sleep(std::time::Duration::from_millis(200));
    let left = std::process::Command::new("pgrep")
        .args(["-f", "sleep 61.25"])
        .output()
        .unwrap();
    assert!(left.stdout.is_empty(), "driver left running: {:?}", left);
}

/// `test record KIND` arguments: the inputs named from a shipped fixture
/// folder's `<name>.parquet`, a settings file and the case folder to create.
fn record_args(
    kind: &str,
    robot: &str,
    fixture: &str,
    inputs: &[&str],
    settings: &str,
    out: &str,
) -> Vec<String> {
    let fixture = common::root().join("fixtures").join(fixture);
    let mut args: Vec<String> = [
        "test",
        "record",
        kind,
        "--robot",
        robot,
        "--settings",
        settings,
        "--out",
        out,
    ]
    .map(String::from)
    .to_vec();
    for name in inputs {
        args.push("--input".into());
        args.push(format!(
            "{name}={}",
            fixture.join(format!("{name}.parquet")).display()
        ));
    }
    args
}

fn shipped_robot() -> String {
    common::root()
        .join("jobs/robots/irb1600_145.toml")
        .display()
        .to_string()
}

/// Records a `predict` case from the shipped fixture's files into `out`.
fn record_predict(dir: &Path, out: &str) -> (i32, String, String) {
    std::fs::write(dir.join("settings.toml"), "model = \"elastogeometric\"\n").unwrap();
    std::fs::copy(shipped_robot(), dir.join("robot.toml")).unwrap();
    let args = record_args(
        "predict",
        "robot.toml",
        "predict/truth_loaded",
        &["conf_wrenches", "parameters"],
        "settings.toml",
        out,
    );
    common::run(&args.iter().map(String::as_str).collect::<Vec<_>>(), dir)
}

#[test]
fn a_recorded_case_passes_then_fails_when_the_stage_output_changes() {
    let tmp = tempfile::tempdir().unwrap();
    let (code, stdout, stderr) = record_predict(tmp.path(), "cases/predict_truth");
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    assert!(stdout.contains("recorded a `predict` case in"), "{stdout}");
    assert!(stdout.contains("predictions.parquet"), "{stdout}");
    let case = tmp.path().join("cases/predict_truth");
    let text = std::fs::read_to_string(case.join("case.toml")).unwrap();
    assert!(
        text.contains("regression case rather than an independent check"),
        "{text}"
    );
    assert!(
        text.contains("[recorded]") && text.contains("kind = \"predict\""),
        "{text}"
    );
    for file in [
        "robot.toml",
        "conf_wrenches.parquet",
        "parameters.parquet",
        "expected/predictions.parquet",
    ] {
        assert!(case.join(file).is_file(), "{file} missing");
    }
    // No staging folder is left beside the case.
    let beside: Vec<PathBuf> = std::fs::read_dir(tmp.path().join("cases"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(beside, std::slice::from_ref(&case));

    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 0, "{stdout}");
    assert!(
        stdout.contains("cases/predict_truth (recorded)"),
        "{stdout}"
    );
    assert!(
        stdout.contains("1 passed (1 recorded from egcal), 0 failed"),
        "{stdout}"
    );

    // The robot file of the cell changes (a link 1 mm longer): the case fails.
    let robot = case.join("robot.toml");
    let text = std::fs::read_to_string(&robot).unwrap();
    assert!(text.contains("a_mm = 150.0"));
    std::fs::write(&robot, text.replacen("a_mm = 150.0", "a_mm = 151.0", 1)).unwrap();
    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 1, "{stdout}");
    assert!(stdout.contains("table `predictions`, column `"), "{stdout}");

    // A recorded case is never overwritten.
    let (code, _, stderr) = record_predict(tmp.path(), "cases/predict_truth");
    assert_eq!(code, 2);
    assert!(stderr.contains("already exists"), "{stderr}");
}

#[test]
fn recording_a_failing_stage_writes_nothing_and_sweeps_a_killed_recording() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(tmp.path().join("cases")).unwrap();
    // A killed recording's staging folder (its pid is dead).
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let leftover = tmp.path().join(format!("cases/.old.{dead}.0.tmp"));
    std::fs::create_dir_all(leftover.join("expected")).unwrap();

    std::fs::write(tmp.path().join("bad.toml"), "model = \"no_such_model\"\n").unwrap();
    let args = record_args(
        "predict",
        &shipped_robot(),
        "predict/nominal",
        &["conf_wrenches"],
        "bad.toml",
        "cases/bad",
    );
    let (code, _, stderr) = common::run(
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
        tmp.path(),
    );
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("the stage failed (exit 2)"), "{stderr}");
    assert!(stderr.contains("no_such_model"), "{stderr}");
    let left: Vec<_> = std::fs::read_dir(tmp.path().join("cases"))
        .unwrap()
        .flatten()
        .collect();
    assert!(
        left.is_empty(),
        "left behind: {:?}",
        left.iter().map(|e| e.path()).collect::<Vec<_>>()
    );
}

#[test]
fn a_scan_logs_case_records_with_its_log_folder_copied() {
    let tmp = tempfile::tempdir().unwrap();
    let fixture = common::root().join("fixtures/scan_logs/two_robots_window");
    copy_dir(&fixture.join("logs"), &tmp.path().join("logs"));
    let case: toml::Table =
        toml::from_str(&std::fs::read_to_string(fixture.join("case.toml")).unwrap()).unwrap();
    let settings = toml::to_string(case["settings"].as_table().unwrap()).unwrap();
    std::fs::write(tmp.path().join("scan.toml"), settings).unwrap();
    let robot = common::root().join("jobs/robots/irb1600_145.toml");
    let record = |copy: &[&str], out: &str| {
        let mut args = vec![
            "test",
            "record",
            "scan_logs",
            "--robot",
            robot.to_str().unwrap(),
            "--settings",
            "scan.toml",
            "--run-date",
            "2026-03-05",
            "--out",
            out,
        ];
        args.extend_from_slice(copy);
        common::run(&args, tmp.path())
    };
    // Without its logs the case cannot run from its own folder: refused.
    let (code, _, stderr) = record(&[], "cases/without_logs");
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("add it with --copy"), "{stderr}");
    assert!(!tmp.path().join("cases/without_logs").exists());

    let (code, stdout, stderr) = record(&["--copy", "logs"], "cases/window");
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let text = std::fs::read_to_string(tmp.path().join("cases/window/case.toml")).unwrap();
    assert!(text.contains("run_date = \"2026-03-05\""), "{text}");
    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 0, "{stdout}");
    // The recorded selection equals the independent fixture's.
    for table in ["measurements", "selection"] {
        let want =
            egcal::table::read_parquet(&fixture.join(format!("expected/{table}.parquet"))).unwrap();
        let got = egcal::table::read_parquet(
            &tmp.path()
                .join(format!("cases/window/expected/{table}.parquet")),
        )
        .unwrap();
        let differences = egcal::fixture_cases::compare::differences(table, &want, &got, 0.0);
        assert!(differences.is_empty(), "{differences:?}");
    }
}

#[test]
fn a_killed_recording_leaves_no_case_and_its_leftovers_are_removed_next_time() {
    use std::os::unix::process::CommandExt;
    let tmp = tempfile::tempdir().unwrap();
    // A measure stage whose driver never answers: the recording is killed while
    // its stage runs, with the case half built.
    std::fs::write(
        tmp.path().join("hang.toml"),
        "driver = \"external\"\ncommand = [\"sleep\", \"30\"]\ntimeout_s = 20.0\n",
    )
    .unwrap();
    let mut recording = common::egcal()
        .args(record_args(
            "measure",
            &shipped_robot(),
            "measure/noiseless_simulator",
            &["conf_wrenches"],
            "hang.toml",
            "cases/hung",
        ))
        .current_dir(tmp.path())
        .process_group(0)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let pid = recording.id();
    let staging = tmp.path().join(format!("cases/.hung.{pid}.0.tmp"));
    let work = std::env::temp_dir().join(format!("egcal-test-{pid}"));
    let started = std::time::Instant::now();
    while !(staging.join("conf_wrenches.parquet").is_file() && work.join("first").is_dir()) {
        assert!(
            started.elapsed().as_secs() < 60,
            "the recording never started its stage"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_millis(200));
    // SIGKILL to the recording and its stage (and the stage's driver).
    let killed = std::process::Command::new("kill")
        .args(["-s", "KILL", "--", &format!("-{pid}")])
        .status()
        .unwrap();
    assert!(killed.success());
    recording.wait().unwrap();
    assert!(
        staging.is_dir(),
        "the half-built case is where the kill left it"
    );
    assert!(!tmp.path().join("cases/hung").exists(), "no case appeared");

    // The next recording in that folder removes the leftovers, and works.
    let (code, stdout, stderr) = record_predict(tmp.path(), "cases/predict_truth");
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    assert!(
        !staging.exists(),
        "the killed recording's staging folder is removed"
    );
    assert!(
        !work.exists(),
        "the killed recording's work folder is removed"
    );
    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 0, "{stdout}");
    assert!(stdout.contains("1 passed"), "{stdout}");
}

#[test]
fn a_known_bad_file_records_its_error_and_fails_once_it_is_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("s.toml"), "model = \"elastogeometric\"\n").unwrap();
    let bad = record_args(
        "predict",
        &shipped_robot(),
        "predict/bad_nan",
        &["conf_wrenches"],
        "s.toml",
        "cases/nan_row",
    );
    let run = |args: &[String]| {
        common::run(
            &args.iter().map(String::as_str).collect::<Vec<_>>(),
            tmp.path(),
        )
    };
    // Without --expect-error a failing stage is refused, with the hint.
    let (code, _, stderr) = run(&bad);
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("add --expect-error"), "{stderr}");

    let mut args = bad.clone();
    args.push("--expect-error".into());
    let (code, stdout, stderr) = run(&args);
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    assert!(stdout.contains("its error, exit 2"), "{stdout}");
    let case = tmp.path().join("cases/nan_row");
    let text = std::fs::read_to_string(case.join("case.toml")).unwrap();
    assert!(
        text.contains("conf_wrenches.parquet: column `q3_deg` is NaN at row 4"),
        "{text}"
    );
    assert!(
        !text.contains(".tmp/"),
        "no temporary path is expected: {text}"
    );
    assert!(!case.join("expected").exists());
    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 0, "{stdout}");

    // The file is repaired (or egcal starts accepting it): the case fails.
    std::fs::copy(
        common::root().join("fixtures/predict/nominal/conf_wrenches.parquet"),
        case.join("conf_wrenches.parquet"),
    )
    .unwrap();
    let (code, stdout, _) = egcal_test(&["cases"], tmp.path());
    assert_eq!(code, 1, "{stdout}");
    assert!(
        stdout.contains("but the stage succeeded (exit 0)"),
        "{stdout}"
    );

    // --expect-error on a stage that succeeds is refused.
    let mut good = record_args(
        "predict",
        &shipped_robot(),
        "predict/nominal",
        &["conf_wrenches"],
        "s.toml",
        "cases/good",
    );
    good.push("--expect-error".into());
    let (code, _, stderr) = run(&good);
    assert_eq!(code, 3);
    assert!(
        stderr.contains("--expect-error records a stage that fails"),
        "{stderr}"
    );
}
