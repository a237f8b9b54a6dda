//! The embedded executor (`egcal fleet run`): every robot-night of the fleet on
//! this machine, `jobs` at a time, then the night gathered.
//!
//! Nights run in this process on worker threads (the numeric stages share one
//! rayon pool), each with its own output folder and lock. A night already
//! decided is not run again, so a killed `fleet run` restarts where it stopped.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::gather::{self, Gathered};
use super::manifest::Manifest;
use super::night::{self, night_line};
use super::{Fleet, FleetError};

/// How `fleet run` runs.
#[derive(Debug, Clone, Copy)]
pub struct LocalOptions {
    pub run_date: i64,
    /// Robot-nights at once (at least 1).
    pub jobs: usize,
    /// No line per night.
    pub quiet: bool,
}

/// Runs the night of every robot not yet decided, then gathers the night.
pub fn run(fleet: &Fleet, options: &LocalOptions) -> Result<Gathered, FleetError> {
    let jobs = options.jobs.clamp(1, fleet.robots.len().max(1));
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let stages_at_once = (cores / jobs).max(1);
    night::check_template(fleet)?;
    Manifest::new(fleet, options.run_date, "local", 1).write(fleet, options.run_date)?;
    let next = AtomicUsize::new(0);
    let first_error: Mutex<Option<FleetError>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(robot) = fleet.robots.get(i) else {
                        break;
                    };
                    let ran = night::already_decided(fleet, robot, options.run_date).and_then(
                        |decided| {
                            (!decided)
                                .then(|| {
                                    night::run_night(
                                        fleet,
                                        robot,
                                        options.run_date,
                                        None,
                                        stages_at_once,
                                    )
                                })
                                .transpose()
                        },
                    );
                    match ran {
                        Ok(record) if !options.quiet => {
                            eprintln!("{}", night_line(robot, record.as_ref()))
                        }
                        Ok(_) => {}
                        Err(e) => {
                            let mut slot = first_error.lock().unwrap_or_else(|p| p.into_inner());
                            slot.get_or_insert(e);
                            break;
                        }
                    }
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    gather::gather(fleet, options.run_date)
}
