//! End-to-end tests of the runner through the binary: caching, status reasons,
//! kills at arbitrary instants, corrupted cache entries, and job-file errors.

mod common;

use std::path::Path;
use std::time::Duration;

use common::{run, small_job};
use egcal::table;

fn ran_and_cached(stderr: &str) -> (Vec<String>, Vec<String>) {
    let mut ran = Vec::new();
    let mut cached = Vec::new();
    for line in stderr.lines() {
        if let Some((stage, rest)) = line.split_once(": ") {
            if rest.starts_with("running") {
                ran.push(stage.to_string());
            } else if rest == "cached" {
                cached.push(stage.to_string());
            }
        }
    }
    ran.sort();
    cached.sort();
    (ran, cached)
}

#[test]
fn second_run_is_fully_cached_and_a_setting_change_reruns_only_descendants() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    let (code, stdout, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stdout}\n{stderr}");
    let (ran, _) = ran_and_cached(&stderr);
    assert_eq!(
        ran,
        [
            "identify",
            "measure",
            "poses",
            "predict_nominal",
            "wrenches"
        ]
    );

    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0);
    let (ran, cached) = ran_and_cached(&stderr);
    assert!(ran.is_empty(), "{stderr}");
    assert_eq!(cached.len(), 5);

    // Change one setting of `identify`: only it is stale.
    let text = std::fs::read_to_string(job).unwrap();
    std::fs::write(
        job,
        text.replace(
            "models = [\"nominal\", \"registered\"]",
            "models = [\"registered\"]",
        ),
    )
    .unwrap();
    let (code, status, _) = run(&["status", job], dir.path());
    assert_eq!(code, 0);
    assert!(
        status.contains("identify             stale: setting `models` changed"),
        "{status}"
    );
    assert!(status.contains("measure              cached"), "{status}");
    let (_, _, stderr) = run(&["run", job], dir.path());
    let (ran, _) = ran_and_cached(&stderr);
    assert_eq!(ran, ["identify"]);

    // Change a setting upstream: it and everything downstream re-run, the
    // independent stage does not.
    let text = std::fs::read_to_string(job).unwrap();
    std::fs::write(job, text.replace("per_config = 3", "per_config = 4")).unwrap();
    let (_, status, _) = run(&["status", job], dir.path());
    assert!(
        status.contains("wrenches             stale: setting `per_config` changed (3 -> 4)"),
        "{status}"
    );
    assert!(
        status.contains("measure              stale: waits on stale upstream wrenches"),
        "{status}"
    );
    assert!(status.contains("predict_nominal      cached"), "{status}");
    let (_, _, stderr) = run(&["run", job], dir.path());
    let (ran, cached) = ran_and_cached(&stderr);
    assert_eq!(ran, ["identify", "measure", "wrenches"]);
    assert_eq!(cached, ["poses", "predict_nominal"]);
}

#[test]
fn an_upstream_rerun_with_identical_output_does_not_cascade() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    assert_eq!(run(&["run", job], dir.path()).0, 0);
    // A setting that changes the key of `poses` but not its output: more
    // orientation attempts than any point needs.
    let text = std::fs::read_to_string(job).unwrap();
    std::fs::write(
        job,
        text.replace(
            "edge_mm = 300.0",
            "edge_mm = 300.0\norientation_attempts = 51",
        ),
    )
    .unwrap();
    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    let (ran, cached) = ran_and_cached(&stderr);
    assert_eq!(ran, ["poses"], "{stderr}");
    assert!(cached.contains(&"wrenches".to_string()));
}

