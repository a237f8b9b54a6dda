//! ATI Net F/T and Ethernet Axia boxes: the calibration (counts per unit, units,
//! serial) from `netftapi2.xml` over HTTP, never hard-coded, and readings from
//! the RDT stream over UDP (big-endian; a request `0x1234, command, count` and
//! 36-byte records `rdt_sequence, ft_sequence, status, 6 × counts`).
//!
//! A reading asks for `samples` records and averages them. It is refused when a
//! record is malformed (`protocol`), when the status word reports an error
//! (saturation: `out_of_range`; anything else: `not_ready`), when `ft_sequence`
//! stalls or goes backwards (`stale_data`), when `rdt_sequence` skips
//! (`sequence_gap`), when the records stop coming (a stream another client took,
//! or no reply: `timeout`), and when the calibration changed since the driver
//! connected (`unit_mismatch`: the scale is no longer the one checked).
//!
//! The box does not acknowledge a software bias (0x0042), so a bias is verified
//! by fresh readings near zero.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use super::cell::{ForceUnit, NetFtSettings, TorqueUnit};
use crate::rig::RigError;
use crate::rig::protocol::ErrorCode;

const HEADER: u16 = 0x1234;
const CMD_STOP: u16 = 0x0000;
const CMD_START_REALTIME: u16 = 0x0002;
const CMD_BIAS: u16 = 0x0042;
const RECORD_BYTES: usize = 36;
/// Status of a healthy box, and the one warning that is not an error (the
/// monitor-condition latch with its summary bit).
const STATUS_LATCH_WARNING: u32 = 0x8001_0000;
const STATUS_SATURATION: u32 = 0x0002_0000;

/// What `netftapi2.xml` says about the active configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub counts_per_force: f64,
    pub counts_per_torque: f64,
    pub force_unit: ForceUnit,
    pub torque_unit: TorqueUnit,
    /// Calibration serial and configuration slot: a change means another scale.
    pub serial: String,
    pub slot: String,
}

/// One RDT record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Record {
    pub rdt_sequence: u32,
    pub ft_sequence: u32,
    pub status: u32,
    pub counts: [i32; 6],
}

fn device(code: ErrorCode, transient: bool, message: String) -> RigError {
    RigError::device(code, transient, format!("force sensor: {message}"))
}

/// The text of `<tag>…</tag>` in a flat XML document.
fn element<'a>(xml: &'a str, tag: &str) -> Option<&'a str> {
    let open = format!("<{tag}>");
    let start = xml.find(&open)? + open.len();
    let end = xml[start..].find(&format!("</{tag}>"))? + start;
    Some(xml[start..end].trim())
}

/// The calibration of a `netftapi2.xml` document.
pub fn parse_calibration(xml: &str) -> Result<Calibration, String> {
    if !xml.contains("<netft>") {
        return Err("netftapi2.xml is not a <netft> document".into());
    }
    let field =
        |tag: &str| element(xml, tag).ok_or_else(|| format!("netftapi2.xml has no <{tag}>"));
    let positive = |tag: &str| -> Result<f64, String> {
        let text = field(tag)?;
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| format!("netftapi2.xml <{tag}> is `{text}`, expected a positive number"))
    };
    let force_unit = match element(xml, "cfgfu") {
        Some(code) => code.parse().ok().and_then(ForceUnit::from_code),
        None => element(xml, "scfgfu").and_then(force_unit_label),
    }
    .ok_or_else(|| "netftapi2.xml names no known force unit (cfgfu/scfgfu)".to_string())?;
    let torque_unit = match element(xml, "cfgtu") {
        Some(code) => code.parse().ok().and_then(TorqueUnit::from_code),
        None => element(xml, "scfgtu").and_then(torque_unit_label),
    }
    .ok_or_else(|| "netftapi2.xml names no known torque unit (cfgtu/scfgtu)".to_string())?;
    Ok(Calibration {
        counts_per_force: positive("cfgcpf")?,
        counts_per_torque: positive("cfgcpt")?,
        force_unit,
        torque_unit,
        serial: element(xml, "cfgcalsn").unwrap_or_default().to_string(),
        slot: element(xml, "setcfgsel").unwrap_or_default().to_string(),
    })
}

fn force_unit_label(label: &str) -> Option<ForceUnit> {
    Some(match label {
        "lbf" => ForceUnit::Lbf,
        "N" => ForceUnit::Newton,
        "klbf" => ForceUnit::Klbf,
        "kN" => ForceUnit::KiloNewton,
        "kgf" => ForceUnit::Kgf,
        "gf" => ForceUnit::Gf,
        _ => return None,
    })
}

