//! `scan_logs` over S3 (issue #17): the synthetic logs of `jobs/make_logs.toml`
//! served by a real S3 server (Garage on loopback, started by `.ci/services.sh`)
//! must give the same measurements, selection and content key as the same files
//! on disk; ETags key the cache by default; only the robot's and window's
//! partitions are listed; a fleet finds its robots in the bucket.
//!
//! Needs `EGCAL_TEST_S3_ENDPOINT`, `EGCAL_TEST_S3_BUCKET` and the `AWS_*`
//! credentials of `.ci/services.sh`'s env.sh; where they are missing the tests say
//! so and skip. The tests of missing credentials and malformed endpoints need no
//! server (a closed loopback port stands for the instance-metadata service) and
//! always run.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use egcal::stages::Stage;
use egcal::stages::scan_logs::{ScanLogsSettings, ScanLogsStage};
use egcal::table;
use object_store::aws::AmazonS3Builder;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStoreExt, PutPayload};

const RUN_DATE: &str = "2026-11-20";

/// The test server's endpoint and bucket, or why the tests skip.
fn server() -> Option<(String, String)> {
    match (
        std::env::var("EGCAL_TEST_S3_ENDPOINT"),
        std::env::var("EGCAL_TEST_S3_BUCKET"),
    ) {
        (Ok(endpoint), Ok(bucket)) => Some((endpoint, bucket)),
        _ => {
            common::skip_without_service("no S3 test server (EGCAL_TEST_S3_ENDPOINT unset)");
            None
        }
    }
}

/// Puts (or replaces) one object.
fn put(bucket: &str, key: &str, bytes: Vec<u8>) {
    let store = AmazonS3Builder::from_env()
        .with_bucket_name(bucket)
        .build()
        .unwrap();
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
        .block_on(store.put(&ObjectPath::from(key), PutPayload::from(bytes)))
        .unwrap();
}

/// The log files of the copy, relative to `out/make_logs`.
fn log_files(dir: &Path) -> Vec<PathBuf> {
    let pattern = dir.join("out/make_logs/*/robot_id=*/date=*/*.parquet");
    glob::glob(&pattern.to_string_lossy())
        .unwrap()
        .map(|p| {
            p.unwrap()
                .strip_prefix(dir.join("out/make_logs"))
                .unwrap()
                .to_path_buf()
        })
        .collect()
}

/// `jobs/` with make_logs run, and its logs uploaded below a prefix of its own:
/// (folder, prefix).
fn prepared(bucket: &str) -> &'static (PathBuf, String) {
    static PREPARED: OnceLock<(PathBuf, String)> = OnceLock::new();
    PREPARED.get_or_init(|| {
        let dir = common::shared_dir("logs_s3_prepared");
        common::copy_dir(&common::root().join("jobs"), &dir, &["out", "calibration"]);
        let (code, stdout, stderr) = common::run(&["-q", "run", "make_logs.toml"], &dir);
        assert_eq!(code, 0, "make_logs: {stdout}{stderr}");
        let prefix = format!(
            "tests/{}-{}/logs",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos()
        );
        for file in log_files(&dir) {
            let bytes = std::fs::read(dir.join("out/make_logs").join(&file)).unwrap();
            put(bucket, &format!("{prefix}/{}", file.display()), bytes);
        }
        (dir, prefix)
    })
}

/// A job of one scan_logs stage over `logs` with `extra` settings.
fn scan_job(dir: &Path, name: &str, logs: &str, extra: &str) -> PathBuf {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(
        &path,
        format!(
            r#"[job]
name = "{name}"
robot = "robots/irb1600_145.toml"

[[stages]]
id = "logs"
kind = "scan_logs"
logs = "{logs}"
robot_id = "robot_a"
last = "14d"
min_rows = 200
{extra}
"#
        ),
    )
    .unwrap();
    path
}

fn settings(logs: &str, content_key: &str) -> ScanLogsSettings {
    toml::from_str(&format!(
        "logs = \"{logs}\"\nrobot_id = \"robot_a\"\ncontent_key = \"{content_key}\""
    ))
    .unwrap()
}

fn key(dir: &Path, settings: &ScanLogsSettings) -> serde_json::Value {
    let day = table::time::parse_date(RUN_DATE).unwrap();
    ScanLogsStage.external_key(settings, dir, day).unwrap()
}

const LOCAL_LOGS: &str = "out/make_logs/*/robot_id=*/date=*/*.parquet";