/// Two stages alike but for their ids draw different random streams: each gets
/// its own cache entry (no shared key, so no race on one entry, and neither
/// receives the other's draw as a cache hit).
#[test]
fn twin_stages_with_different_ids_get_their_own_entries_and_draws() {
    let dir = tempfile::tempdir().unwrap();
    let job = common::measure_job(dir.path(), "simulator = { tracker_noise_mm = 0.05 }");
    let text = std::fs::read_to_string(&job).unwrap();
    let twin =
        text[text.find("[[stages]]").unwrap()..].replace("id = \"measure\"", "id = \"twin\"");
    std::fs::write(&job, format!("{text}\n{twin}")).unwrap();
    let job = job.to_str().unwrap();
    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    let (ran, _) = ran_and_cached(&stderr);
    assert_eq!(ran.len(), 2, "{stderr}");
    let x = |stage: &str| {
        let file = dir.path().join(format!("out/{stage}/measurements.parquet"));
        let df = egcal::table::read_parquet(&file).unwrap();
        egcal::table::schema::f64_values(&df, "x_mm", &file).unwrap()
    };
    assert_ne!(x("measure"), x("twin"), "the twins measured the same noise");
    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(ran_and_cached(&stderr).1.len(), 2, "{stderr}");
}

#[test]
fn outputs_carry_provenance() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    assert_eq!(run(&["run", job.to_str().unwrap()], dir.path()).0, 0);
    let provenance = table::read_provenance(&dir.path().join("out/measure/measurements.parquet"))
        .unwrap()
        .unwrap();
    assert_eq!(provenance.job, "small");
    assert_eq!(provenance.stage_id, "measure");
    assert_eq!(provenance.stage_kind, "measure");
    assert_eq!(provenance.cache_key.len(), 64);
    assert!(provenance.input_hashes.contains_key("conf_wrenches"));
    assert!(provenance.input_hashes.contains_key("truth"));
    assert_eq!(provenance.tool_version, env!("CARGO_PKG_VERSION"));
    let (code, shown, _) = run(&["show", "out/measure/measurements.parquet"], dir.path());
    assert_eq!(code, 0);
    assert!(
        shown.contains("\"stage_kind\": \"measure\"") && shown.contains("first 10 rows"),
        "{shown}"
    );
}

#[test]
fn a_corrupted_cache_entry_is_detected_and_recomputed() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    assert_eq!(run(&["run", job], dir.path()).0, 0);
    // Truncate the cached measurements table.
    let cache = dir.path().join("out/.egcal/cache");
    let mut damaged = None;
    for shard in std::fs::read_dir(&cache).unwrap() {
        for entry in std::fs::read_dir(shard.unwrap().path()).unwrap() {
            let file = entry.unwrap().path().join("measurements.parquet");
            if file.exists() {
                let bytes = std::fs::read(&file).unwrap();
                std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
                damaged = Some(file);
            }
        }
    }
    assert!(damaged.is_some());
    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains("measure: cache entry") && stderr.contains("is corrupt"),
        "{stderr}"
    );
    let (ran, _) = ran_and_cached(&stderr);
    assert_eq!(ran, ["measure"]);
    table::read_parquet(&damaged.unwrap()).unwrap();
}

/// Kills `egcal run` at increasing delays; after every kill, each published
/// table and every cache entry that exists must be complete, and a final run
/// must finish with the same data as an uninterrupted one.
#[test]
fn killing_a_run_at_any_instant_leaves_nothing_corrupt() {
    let reference = tempfile::tempdir().unwrap();
    let job = small_job(reference.path(), 6, "");
    assert_eq!(run(&["run", job.to_str().unwrap()], reference.path()).0, 0);

    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 6, "");
    for delay_ms in [5, 30, 80, 150, 250, 400, 600, 900] {
        let mut child = common::egcal()
            .args(["run", "--quiet", job.to_str().unwrap()])
            .current_dir(dir.path())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        assert_everything_readable(&dir.path().join("out"));
    }
    let (code, _, stderr) = run(&["run", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0, "{stderr}");
    for table in [
        "poses/poses",
        "wrenches/candidates",
        "measure/measurements",
        "identify/parameters",
    ] {
        let a =
            table::read_parquet(&reference.path().join(format!("out/{table}.parquet"))).unwrap();
        let b = table::read_parquet(&dir.path().join(format!("out/{table}.parquet"))).unwrap();
        assert_eq!(table::content_hash(&a), table::content_hash(&b), "{table}");
    }
}

