//! The reference lab driver (`egcal lab-driver --cell CELL.toml`, issue #18):
//! egcal's driver protocol (`schemas/driver-protocol.md`) on stdin/stdout, the
//! devices' own wire protocols on the other side, so a lab with the paper's kind
//! of cell does not write a driver of its own.
//!
//! Devices: an ABB controller over Robot Web Services 1.0 or 2.0 ([`rws`]), a
//! Leica laser tracker over emScon TPI ([`emscon`]), the ATI Net F/T / Ethernet
//! Axia force/torque sensor ([`netft`]) and a cable-robot controller over
//! egcal's UDP protocol ([`cable_robot`]). Each device's failures are the protocol's coded errors, so
//! the measure stage retries, records or stops as the code says. A device the
//! cell file leaves out answers `not_connected` for the methods that need it.

pub mod cable_robot;
pub mod cell;
pub mod emscon;
pub mod http;
pub mod netft;
pub mod rig;
pub mod rws;
pub mod udp;

pub use cell::{CellFile, CellFileError};
pub use rig::LabRig;
