//! A night's manifest (`nights/<date>/manifest.json`): which robot-nights each
//! task runs, written before any task starts so that a task finds its robots by
//! index alone and gathering knows which records to expect.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::{Fleet, FleetError};
use crate::table::time::date_string;

/// One `sbatch --array` submission covering tasks `first_task ..` of the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ArraySubmission {
    pub job_id: String,
    pub first_task: usize,
    pub tasks: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub fleet: String,
    pub run_date: String,
    /// `local` (`fleet run`) or `slurm` (`fleet submit`).
    pub executor: String,
    /// Task index → the robots it runs, in order.
    pub tasks: Vec<Vec<String>>,
    pub created_at: String,
    /// The Slurm arrays that run the tasks.
    #[serde(default)]
    pub arrays: Vec<ArraySubmission>,
}

impl Manifest {
    /// The fleet's robots in tasks of `per_task` nights each.
    pub fn new(fleet: &Fleet, run_date: i64, executor: &str, per_task: usize) -> Manifest {
        Manifest {
            fleet: fleet.name.clone(),
            run_date: date_string(run_date),
            executor: executor.to_string(),
            tasks: fleet
                .robots
                .chunks(per_task.max(1))
                .map(<[String]>::to_vec)
                .collect(),
            created_at: crate::table::now_rfc3339(),
            arrays: Vec::new(),
        }
    }

    pub fn path(fleet: &Fleet, run_date: i64) -> PathBuf {
        fleet.night_dir(run_date).join("manifest.json")
    }

    pub fn write(&self, fleet: &Fleet, run_date: i64) -> Result<(), FleetError> {
        let path = Manifest::path(fleet, run_date);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| FleetError::io(dir, e))?;
        }
        let json = serde_json::to_string_pretty(self).expect("a manifest serialises");
        crate::fsio::write_bytes_atomic(&path, json.as_bytes())
            .map_err(|e| FleetError::io(&path, e))
    }

    pub fn read(fleet: &Fleet, run_date: i64) -> Result<Manifest, FleetError> {
        let path = Manifest::path(fleet, run_date);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                FleetError::Usage(format!(
                    "no night {} of fleet `{}` was run or submitted ({} not found)",
                    date_string(run_date),
                    fleet.name,
                    path.display()
                ))
            } else {
                FleetError::io(&path, e)
            }
        })?;
        serde_json::from_str(&text).map_err(|e| FleetError::io(&path, format!("bad manifest: {e}")))
    }

    /// The task of each robot.
    pub fn task_of(&self, robot: &str) -> Option<usize> {
        self.tasks.iter().position(|t| t.iter().any(|r| r == robot))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_are_packed_in_order() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("j.toml"), "").unwrap();
        let path = dir.path().join("f.toml");
        std::fs::write(
            &path,
            "[fleet]\nname = \"p\"\njob = \"j.toml\"\nrobots = [\"e\", \"d\", \"c\", \"b\", \"a\"]\n",
        )
        .unwrap();
        let fleet = Fleet::load(&path).unwrap();
        let m = Manifest::new(&fleet, 20_000, "slurm", 2);
        assert_eq!(m.tasks, [vec!["a", "b"], vec!["c", "d"], vec!["e"]]);
        assert_eq!(m.task_of("d"), Some(1));
        m.write(&fleet, 20_000).unwrap();
        assert_eq!(Manifest::read(&fleet, 20_000).unwrap(), m);
        assert!(
            Manifest::read(&fleet, 20_001)
                .unwrap_err()
                .to_string()
                .contains("no night")
        );
    }
}
