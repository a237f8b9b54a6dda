//! egcal: elasto-geometric calibration of industrial robots as reproducible batch
//! jobs. See `ARCHITECTURE.md` for the module map.

pub mod calibration;
pub mod cdpr;
pub mod commands;
pub mod compensation;
pub mod design;
pub mod exit_code;
pub mod export;
pub mod fixture_cases;
pub mod fleet;
pub mod fsio;
pub mod gate;
pub mod iso9283;
pub mod job;
pub mod job_run;
pub mod journal;
pub mod lab;
pub mod ladder;
pub mod logs;
pub mod publish;
pub mod report;
pub mod rig;
pub mod robot;
pub mod runner;
pub mod stages;
pub mod stats;
pub mod suggest;
pub mod table;
pub mod toml_error;