fn torque_unit_label(label: &str) -> Option<TorqueUnit> {
    Some(match label {
        "lbf-in" | "lbfin" => TorqueUnit::LbfIn,
        "lbf-ft" | "lbfft" => TorqueUnit::LbfFt,
        "Nm" | "N-m" => TorqueUnit::NewtonMetre,
        "Nmm" | "N-mm" => TorqueUnit::NewtonMillimetre,
        "kgf-cm" | "kg-cm" => TorqueUnit::KgfCm,
        "kNm" | "kN-m" => TorqueUnit::KiloNewtonMetre,
        _ => return None,
    })
}

/// An RDT request.
pub fn request(command: u16, count: u32) -> [u8; 8] {
    let mut bytes = [0u8; 8];
    bytes[0..2].copy_from_slice(&HEADER.to_be_bytes());
    bytes[2..4].copy_from_slice(&command.to_be_bytes());
    bytes[4..8].copy_from_slice(&count.to_be_bytes());
    bytes
}

/// An RDT record, or why the datagram is not one.
pub fn parse_record(datagram: &[u8]) -> Result<Record, String> {
    if datagram.len() != RECORD_BYTES {
        return Err(format!(
            "an RDT datagram of {} bytes, expected {RECORD_BYTES}",
            datagram.len()
        ));
    }
    let u32_at = |i: usize| u32::from_be_bytes(datagram[i..i + 4].try_into().expect("4 bytes"));
    let mut counts = [0i32; 6];
    for (k, c) in counts.iter_mut().enumerate() {
        *c = u32_at(12 + 4 * k) as i32;
    }
    Ok(Record {
        rdt_sequence: u32_at(0),
        ft_sequence: u32_at(4),
        status: u32_at(8),
        counts,
    })
}

/// A connected box.
pub struct NetFt {
    settings: NetFtSettings,
    timeout: Duration,
    socket: UdpSocket,
    calibration: Calibration,
}

impl NetFt {
    /// Reads the calibration, checks its units against the cell file's, opens the
    /// RDT socket and, when asked, biases the sensor.
    pub fn connect(settings: &NetFtSettings, cell_timeout_s: f64) -> Result<NetFt, RigError> {
        let timeout = Duration::from_secs_f64(settings.timeout_s.unwrap_or(cell_timeout_s));
        let socket = super::udp::connect(&settings.address, settings.rdt_port).map_err(|e| {
            device(
                ErrorCode::NotConnected,
                false,
                format!(
                    "cannot open RDT to {}:{}: {e}",
                    settings.address, settings.rdt_port
                ),
            )
        })?;
        let mut netft = NetFt {
            settings: settings.clone(),
            timeout,
            socket,
            calibration: Calibration {
                counts_per_force: 1.0,
                counts_per_torque: 1.0,
                force_unit: settings.force_unit,
                torque_unit: settings.torque_unit,
                serial: String::new(),
                slot: String::new(),
            },
        };
        netft.calibration = netft.fetch_calibration(true)?;
        if settings.bias_at_start {
            netft.bias()?;
        }
        Ok(netft)
    }

    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// `netftapi2.xml`, checked against the declared units (at connect) or the
    /// calibration read at connect (afterwards).
    fn fetch_calibration(&self, connecting: bool) -> Result<Calibration, RigError> {
        let s = &self.settings;
        let (status, body) =
            super::http::get(&s.address, s.http_port, "/netftapi2.xml", self.timeout).map_err(
                |e| {
                    device(
                        if connecting {
                            ErrorCode::NotConnected
                        } else {
                            ErrorCode::Timeout
                        },
                        !connecting,
                        format!("netftapi2.xml: {e}"),
                    )
                },
            )?;
        if status != 200 {
            return Err(device(
                ErrorCode::Protocol,
                false,
                format!("netftapi2.xml: HTTP status {status}"),
            ));
        }
        let calibration =
            parse_calibration(&body).map_err(|e| device(ErrorCode::Protocol, false, e))?;
        if calibration.force_unit != s.force_unit || calibration.torque_unit != s.torque_unit {
            return Err(device(
                ErrorCode::UnitMismatch,
                false,
                format!(
                    "the box is configured for {} and {}, the cell file declares {} and {} (force_unit, torque_unit)",
                    calibration.force_unit.label(),
                    calibration.torque_unit.label(),
                    s.force_unit.label(),
                    s.torque_unit.label()
                ),
            ));
        }
        if !connecting && calibration != self.calibration {
            return Err(device(
                ErrorCode::UnitMismatch,
                false,
                format!(
                    "the calibration changed since the driver connected (serial {} slot {} {}/{} counts, now serial {} slot {} {}/{} counts): restart the driver after checking the box",
                    self.calibration.serial,
                    self.calibration.slot,
                    self.calibration.counts_per_force,
                    self.calibration.counts_per_torque,
                    calibration.serial,
                    calibration.slot,
                    calibration.counts_per_force,
                    calibration.counts_per_torque
                ),
            ));
        }
        Ok(calibration)
    }

