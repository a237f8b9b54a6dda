//! The fleet file: which job every robot runs each night, which robots, their
//! own settings, and how to ask Slurm for the work.
//!
//! ```toml
//! [fleet]
//! name = "plant_1"
//! job = "nightly.toml"                   # `{robot_id}` in it becomes each robot's id
//! robots_from_logs = "out/make_logs"      # or: robots = ["robot_a", "robot_b"]
//!
//! [slurm]
//! nights_per_task = 4
//! time_limit = "01:00:00"
//!
//! [robots.robot_b]
//! vars = { robot_file = "robots/irb1600_145.toml" }
//! stages.gate = { drift_threshold_mm = 0.2 }
//! ```

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::FleetError;
use crate::job::JobOverrides;
use crate::job::overrides::OverrideOrigin;
use crate::job::raw::LineIndex;
use crate::logs::s3::S3Settings;
use crate::logs::{self, LogSource};

/// The `[fleet]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FleetHeader {
    /// Name of the fleet, in messages, Slurm job names and the report.
    pub name: String,
    /// Job template, relative to the fleet file; its `{robot_id}` placeholders
    /// become each robot's id.
    pub job: String,
    /// Output folder, relative to the fleet file; default `out/<name>` beside it.
    /// Each robot's job outputs go to `robots/<robot_id>/` below it, each night's
    /// records to `nights/<YYYY-MM-DD>/`.
    #[serde(default)]
    pub output: Option<String>,
    /// The robots, by id (letters, digits, `_`, `-`, `.`).
    #[serde(default)]
    pub robots: Option<Vec<String>>,
    /// Or: every `robot_id=` folder found under this log folder, glob or
    /// `s3://bucket/prefix`, relative to the fleet file.
    #[serde(default)]
    pub robots_from_logs: Option<String>,
    /// Endpoint, region and plain-HTTP permission for an `s3://` `robots_from_logs`
    /// (each defaults to its `AWS_*` variable).
    #[serde(default)]
    pub s3: S3Settings,
}

/// The `[slurm]` table: how `egcal fleet submit` asks for the work.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SlurmSettings {
    /// Robot-nights one array task runs one after the other: short nights share a
    /// task so that Slurm's per-task overhead does not dominate.
    #[schemars(range(min = 1, max = 100_000))]
    pub nights_per_task: usize,
    /// Partition (`--partition`); the cluster's default when absent.
    pub partition: Option<String>,
    /// Wall-clock limit per task (`--time`), e.g. `"01:00:00"`.
    pub time_limit: Option<String>,
    /// Cores per task (`--cpus-per-task`).
    #[schemars(range(min = 1, max = 4096))]
    pub cpus_per_task: usize,
    /// Memory per task (`--mem`), e.g. `"4G"`.
    pub mem: Option<String>,
    /// Tasks running at once (`%M` of `--array`); 0: no limit. `--max-parallel`
    /// overrides it.
    #[schemars(range(min = 0, max = 1_000_000))]
    pub max_parallel: usize,
    /// Further `sbatch` options, e.g. `["--account=plant1", "--qos=night"]`.
    pub extra_options: Vec<String>,
}

impl Default for SlurmSettings {
    fn default() -> Self {
        SlurmSettings {
            nights_per_task: 4,
            partition: None,
            time_limit: None,
            cpus_per_task: 1,
            mem: None,
            max_parallel: 0,
            extra_options: Vec::new(),
        }
    }
}

/// One robot's own settings.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RobotOverrides {
    /// Values of further placeholders of the job template.
    #[serde(default)]
    pub vars: BTreeMap<String, String>,
    /// Stage id → settings replacing the template's for this robot.
    #[serde(default)]
    #[schemars(with = "BTreeMap<String, BTreeMap<String, serde_json::Value>>")]
    pub stages: BTreeMap<String, toml::Table>,
}

/// The whole file as written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FleetFileRaw {
    pub fleet: FleetHeader,
    #[serde(default)]
    pub slurm: SlurmSettings,
    /// Robot id → its own settings.
    #[serde(default)]
    pub robots: BTreeMap<String, RobotOverrides>,
}

