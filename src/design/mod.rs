//! Experiment design (paper §IV): pose generation with collision and visibility
//! filters, and DETMAX selection by observability.

pub mod collision;
pub mod detmax;
pub mod observability;
pub mod poses;