    fn send(&self, command: u16, count: u32) -> Result<(), RigError> {
        self.socket
            .send(&request(command, count))
            .map(|_| ())
            .map_err(|e| {
                device(
                    ErrorCode::NotConnected,
                    true,
                    format!("sending an RDT request: {e}"),
                )
            })
    }

    /// `count` records of a fresh real-time stream, checked. The stream is
    /// stopped whenever the request fails, and records still in flight from an
    /// earlier request (their `rdt_sequence` does not start at 1) are dropped.
    fn records(&self, count: u32) -> Result<Vec<Record>, RigError> {
        self.drain();
        self.send(CMD_START_REALTIME, count)?;
        let received = self.receive(count);
        if received.is_err() {
            let _ = self.send(CMD_STOP, 0);
        }
        received
    }

    fn receive(&self, count: u32) -> Result<Vec<Record>, RigError> {
        let deadline = Instant::now() + self.timeout;
        let mut records: Vec<Record> = Vec::with_capacity(count as usize);
        let mut buffer = [0u8; 1500];
        while records.len() < count as usize {
            let n = match super::udp::recv_before(&self.socket, &mut buffer, deadline) {
                Ok(Some(n)) => n,
                Ok(None) => {
                    return Err(device(
                        ErrorCode::Timeout,
                        true,
                        format!(
                            "{} of {count} RDT records within {:.1} s (no reply, or another client took the stream)",
                            records.len(),
                            self.timeout.as_secs_f64()
                        ),
                    ));
                }
                Err(e) => {
                    return Err(device(
                        ErrorCode::NotConnected,
                        true,
                        format!("receiving RDT records: {e}"),
                    ));
                }
            };
            let record =
                parse_record(&buffer[..n]).map_err(|e| device(ErrorCode::Protocol, false, e))?;
            if records.is_empty() && record.rdt_sequence != 1 {
                continue; // the tail of an earlier request's stream
            }
            check_record(&record, records.last())?;
            records.push(record);
        }
        Ok(records)
    }

    /// Discards datagrams left from an earlier request.
    fn drain(&self) {
        let mut buffer = [0u8; 1500];
        if self.socket.set_nonblocking(true).is_ok() {
            while self.socket.recv(&mut buffer).is_ok() {}
            let _ = self.socket.set_nonblocking(false);
        }
    }

    /// The mean of `samples` records, in N and N·m.
    pub fn read(&mut self) -> Result<[f64; 6], RigError> {
        self.fetch_calibration(false)?;
        let records = self.records(self.settings.samples)?;
        Ok(self.mean_wrench(&records))
    }

    fn mean_wrench(&self, records: &[Record]) -> [f64; 6] {
        let c = &self.calibration;
        let mut mean = [0.0; 6];
        for record in records {
            for (m, count) in mean.iter_mut().zip(record.counts) {
                *m += f64::from(count);
            }
        }
        let n = records.len().max(1) as f64;
        for (k, m) in mean.iter_mut().enumerate() {
            *m = if k < 3 {
                *m / n / c.counts_per_force * c.force_unit.newtons()
            } else {
                *m / n / c.counts_per_torque * c.torque_unit.newton_metres()
            };
        }
        mean
    }

    /// Software bias, verified by fresh readings near zero (the box does not
    /// acknowledge it).
    pub fn bias(&mut self) -> Result<(), RigError> {
        self.send(CMD_BIAS, 0)?;
        let wrench = self.read()?;
        let force = wrench[..3].iter().map(|v| v * v).sum::<f64>().sqrt();
        let moment = wrench[3..].iter().map(|v| v * v).sum::<f64>().sqrt();
        if force > self.settings.bias_tolerance_n || moment > self.settings.bias_tolerance_nm {
            return Err(device(
                ErrorCode::NotReady,
                false,
                format!(
                    "after the software bias the sensor reads {force:.3} N and {moment:.4} N·m, more than bias_tolerance_n = {} / bias_tolerance_nm = {}: the bias did not take",
                    self.settings.bias_tolerance_n, self.settings.bias_tolerance_nm
                ),
            ));
        }
        Ok(())
    }
}

impl Drop for NetFt {
    fn drop(&mut self) {
        let _ = self.send(CMD_STOP, 0);
    }
}