/// A loaded fleet file with paths resolved and its robots listed.
#[derive(Debug, Clone)]
pub struct Fleet {
    /// The fleet file, absolute.
    pub file: PathBuf,
    pub name: String,
    /// The job template, absolute.
    pub job: PathBuf,
    /// The output folder, absolute.
    pub output: PathBuf,
    /// The robots, sorted.
    pub robots: Vec<String>,
    pub slurm: SlurmSettings,
    overrides: BTreeMap<String, RobotOverrides>,
    /// Lines of the fleet file's keys, for problems with a robot's overrides.
    lines: LineIndex,
}

/// `true` for an id safe in paths and file names.
fn is_robot_id(id: &str) -> bool {
    !id.is_empty()
        && id != "."
        && id != ".."
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

impl Fleet {
    /// Reads the fleet file and lists its robots (from the file, or the
    /// `robot_id=` folders of its logs).
    pub fn load(path: &Path) -> Result<Fleet, FleetError> {
        let bad = |key: &str, message: String| FleetError::File {
            file: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad("", format!("cannot read the fleet file: {e}")))?;
        let raw: FleetFileRaw = crate::toml_error::from_str_strict(&text).map_err(|e| match e {
            crate::toml_error::StrictError::Syntax(message) => {
                bad("", format!("invalid TOML: {message}"))
            }
            crate::toml_error::StrictError::Invalid { key, message } => bad(&key, message),
        })?;
        let lines = toml::de::DeTable::parse(&text)
            .map(|table| LineIndex::build(&text, table.get_ref()))
            .unwrap_or_default();
        let file = std::path::absolute(path)
            .map_err(|e| bad("", format!("cannot resolve the path: {e}")))?;
        let dir = file.parent().unwrap_or(Path::new("/")).to_path_buf();
        let header = &raw.fleet;
        if !is_robot_id(&header.name) {
            return Err(bad(
                "fleet.name",
                format!(
                    "`{}`: use letters, digits, `_`, `-` and `.` only",
                    header.name
                ),
            ));
        }
        if raw.slurm.nights_per_task == 0 {
            return Err(bad("slurm.nights_per_task", "must be at least 1".into()));
        }
        if raw.slurm.cpus_per_task == 0 {
            return Err(bad("slurm.cpus_per_task", "must be at least 1".into()));
        }
        let mut robots: Vec<String> = match (&header.robots, &header.robots_from_logs) {
            (Some(_), Some(_)) => {
                return Err(bad(
                    "fleet.robots",
                    "give `robots` or `robots_from_logs`, not both".into(),
                ));
            }
            (None, None) => {
                return Err(bad(
                    "fleet",
                    "no robots: give `robots = [...]` or `robots_from_logs = \"<log folder>\"`"
                        .into(),
                ));
            }
            (Some(list), None) => list.clone(),
            (None, Some(logs)) => {
                let source = LogSource::parse(logs, &dir, &header.s3)
                    .map_err(|e| bad("fleet.robots_from_logs", e))?;
                let ids = logs::partition_robot_ids(&source)
                    .map_err(|e| bad("fleet.robots_from_logs", e.to_string()))?;
                if ids.is_empty() {
                    return Err(bad(
                        "fleet.robots_from_logs",
                        format!("no `robot_id=` folders under {source}"),
                    ));
                }
                ids.into_iter().collect()
            }
        };
        for (i, id) in robots.iter().enumerate() {
            if !is_robot_id(id) {
                return Err(bad(
                    &format!("fleet.robots[{i}]"),
                    format!("robot id `{id}`: use letters, digits, `_`, `-` and `.` only"),
                ));
            }
        }
        robots.sort();
        if let Some(pair) = robots.windows(2).find(|pair| pair[0] == pair[1]) {
            return Err(bad(
                "fleet.robots",
                format!("robot `{}` is listed twice", pair[0]),
            ));
        }
        for (id, overrides) in &raw.robots {
            if robots.binary_search(id).is_err() {
                return Err(bad(
                    &format!("robots.{id}"),
                    format!(
                        "settings for robot `{id}`, which is not in the fleet{}",
                        crate::suggest::did_you_mean(id, robots.iter().map(String::as_str))
                    ),
                ));
            }
            if overrides.vars.contains_key("robot_id") {
                return Err(bad(
                    &format!("robots.{id}.vars.robot_id"),
                    "`robot_id` is the robot's id; it cannot be overridden".into(),
                ));
            }
        }
        let job = dir.join(&header.job);
        if !job.is_file() {
            return Err(bad(
                "fleet.job",
                format!("job template {} not found", job.display()),
            ));
        }
        let output = match &header.output {
            Some(output) => dir.join(output),
            None => dir.join("out").join(&header.name),
        };
        Ok(Fleet {
            file,
            name: header.name.clone(),
            job,
            output,
            robots,
            slurm: raw.slurm,
            overrides: raw.robots,
            lines,
        })
    }

    /// What the job template gets for `robot`: its id as `{robot_id}`, and its
    /// own placeholders and settings.
    pub fn job_overrides(&self, robot: &str) -> JobOverrides {
        let own = self.overrides.get(robot).cloned().unwrap_or_default();
        let mut vars = own.vars;
        vars.insert("robot_id".into(), robot.to_string());
        JobOverrides {
            vars,
            stage_settings: own.stages,
            origin: Some(OverrideOrigin {
                file: self.file.clone(),
                key: format!("robots.{robot}"),
                lines: self.lines.clone(),
            }),
        }
    }

    /// The robots with settings of their own in the fleet file.
    pub fn robots_with_overrides(&self) -> impl Iterator<Item = &str> {
        self.overrides
            .iter()
            .filter(|(_, o)| !o.vars.is_empty() || !o.stages.is_empty())
            .map(|(id, _)| id.as_str())
    }

    /// The output folder of `robot`'s job (its cache lives there across nights).
    pub fn robot_output(&self, robot: &str) -> PathBuf {
        self.output.join("robots").join(robot)
    }

    /// The records of one night.
    pub fn night_dir(&self, run_date: i64) -> PathBuf {
        self.output
            .join("nights")
            .join(crate::table::time::date_string(run_date))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) -> PathBuf {
        std::fs::write(dir.join("nightly.toml"), "").unwrap();
        let path = dir.join("fleet.toml");
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn robots_are_listed_sorted_with_their_overrides() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            dir.path(),
            r#"
[fleet]
name = "p"
job = "nightly.toml"
robots = ["r2", "r1"]
[robots.r2]
vars = { cell = "c7" }
stages.gate = { alpha = 0.05 }
"#,
        );
        let fleet = Fleet::load(&path).unwrap();
        assert_eq!(fleet.robots, ["r1", "r2"]);
        let o = fleet.job_overrides("r2");
        assert_eq!(o.vars["robot_id"], "r2");
        assert_eq!(o.vars["cell"], "c7");
        assert_eq!(o.stage_settings["gate"]["alpha"].as_float(), Some(0.05));
        assert_eq!(fleet.job_overrides("r1").vars.len(), 1);
        assert!(fleet.robot_output("r1").ends_with("out/p/robots/r1"));
    }

    #[test]
    fn robots_come_from_the_partition_folders_of_the_logs() {
        let dir = tempfile::tempdir().unwrap();
        for part in [
            "logs/a/robot_id=r1/date=2026-11-01",
            "logs/b/robot_id=r2/date=2026-11-01",
        ] {
            std::fs::create_dir_all(dir.path().join(part)).unwrap();
        }
        let path = write(
            dir.path(),
            "[fleet]\nname = \"p\"\njob = \"nightly.toml\"\nrobots_from_logs = \"logs\"\n",
        );
        assert_eq!(Fleet::load(&path).unwrap().robots, ["r1", "r2"]);
    }

    #[test]
    fn problems_name_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("robots = [\"a/b\"]", "fleet.robots[0]"),
            ("robots = [\"a\", \"a\"]", "listed twice"),
            ("robots = [\"a\"]\n[robots.b]\nvars = {}", "robots.b"),
            ("robots = [\"a\"]\nrobot = 1", "unknown field `robot`"),
            ("", "no robots"),
            (
                "robots = [\"a\"]\n[slurm]\nnights_per_task = 0",
                "nights_per_task",
            ),
        ];
        for (extra, expected) in cases {
            let path = write(
                dir.path(),
                &format!("[fleet]\nname = \"p\"\njob = \"nightly.toml\"\n{extra}\n"),
            );
            let message = Fleet::load(&path).unwrap_err().to_string();
            assert!(message.contains(expected), "{extra}: {message}");
            assert!(message.contains("fleet.toml"), "{message}");
        }
    }
}