fn assert_everything_readable(out: &Path) {
    let Ok(entries) = std::fs::read_dir(out) else {
        return;
    };
    for stage in entries.flatten() {
        let path = stage.path();
        if path.file_name().is_some_and(|n| n == ".egcal") || !path.is_dir() {
            continue;
        }
        for file in std::fs::read_dir(&path).unwrap().flatten() {
            let file = file.path();
            if file.extension().is_some_and(|e| e == "parquet") {
                table::read_parquet(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            }
        }
    }
    let cache = egcal::runner::cache::Cache::new(out.join(".egcal/cache"));
    let Ok(shards) = std::fs::read_dir(cache.root()) else {
        return;
    };
    for shard in shards.flatten() {
        for entry in std::fs::read_dir(shard.path()).unwrap().flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                continue; // an unfinished temporary entry: never looked up
            }
            match cache.lookup(&name) {
                egcal::runner::cache::Lookup::Hit(_) => {}
                other => panic!("cache entry {name}: {other:?}"),
            }
        }
    }
}

#[test]
fn job_file_errors_name_file_line_key_and_hint() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let text = std::fs::read_to_string(&job).unwrap();
    let check = |text: String, expected: &[&str]| {
        std::fs::write(&job, text).unwrap();
        let (code, stdout, stderr) = run(&["check", job.to_str().unwrap()], dir.path());
        assert_eq!(code, 2, "{stdout}{stderr}");
        for e in expected {
            assert!(stderr.contains(e), "expected `{e}` in:\n{stderr}");
        }
    };
    // Misspelt setting, unknown kind and unknown input reported together.
    check(
        text.replace("per_config = 3", "per_confg = 3")
            .replace("kind = \"predict\"", "kind = \"predcit\"")
            .replace("poses = \"poses\"", "poses = \"pose\""),
        &[
            "3 problems in the job file",
            "job.toml:18: stages[1].per_confg: unknown setting `per_confg` for stage kind `wrenches` (did you mean `per_config`?)",
            "stages[4].kind: unknown stage kind `predcit` (did you mean `predict`?)",
            "stages[1].inputs.poses: unknown stage `pose` (did you mean `poses`?)",
        ],
    );
    // A cycle.
    check(
        text.clone()
            + "\n[[stages]]\nid = \"a\"\nkind = \"identify\"\ninputs = { measurements = \"b.measurements\" }\n\n[[stages]]\nid = \"b\"\nkind = \"measure\"\ninputs = { conf_wrenches = \"a.parameters\" }\n",
        &["stages form a cycle: b -> a -> b"],
    );
    // A wrong type with its line.
    check(
        text.replace("per_config = 3", "per_config = \"three\""),
        &["stages[1].per_config", "invalid type"],
    );
    // A missing external file.
    check(
        text.replace(
            "fixtures/predict/nominal/conf_wrenches.parquet",
            "fixtures/nope.parquet",
        ),
        &[
            "stages[4].inputs.conf_wrenches: no file matches",
            "nope.parquet",
        ],
    );
}

#[test]
fn a_bad_external_table_names_file_column_and_row() {
    let dir = tempfile::tempdir().unwrap();
    let bad = common::root().join("fixtures/predict/bad_nan/conf_wrenches.parquet");
    let good = common::root().join("fixtures/predict/nominal/conf_wrenches.parquet");
    let job = small_job(dir.path(), 3, "");
    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace(&*good.to_string_lossy(), &bad.to_string_lossy());
    std::fs::write(&job, text).unwrap();
    let (code, _, stderr) = run(
        &["run", "--only", "predict_nominal", job.to_str().unwrap()],
        dir.path(),
    );
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("bad_nan/conf_wrenches.parquet: column `q3_deg` is NaN at row 4"),
        "{stderr}"
    );
}

