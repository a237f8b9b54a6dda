//! The cell's devices behind the [`Rig`] interface, served over the driver
//! protocol by `egcal lab-driver`.
//!
//! Devices connect when the driver starts. `hello` fails, naming the device and
//! its address, when one cannot be reached (refused, no reply in time) or
//! refused what the cell file declares; one that failed with a transient error
//! (a busy controller) is tried again on the next call that needs it, and until
//! then that call answers the connection's error (retried by the campaign).
//! `shutdown` releases every device (the controller's session is logged out)
//! before it is answered.

use std::path::Path;

use super::cable_robot::CableRobot;
use super::cell::{self, CellFile};
use super::emscon::Emscon;
use super::netft::NetFt;
use super::rws::Rws;
use crate::rig::protocol::ErrorCode;
use crate::rig::{Disposition, Rig, RigError};
use crate::robot::MAX_JOINTS;

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

impl LabRig {
    /// Each configured device, its table and kind, address and whether its
    /// connection failed (and why).
    fn devices(&self) -> Vec<(String, Option<&RigError>)> {
        let mut all = Vec::new();
        if let Some(cell::Robot::AbbRws(s)) = &self.cell.robot {
            let port = s.port.unwrap_or(if s.rws_version == 2 { 443 } else { 80 });
            all.push((
                format!("[robot] abb_rws at {}:{port}", s.address),
                slot_error(&self.robot),
            ));
        }
        if let Some(cell::Tracker::LeicaEmscon(s)) = &self.cell.tracker {
            all.push((
                format!("[tracker] leica_emscon at {}:{}", s.address, s.port),
                slot_error(&self.tracker),
            ));
        }
        if let Some(cell::ForceSensor::AtiNetft(s)) = &self.cell.force_sensor {
            all.push((
                format!(
                    "[force_sensor] ati_netft at {} (HTTP {}, RDT {})",
                    s.address, s.http_port, s.rdt_port
                ),
                slot_error(&self.force_sensor),
            ));
        }
        if let Some(cell::CableRobot::EgcalUdp(s)) = &self.cell.cable_robot {
            all.push((
                format!("[cable_robot] egcal_udp at {}:{}", s.address, s.port),
                slot_error(&self.cable_robot),
            ));
        }
        all
    }

    /// Drops every connected device (each releases what it holds), leaving the
    /// slot to reconnect on its next use.
    fn release(&mut self) {
        release(&mut self.robot);
        release(&mut self.tracker);
        release(&mut self.force_sensor);
        release(&mut self.cable_robot);
    }
}

/// Drops a connected device (it releases what it holds); the slot reconnects
/// on its next use.
fn release<D>(slot: &mut Slot<D>) {
    if let Slot::Connected(_) = slot {
        *slot = Slot::Failed(RigError::device(
            ErrorCode::NotConnected,
            true,
            "released by the driver".to_string(),
        ));
    }
}

fn slot_error<D>(slot: &Slot<D>) -> Option<&RigError> {
    match slot {
        Slot::Failed(e) => Some(e),
        _ => None,
    }
}

/// Whether a failed connection fails `hello`: the device cannot be reached
/// (refused, unknown host, no reply in time) or refused the cell file's settings
/// (an error the campaign would not retry). One it would retry (busy) is tried
/// again at the first call instead.
fn fails_hello(e: &RigError) -> bool {
    e.disposition() != Disposition::Retry || e.code() == Some(ErrorCode::Timeout)
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
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; MAX_JOINTS]) -> Result<(), RigError> {
        // An ABB arm over RWS has six joints; `measure` refuses a
        // seven-joint arm on the lab rig.
        self.robot("move_joints")?
            .move_joints(cw_id, std::array::from_fn(|i| q_deg[i]))
    }

    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError> {
        self.cable_robot("apply_wrench")?.apply(wrench)
    }

    fn read_wrench(&mut self) -> Result<[f64; 6], RigError> {
        self.force_sensor()?.read()
    }

    fn read_joints(&mut self) -> Result<[f64; MAX_JOINTS], RigError> {
        self.robot("read_joints")?
            .read_joints()
            .map(|q| crate::robot::joint_array(&q))
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

    fn ready(&mut self) -> Result<(), RigError> {
        let problems: Vec<(String, ErrorCode)> = self
            .devices()
            .into_iter()
            .filter_map(|(device, error)| {
                let e = error.filter(|e| fails_hello(e))?;
                Some((
                    format!("{device} cannot be used: {e}"),
                    e.code().unwrap_or(ErrorCode::NotConnected),
                ))
            })
            .collect();
        let Some((_, code)) = problems.first() else {
            return Ok(());
        };
        let code = *code;
        // The driver is ended after a failed `hello`: log out of what did connect.
        self.release();
        Err(RigError::device(
            code,
            false,
            format!(
                "cell file {}: {}",
                self.file,
                problems
                    .into_iter()
                    .map(|(p, _)| p)
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        ))
    }

    fn shutdown(&mut self) {
        self.release();
    }
}
