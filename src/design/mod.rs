//! Experiment design (paper §IV): pose generation with collision and visibility
//! filters, DETMAX selection by observability, and selection by the predicted
//! uncertainty at the work targets (`work_criterion`); positioner
//! configurations at which the tracker sees a nest (`nest_views`).

pub mod branch_coverage;
pub mod collision;
pub mod detmax;
pub mod nest_views;
pub mod observability;
pub mod poses;
pub mod work_criterion;