#[test]
fn a_live_lock_blocks_and_a_stale_one_is_taken_over() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    std::fs::create_dir_all(dir.path().join("out/.egcal")).unwrap();
    std::fs::write(dir.path().join("out/.egcal/lock"), "1\n").unwrap();
    let (code, _, stderr) = run(&["run", "--only", "predict_nominal", job], dir.path());
    assert_eq!(code, 5, "{stderr}");
    assert!(stderr.contains("another egcal run (pid 1)"), "{stderr}");
    std::fs::write(dir.path().join("out/.egcal/lock"), "4000000000\n").unwrap();
    let (code, _, stderr) = run(&["run", "--only", "predict_nominal", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("taking over a stale lock"), "{stderr}");
}

#[test]
fn dag_lists_every_edge() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let (code, mermaid, _) = run(&["dag", job.to_str().unwrap()], dir.path());
    assert_eq!(code, 0);
    assert!(mermaid.starts_with("flowchart LR"));
    assert!(mermaid.contains("poses -->|poses| wrenches"), "{mermaid}");
    assert!(
        mermaid.contains("measure -->|measurements| identify"),
        "{mermaid}"
    );
    let (_, dot, _) = run(&["dag", "--dot", job.to_str().unwrap()], dir.path());
    assert!(dot.contains("\"wrenches\" -> \"measure\""), "{dot}");
}

/// Every file under `dir` whose name ends in `.tmp`.
fn temps_under(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return found;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.to_string_lossy().ends_with(".tmp") {
            found.push(path);
        } else if entry.file_type().is_ok_and(|t| t.is_dir()) {
            found.extend(temps_under(&path));
        }
    }
    found
}

