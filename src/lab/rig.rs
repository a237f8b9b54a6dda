//! The cell's devices behind the [`Rig`] interface, served over the driver
//! protocol by `egcal lab-driver`.
//!
//! Devices connect when the driver starts; one that fails to connect is tried
//! again on the next call that needs it, and until then that call answers the
//! connection's error (a transient one is retried by the campaign).

use std::path::Path;

use super::cable_robot::CableRobot;
use super::cell::{self, CellFile};
use super::emscon::Emscon;
use super::netft::NetFt;
use super::rws::Rws;
use crate::rig::protocol::ErrorCode;
use crate::rig::{Rig, RigError};

/// A device slot: absent from the cell file, connected, or not (yet).
enum Slot<D> {
    Absent,
    Connected(D),
    Failed(RigError),
}

/// The cell's devices.
pub struct LabRig {
    cell: CellFile,
    file: String,
    robot: Slot<Rws>,
    tracker: Slot<Emscon>,
    force_sensor: Slot<NetFt>,
    cable_robot: Slot<CableRobot>,
    measured_at_us: i64,
    measured_sigma_mm: Option<[f64; 3]>,
}

impl LabRig {
    /// Connects every device of the cell file.
    pub fn connect(cell: CellFile, file: &Path) -> LabRig {
        let mut rig = LabRig {
            cell,
            file: file.display().to_string(),
            robot: Slot::Absent,
            tracker: Slot::Absent,
            force_sensor: Slot::Absent,
            cable_robot: Slot::Absent,
            measured_at_us: 0,
            measured_sigma_mm: None,
        };
        rig.robot = rig.connect_robot();
        rig.tracker = rig.connect_tracker();
        rig.force_sensor = rig.connect_force_sensor();
        rig.cable_robot = rig.connect_cable_robot();
        rig
    }

    pub fn name(&self) -> String {
        format!("egcal lab driver, cell {}", self.cell.cell.name)
    }

    /// The methods the configured devices implement (for `hello`).
    pub fn capabilities(&self) -> Vec<String> {
        let mut methods = vec!["hello", "shutdown"];
        if self.cell.robot.is_some() {
            methods.extend(["move_joints", "read_joints"]);
        }
        if self.cell.tracker.is_some() {
            methods.push("measure");
        }
        if self.cell.force_sensor.is_some() {
            methods.push("read_wrench");
        }
        if self.cell.cable_robot.is_some() {
            methods.extend(["apply_wrench", "release_wrench"]);
        }
        methods.into_iter().map(str::to_string).collect()
    }

    fn connect_robot(&self) -> Slot<Rws> {
        match &self.cell.robot {
            None => Slot::Absent,
            Some(cell::Robot::AbbRws(settings)) => {
                match Rws::connect(settings, self.cell.cell.timeout_s) {
                    Ok(device) => Slot::Connected(device),
                    Err(e) => Slot::Failed(e),
                }
            }
        }
    }

    fn robot(&mut self, method: &str) -> Result<&mut Rws, RigError> {
        if let Slot::Failed(_) = self.robot {
            self.robot = self.connect_robot();
        }
        let absent = self.absent("robot", method);
        ready(&mut self.robot, absent)
    }

    fn connect_tracker(&self) -> Slot<Emscon> {
        match &self.cell.tracker {
            None => Slot::Absent,
            Some(cell::Tracker::LeicaEmscon(settings)) => {
                match Emscon::connect(settings, self.cell.cell.timeout_s) {
                    Ok(device) => Slot::Connected(device),
                    Err(e) => Slot::Failed(e),
                }
            }
        }
    }

    fn tracker(&mut self) -> Result<&mut Emscon, RigError> {
        if let Slot::Failed(_) = self.tracker {
            self.tracker = self.connect_tracker();
        }
        let absent = self.absent("tracker", "measure");
        ready(&mut self.tracker, absent)
    }

    fn connect_force_sensor(&self) -> Slot<NetFt> {
        match &self.cell.force_sensor {
            None => Slot::Absent,
            Some(cell::ForceSensor::AtiNetft(settings)) => {
                match NetFt::connect(settings, self.cell.cell.timeout_s) {
                    Ok(device) => Slot::Connected(device),
                    Err(e) => Slot::Failed(e),
                }
            }
        }
    }

    fn connect_cable_robot(&self) -> Slot<CableRobot> {
        match &self.cell.cable_robot {
            None => Slot::Absent,
            Some(cell::CableRobot::EgcalUdp(settings)) => {
                match CableRobot::connect(settings, self.cell.cell.timeout_s) {
                    Ok(device) => Slot::Connected(device),
                    Err(e) => Slot::Failed(e),
                }
            }
        }
    }

    fn absent(&self, table: &str, method: &str) -> RigError {
        RigError::device(
            ErrorCode::NotConnected,
            false,
            format!(
                "{method} needs a [{table}] device, and the cell file {} has none",
                self.file
            ),
        )
    }

    fn force_sensor(&mut self) -> Result<&mut NetFt, RigError> {
        if let Slot::Failed(_) = self.force_sensor {
            self.force_sensor = self.connect_force_sensor();
        }
        let absent = self.absent("force_sensor", "read_wrench");
        ready(&mut self.force_sensor, absent)
    }

    fn cable_robot(&mut self, method: &str) -> Result<&mut CableRobot, RigError> {
        if let Slot::Failed(_) = self.cable_robot {
            self.cable_robot = self.connect_cable_robot();
        }
        let absent = self.absent("cable_robot", method);
        ready(&mut self.cable_robot, absent)
    }
}

/// The connected device, or why there is none.
fn ready<D>(slot: &mut Slot<D>, absent: RigError) -> Result<&mut D, RigError> {
    match slot {
        Slot::Connected(device) => Ok(device),
        Slot::Failed(e) => Err(e.clone()),
        Slot::Absent => Err(absent),
    }
}

impl Rig for LabRig {
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; 6]) -> Result<(), RigError> {
        self.robot("move_joints")?.move_joints(cw_id, q_deg)
    }

    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError> {
        self.cable_robot("apply_wrench")?.apply(wrench)
    }

    fn read_wrench(&mut self) -> Result<[f64; 6], RigError> {
        self.force_sensor()?.read()
    }

    fn read_joints(&mut self) -> Result<[f64; 6], RigError> {
        self.robot("read_joints")?.read_joints()
    }

    fn measure(&mut self) -> Result<[f64; 3], RigError> {
        let (position_mm, sigma_mm) = self.tracker()?.measure()?;
        self.measured_at_us = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as i64);
        self.measured_sigma_mm = sigma_mm;
        Ok(position_mm)
    }

    fn release_wrench(&mut self) -> Result<(), RigError> {
        self.cable_robot("release_wrench")?.release()
    }

    fn measured_at_us(&self) -> i64 {
        self.measured_at_us
    }

    fn measured_sigma_mm(&self) -> Option<[f64; 3]> {
        self.measured_sigma_mm
    }
}