/// A record's status and sequence, against the previous record of the request.
fn check_record(record: &Record, previous: Option<&Record>) -> Result<(), RigError> {
    if record.status != 0 && record.status != STATUS_LATCH_WARNING {
        return Err(if record.status & STATUS_SATURATION != 0 {
            device(
                ErrorCode::OutOfRange,
                false,
                format!(
                    "status 0x{:08x}: the transducer is saturated (load beyond its range)",
                    record.status
                ),
            )
        } else {
            device(
                ErrorCode::NotReady,
                true,
                format!("status 0x{:08x}: the box reports an error", record.status),
            )
        });
    }
    if let Some(previous) = previous {
        let step = record.ft_sequence.wrapping_sub(previous.ft_sequence);
        if step == 0 || step > u32::MAX / 2 {
            return Err(device(
                ErrorCode::StaleData,
                true,
                format!(
                    "ft_sequence {} after {}: the box's samples {}",
                    record.ft_sequence,
                    previous.ft_sequence,
                    if step == 0 {
                        "stalled"
                    } else {
                        "went backwards"
                    }
                ),
            ));
        }
        if record.rdt_sequence != previous.rdt_sequence.wrapping_add(1) {
            return Err(device(
                ErrorCode::SequenceGap,
                true,
                format!(
                    "rdt_sequence {} after {}: records were lost",
                    record.rdt_sequence, previous.rdt_sequence
                ),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const XML: &str = "<?xml version=\"1.0\"?>\n<netft><prodname>Net F/T</prodname><setcfgsel>0</setcfgsel><cfgcalsn>FT27462</cfgcalsn><cfgfu>2</cfgfu><scfgfu>N</scfgfu><cfgtu>3</cfgtu><scfgtu>Nm</scfgtu><cfgcpf>1000000</cfgcpf><cfgcpt>1000000</cfgcpt></netft>";

    #[test]
    fn reads_the_calibration_by_codes_then_labels() {
        let c = parse_calibration(XML).unwrap();
        assert_eq!(c.counts_per_force, 1e6);
        assert_eq!(
            (c.force_unit, c.torque_unit),
            (ForceUnit::Newton, TorqueUnit::NewtonMetre)
        );
        assert_eq!(c.serial, "FT27462");
        let labels_only = XML.replace("<cfgtu>3</cfgtu>", "").replace("Nm<", "Nmm<");
        assert_eq!(
            parse_calibration(&labels_only).unwrap().torque_unit,
            TorqueUnit::NewtonMillimetre
        );
        assert!(parse_calibration("<html></html>").is_err());
        assert!(parse_calibration(&XML.replace("1000000</cfgcpt>", "0</cfgcpt>")).is_err());
    }

    #[test]
    fn requests_and_records_are_big_endian() {
        assert_eq!(request(0x0002, 100), [0x12, 0x34, 0, 2, 0, 0, 0, 100]);
        let mut datagram = Vec::new();
        for v in [7u32, 700, 0] {
            datagram.extend(v.to_be_bytes());
        }
        for v in [1i32, -2, 3, -4, 5, -6] {
            datagram.extend(v.to_be_bytes());
        }
        let r = parse_record(&datagram).unwrap();
        assert_eq!((r.rdt_sequence, r.ft_sequence, r.status), (7, 700, 0));
        assert_eq!(r.counts, [1, -2, 3, -4, 5, -6]);
        assert!(parse_record(&datagram[..30]).is_err());
    }

    #[test]
    fn sequences_and_status_are_checked_with_wrap_around() {
        let r = |rdt: u32, ft: u32, status: u32| Record {
            rdt_sequence: rdt,
            ft_sequence: ft,
            status,
            counts: [0; 6],
        };
        assert!(check_record(&r(2, 14, 0), Some(&r(1, 7, 0))).is_ok());
        assert!(
            check_record(&r(2, 3, 0), Some(&r(1, u32::MAX - 3, 0))).is_ok(),
            "wraps"
        );
        let code = |e: RigError| e.code().unwrap();
        assert_eq!(
            code(check_record(&r(2, 7, 0), Some(&r(1, 7, 0))).unwrap_err()),
            ErrorCode::StaleData
        );
        assert_eq!(
            code(check_record(&r(2, 6, 0), Some(&r(1, 7, 0))).unwrap_err()),
            ErrorCode::StaleData
        );
        assert_eq!(
            code(check_record(&r(3, 14, 0), Some(&r(1, 7, 0))).unwrap_err()),
            ErrorCode::SequenceGap
        );
        assert_eq!(
            code(check_record(&r(1, 7, 0x8002_0000), None).unwrap_err()),
            ErrorCode::OutOfRange
        );
        assert_eq!(
            code(check_record(&r(1, 7, 0xa000_0000), None).unwrap_err()),
            ErrorCode::NotReady
        );
        assert!(check_record(&r(1, 7, STATUS_LATCH_WARNING), None).is_ok());
    }
}