/// Every published file (outside `.egcal`) with its bytes.
fn published_files(out: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    fn walk(dir: &Path, out: &Path, files: &mut std::collections::BTreeMap<String, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.file_name().is_some_and(|n| n == ".egcal") {
                continue;
            }
            if path.is_dir() {
                walk(&path, out, files);
            } else {
                let name = path.strip_prefix(out).unwrap().display().to_string();
                files.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut files = std::collections::BTreeMap::new();
    walk(out, out, &mut files);
    files
}

/// When a test kills egcal.
enum Kill<'a> {
    After(Duration),
    /// As soon as this holds (polled), or when egcal ends by itself.
    When(&'a dyn Fn() -> bool),
}

/// Starts `egcal` with `args` in `dir`, kills it (SIGKILL) as `kill` says and
/// returns whether temporaries were left under `watch`.
fn kill_egcal(args: &[&str], dir: &Path, watch: &Path, kill: Kill) -> bool {
    let mut child = common::egcal().args(args).current_dir(dir).spawn().unwrap();
    match kill {
        Kill::After(delay) => std::thread::sleep(delay),
        Kill::When(ready) => {
            let started = std::time::Instant::now();
            while !ready()
                && child.try_wait().unwrap().is_none()
                && started.elapsed() < Duration::from_secs(5)
            {}
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    !temps_under(watch).is_empty()
}

/// Kills a fully cached run while it publishes its outputs (they were deleted,
/// so every stage copies its tables out of the cache), at the moment a file is
/// being written and at varied delays. No published table is ever torn, the
/// next run removes the temporaries and says so, and its outputs are identical.
#[test]
fn killing_a_run_while_it_publishes_leaves_no_torn_table_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    assert_eq!(run(&["run", job], dir.path()).0, 0);
    let out = dir.path().join("out");
    let reference = published_files(&out);

    // Each run removes what the previous kill left; the last kill's leftovers
    // are what the final run must report.
    let mut left = 0;
    let mut last_left = false;
    // The last trial kills while a file is written: the final run has leftovers.
    for trial in 0..15u64 {
        for entry in std::fs::read_dir(&out).unwrap().flatten() {
            if entry.file_name() != ".egcal" {
                std::fs::remove_dir_all(entry.path()).unwrap();
            }
        }
        // Alternately while a file is being written and at varied delays.
        let writing = || !temps_under(&out).is_empty();
        let kill = match trial % 2 {
            0 => Kill::When(&writing),
            _ => Kill::After(Duration::from_millis(2 * trial)),
        };
        last_left = kill_egcal(&["run", "--quiet", job], dir.path(), &out, kill);
        left += usize::from(last_left);
        assert_everything_readable(&out);
    }
    eprintln!("{left} of 15 kills left temporary files");

    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    if last_left {
        assert!(
            stderr.contains("temporary file") && stderr.contains("left by a killed run"),
            "{stderr}"
        );
    }
    assert_eq!(temps_under(&out), Vec::<std::path::PathBuf>::new());
    assert_eq!(published_files(&out), reference);
}

/// Files in the cache entries of shard `00` (where the planted ones go, and
/// their temporaries when gc renames them): falls as gc removes them. One
/// folder read per entry, so that polling it is quick.
fn planted_files(cache: &Path) -> usize {
    std::fs::read_dir(cache.join("00")).map_or(0, |entries| {
        entries
            .flatten()
            .map(|e| std::fs::read_dir(e.path()).map_or(0, Iterator::count))
            .sum()
    })
}

/// Copies of a cache entry under new keys (manifests rewritten to match), so
/// that `cache gc` has entries to remove, each with `padding` files more than
/// its manifest lists, so that removing one takes long enough to be killed
/// half-way.
fn plant_unused_entries(cache: &Path, first: usize, count: usize, padding: usize) {
    let shard = std::fs::read_dir(cache).unwrap().flatten().next().unwrap();
    let entry = std::fs::read_dir(shard.path())
        .unwrap()
        .flatten()
        .find(|e| e.file_name().len() == 64);
    let entry = entry.unwrap().path();
    let key = entry.file_name().unwrap().to_str().unwrap().to_string();
    for n in first..first + count {
        let new_key = format!("{:064x}", n);
        let target = cache.join(&new_key[..2]).join(&new_key);
        std::fs::create_dir_all(&target).unwrap();
        for file in std::fs::read_dir(&entry).unwrap().flatten() {
            let name = file.file_name();
            if name == "manifest.json" {
                let text = std::fs::read_to_string(file.path()).unwrap();
                std::fs::write(target.join(&name), text.replace(&key, &new_key)).unwrap();
            } else {
                std::fs::copy(file.path(), target.join(&name)).unwrap();
            }
        }
        for k in 0..padding {
            std::fs::write(target.join(format!("padding-{k}")), b"").unwrap();
        }
    }
}

/// Kills `cache gc` at varied delays while it removes unused entries: no entry
/// is ever left half-deleted under its key, and the next gc removes what the
/// killed ones left and says so; the job is still fully cached afterwards.
#[test]
fn killing_cache_gc_leaves_no_torn_entry_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    assert_eq!(run(&["run", job], dir.path()).0, 0);
    let out = dir.path().join("out");
    let cache = out.join(".egcal/cache");
    let reference = published_files(&out);

    let mut left = 0;
    let mut last_left = false;
    for trial in 0..10 {
        plant_unused_entries(&cache, trial * 6, 6, 30);
        let planted = planted_files(&cache);
        // When a temporary appears (an entry renamed for removal), when the
        // first file goes, or at a delay (gc first waits on the lock's fsync).
        // The last trial leaves a temporary for the final gc to report.
        let removing = || planted_files(&cache) < planted;
        let writing = || !temps_under(&cache).is_empty();
        let kill = match trial % 3 {
            0 => Kill::When(&writing),
            1 => Kill::When(&removing),
            _ => Kill::After(Duration::from_millis(20 * trial as u64)),
        };
        last_left = kill_egcal(&["cache", "gc", job], dir.path(), &cache, kill);
        left += usize::from(last_left);
        assert_everything_readable(&out);
    }
    eprintln!("{left} of 10 kills of cache gc left temporary folders");

    let (code, stdout, stderr) = run(&["cache", "gc", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.starts_with("removed "), "{stdout}");
    if last_left {
        assert!(stdout.contains("left by a killed run"), "{stdout}");
    }
    assert_eq!(temps_under(&out), Vec::<std::path::PathBuf>::new());
    let (code, _, stderr) = run(&["run", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    let (ran, cached) = ran_and_cached(&stderr);
    assert!(ran.is_empty(), "{stderr}");
    assert_eq!(cached.len(), 5);
    assert_eq!(published_files(&out), reference);
}

/// Temporaries planted with the pid of a process that has exited (dead) and
/// with this test's own pid (alive): `run` and `cache gc` remove the first, keep
/// the second, say so, and leave a user's similarly named file alone.
#[test]
fn run_and_cache_gc_remove_dead_writers_temporaries_and_keep_live_ones() {
    if !Path::new("/proc/1/stat").exists() {
        return; // no /proc: nothing can be judged dead, nothing is removed
    }
    let dir = tempfile::tempdir().unwrap();
    let job = small_job(dir.path(), 3, "");
    let job = job.to_str().unwrap();
    assert_eq!(
        run(&["run", "--only", "predict_nominal", job], dir.path()).0,
        0
    );
    let out = dir.path().join("out");
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let live = std::process::id();
    let key = "ab".repeat(32);
    let plant = || {
        let dead_files = [
            out.join(format!("predict_nominal/.predictions.parquet.{dead}.0.tmp")),
            out.join(format!(".egcal/state/.predict_nominal.json.{dead}.1.tmp")),
            out.join(format!(".egcal/cache/ab/.{key}.{dead}.tmp/manifest.json")),
        ];
        for file in &dead_files {
            std::fs::create_dir_all(file.parent().unwrap()).unwrap();
            std::fs::write(file, b"torn").unwrap();
        }
        dead_files
    };
    let live_file = out.join(format!("predict_nominal/.predictions.parquet.{live}.7.tmp"));
    let user_file = out.join(format!("predict_nominal/.notes.{dead}.tmp"));
    std::fs::write(&live_file, b"being written").unwrap();
    std::fs::write(&user_file, b"mine").unwrap();

    let dead_files = plant();
    let (code, _, stderr) = run(&["run", "--only", "predict_nominal", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stderr.contains(&format!(
            "removed 3 temporary files left by a killed run (pid {dead}): "
        )) && stderr.contains(&format!(
            "predict_nominal/.predictions.parquet.{dead}.0.tmp"
        )) && stderr.contains(&format!("kept 1 temporary file of running process {live}")),
        "{stderr}"
    );
    assert!(dead_files.iter().all(|f| !f.exists()));
    assert!(
        !out.join(format!(".egcal/cache/ab/.{key}.{dead}.tmp"))
            .exists()
    );
    assert!(live_file.exists() && user_file.exists());

    let dead_files = plant();
    let (code, stdout, stderr) = run(&["cache", "gc", job], dir.path());
    assert_eq!(code, 0, "{stderr}");
    assert!(
        stdout.contains(&format!(
            "removed 3 temporary files left by a killed run (pid {dead}): "
        )) && stdout.contains(&format!("kept 1 temporary file of running process {live}")),
        "{stdout}"
    );
    assert!(dead_files.iter().all(|f| !f.exists()));
    assert!(live_file.exists() && user_file.exists());

    // Nothing left: nothing said.
    std::fs::remove_file(&live_file).unwrap();
    let (_, _, stderr) = run(&["run", "--only", "predict_nominal", job], dir.path());
    assert!(!stderr.contains("temporary file"), "{stderr}");
}