#[test]
fn s3_gives_the_same_measurements_and_content_key_as_files() {
    let Some((_, bucket)) = server() else {
        return;
    };
    let (dir, prefix) = prepared(&bucket);
    let dir = dir.as_path();
    let url = format!("s3://{bucket}/{prefix}");
    let content = "content_key = \"content\"";
    for (name, logs) in [("on_disk", LOCAL_LOGS), ("on_s3", url.as_str())] {
        let job = scan_job(dir, name, logs, content);
        let (code, stdout, stderr) =
            common::run(&["run", job.to_str().unwrap(), "--run-date", RUN_DATE], dir);
        assert_eq!(code, 0, "{name}: {stdout}{stderr}");
        if name == "on_s3" {
            // Only the robot's 14 days were listed, not robot_b's or older days.
            assert!(stderr.contains("files=14 found"), "{stderr}");
        }
    }
    for table_name in ["measurements", "selection"] {
        let read = |name: &str| {
            table::read_parquet(&dir.join(format!("out/{name}/logs/{table_name}.parquet"))).unwrap()
        };
        let (disk, s3) = (read("on_disk"), read("on_s3"));
        assert_eq!(disk.height(), 700, "14 days of 50 rows");
        assert!(disk.equals_missing(&s3), "{table_name}");
    }
    let disk_key = key(dir, &settings(LOCAL_LOGS, "content"));
    let s3_key = key(dir, &settings(&url, "content"));
    assert_eq!(disk_key, s3_key);
    assert_eq!(s3_key["files"].as_object().unwrap().len(), 14);
}

#[test]
fn etags_key_the_cache_and_follow_a_replaced_object() {
    let Some((_, bucket)) = server() else {
        return;
    };
    // A prefix of this test's own, since it replaces an object.
    let (source, _) = prepared(&bucket);
    let dir = tempfile::tempdir().unwrap();
    common::copy_dir(source.as_path(), dir.path(), &[]);
    let prefix = format!("tests/{}-etag/logs", std::process::id());
    let files = log_files(dir.path());
    for file in &files {
        let bytes = std::fs::read(dir.path().join("out/make_logs").join(file)).unwrap();
        put(&bucket, &format!("{prefix}/{}", file.display()), bytes);
    }
    let url = format!("s3://{bucket}/{prefix}");
    let before = key(dir.path(), &settings(&url, "etag"));
    let tags = before["files"].as_object().unwrap();
    assert_eq!(tags.len(), 14);
    assert!(
        tags.values()
            .all(|t| t.as_str().unwrap().starts_with("etag:")),
        "{before}"
    );
    // The same bytes again: the same key, nothing to re-run.
    let newest = files
        .iter()
        .filter(|f| f.to_string_lossy().contains("robot_id=robot_a"))
        .max()
        .unwrap();
    let bytes = std::fs::read(dir.path().join("out/make_logs").join(newest)).unwrap();
    put(&bucket, &format!("{prefix}/{}", newest.display()), bytes);
    assert_eq!(key(dir.path(), &settings(&url, "etag")), before);
    // Another day's file in its place: a new key.
    let other = files
        .iter()
        .filter(|f| f.to_string_lossy().contains("robot_id=robot_a"))
        .min()
        .unwrap();
    let bytes = std::fs::read(dir.path().join("out/make_logs").join(other)).unwrap();
    put(&bucket, &format!("{prefix}/{}", newest.display()), bytes);
    let after = key(dir.path(), &settings(&url, "etag"));
    assert_ne!(after, before);
    let changed: Vec<&String> = after["files"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, v)| before["files"][k.as_str()] != **v)
        .map(|(k, _)| k)
        .collect();
    assert_eq!(changed, [&newest.to_string_lossy().to_string()]);
}

#[test]
fn a_fleet_finds_its_robots_in_the_bucket() {
    let Some((_, bucket)) = server() else {
        return;
    };
    let (dir, prefix) = prepared(&bucket);
    let fleet = dir.as_path().join("s3_fleet.toml");
    std::fs::write(
        &fleet,
        format!(
            "[fleet]\nname = \"s3\"\njob = \"nightly.toml\"\nrobots_from_logs = \"s3://{bucket}/{prefix}\"\n"
        ),
    )
    .unwrap();
    let loaded = egcal::fleet::Fleet::load(&fleet).unwrap();
    assert_eq!(loaded.robots, ["robot_a", "robot_b"]);
}

#[test]
fn wrong_credentials_or_bucket_fail_with_the_address() {
    let Some((_, bucket)) = server() else {
        return;
    };
    let (source, prefix) = prepared(&bucket);
    let dir = source.as_path();
    let url = format!("s3://{bucket}/{prefix}");
    let job = scan_job(dir, "bad_key", &url, "");
    let out = common::egcal()
        .args(["run", job.to_str().unwrap(), "--run-date", RUN_DATE])
        .current_dir(dir)
        .env("AWS_SECRET_ACCESS_KEY", "0".repeat(64))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains(&url), "{stderr}");
    let job = scan_job(
        dir,
        "bad_bucket",
        &format!("s3://no-such-bucket-egcal/{prefix}"),
        "",
    );
    let (code, _, stderr) =
        common::run(&["run", job.to_str().unwrap(), "--run-date", RUN_DATE], dir);
    assert_eq!(code, 3, "{stderr}");
    assert!(stderr.contains("s3://no-such-bucket-egcal"), "{stderr}");
}

/// egcal with no credentials anywhere: no `AWS_*` key pair or provider, a home
/// without `~/.aws`, and the instance-metadata service on a closed loopback port
/// (so the test needs no server and cannot wait on a real one).
fn without_credentials(home: &Path) -> std::process::Command {
    let mut command = common::egcal();
    for name in [
        "AWS_ACCESS_KEY_ID",
        "AWS_SECRET_ACCESS_KEY",
        "AWS_SESSION_TOKEN",
        "AWS_PROFILE",
        "AWS_SHARED_CREDENTIALS_FILE",
        "AWS_WEB_IDENTITY_TOKEN_FILE",
        "AWS_CONTAINER_CREDENTIALS_RELATIVE_URI",
        "AWS_CONTAINER_CREDENTIALS_FULL_URI",
        "AWS_ENDPOINT_URL",
        "AWS_ENDPOINT",
        "AWS_REGION",
    ] {
        command.env_remove(name);
    }
    command
        .env("HOME", home)
        .env("AWS_METADATA_ENDPOINT", "http://127.0.0.1:9")
        .current_dir(home);
    command
}

#[test]
fn no_credentials_say_where_they_are_looked_for() {
    let dir = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(
        common::root().join("jobs/robots"),
        dir.path().join("robots"),
    )
    .unwrap();
    let job = scan_job(
        dir.path(),
        "no_credentials",
        "s3://egcal-test/plant/logs",
        "s3 = { endpoint = \"http://127.0.0.1:9\", region = \"garage\", allow_http = true }",
    );
    let started = std::time::Instant::now();
    let out = without_credentials(dir.path())
        .args(["run", job.to_str().unwrap(), "--run-date", RUN_DATE])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    for word in [
        "s3://egcal-test/plant/logs",
        "no S3 credentials found",
        "AWS_ACCESS_KEY_ID",
        "~/.aws/credentials",
        "AWS_PROFILE",
    ] {
        assert!(stderr.contains(word), "{word}: {stderr}");
    }
    assert!(
        started.elapsed().as_secs() < 60,
        "took {:?}",
        started.elapsed()
    );

    // A profile that is not there is named at once.
    let out = without_credentials(dir.path())
        .env("AWS_PROFILE", "night")
        .args(["run", job.to_str().unwrap(), "--run-date", RUN_DATE])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("AWS_PROFILE"), "{stderr}");
}

#[test]
fn a_malformed_endpoint_is_refused_before_the_client() {
    let dir = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(
        common::root().join("jobs/robots"),
        dir.path().join("robots"),
    )
    .unwrap();
    let job = scan_job(dir.path(), "bad_endpoint", "s3://egcal-test/logs", "");
    for (variable, value, word) in [
        ("AWS_ENDPOINT_URL", "not a url", "AWS_ENDPOINT_URL"),
        ("AWS_REGION", "eu west", "AWS_REGION"),
        ("AWS_ENDPOINT_URL", "http://127.0.0.1:9", "allow_http"),
    ] {
        let out = without_credentials(dir.path())
            .env("AWS_ACCESS_KEY_ID", "a")
            .env("AWS_SECRET_ACCESS_KEY", "b")
            .env_remove("AWS_ALLOW_HTTP")
            .env(variable, value)
            .args(["run", job.to_str().unwrap(), "--run-date", RUN_DATE])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{variable}={value}: {stderr}");
        assert!(
            stderr.contains(word) && !stderr.contains("panicked"),
            "{variable}={value}: {stderr}"
        );
    }
}
