//! ATI Net F/T and Ethernet Axia boxes: the calibration (counts per unit, units,
//! serial) from `netftapi2.xml` over HTTP, never hard-coded, and readings from
//! the RDT stream over UDP (big-endian; a request `0x1234, command, count` and
//! 36-byte records `rdt_sequence, ft_sequence, status, 6 × counts`).
//!
//! A reading asks for `samples` records and averages them, waiting for them
//! `samples / comrdtrate` (the box's RDT output rate, from `netftapi2.xml`) plus
//! the time limit of an exchange. It is refused when a
//! record is malformed (`protocol`), when the status word reports an error (see
//! [`status_error`]: saturation is `out_of_range`, a broken gage or a corrupt
//! calibration stops, anything else is a transient `not_ready`), when `ft_sequence`
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
/// The bits of the RDT status word (ATI manual 9620-05, Net F/T, "system
/// status code"; the Ethernet Axia's manual 9610-05 gives the same bits). Bit 31
/// summarises the errors; bit 16 (a monitor condition latched) is not one.
const STATUS_ERROR: u32 = 1 << 31;
const STATUS_FT_OUT_OF_RANGE: u32 = 1 << 30;
const STATUS_CALIBRATION_CHECKSUM: u32 = 1 << 29;
const STATUS_SIMULATED_ERROR: u32 = 1 << 28;
const STATUS_GAGE_OUT_OF_RANGE: u32 = 1 << 27;
const STATUS_OTHER_ERROR: u32 = 1 << 5;
const STATUS_BUSY: u32 = 1 << 3;
const STATUS_BROKEN_GAGE: u32 = 1 << 2;
const STATUS_SUPPLY_OUT_OF_RANGE: u32 = 1 << 1;
const STATUS_TEMPERATURE_OUT_OF_RANGE: u32 = 1 << 0;
/// Every documented error bit: any of them, or the summary bit, makes the
/// record an error reading.
const STATUS_ERRORS: u32 = STATUS_ERROR
    | STATUS_FT_OUT_OF_RANGE
    | STATUS_CALIBRATION_CHECKSUM
    | STATUS_SIMULATED_ERROR
    | STATUS_GAGE_OUT_OF_RANGE
    | STATUS_OTHER_ERROR
    | STATUS_BUSY
    | STATUS_BROKEN_GAGE
    | STATUS_SUPPLY_OUT_OF_RANGE
    | STATUS_TEMPERATURE_OUT_OF_RANGE;

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

/// The RDT output rate (`comrdtrate`, Hz) of a `netftapi2.xml` document: `None`
/// when the document does not give it, an error when it is not a positive number.
pub fn parse_rdt_rate(xml: &str) -> Result<Option<f64>, String> {
    let Some(text) = element(xml, "comrdtrate") else {
        return Ok(None);
    };
    text.parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v > 0.0)
        .map(Some)
        .ok_or_else(|| {
            format!("netftapi2.xml <comrdtrate> is `{text}`, expected a positive rate in Hz")
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
    /// The RDT output rate the box reported last (Hz), when it reports one.
    rdt_rate_hz: Option<f64>,
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
            rdt_rate_hz: None,
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
    fn fetch_calibration(&mut self, connecting: bool) -> Result<Calibration, RigError> {
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
        self.rdt_rate_hz =
            parse_rdt_rate(&body).map_err(|e| device(ErrorCode::Protocol, false, e))?;
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

    /// How long `count` records take at the box's output rate, plus the time
    /// limit of an exchange; without a rate, the time limit runs from the last
    /// record received (`None`).
    fn stream_time(&self, count: u32) -> Option<Duration> {
        self.rdt_rate_hz
            .map(|rate| Duration::from_secs_f64(f64::from(count) / rate) + self.timeout)
    }

    fn receive(&self, count: u32) -> Result<Vec<Record>, RigError> {
        let started = Instant::now();
        let whole = self.stream_time(count);
        let mut deadline = started + whole.unwrap_or(self.timeout);
        let mut records: Vec<Record> = Vec::with_capacity(count as usize);
        let mut buffer = [0u8; 1500];
        while records.len() < count as usize {
            let n = match super::udp::recv_before(&self.socket, &mut buffer, deadline) {
                Ok(Some(n)) => n,
                Ok(None) => {
                    let waited = match (whole, self.rdt_rate_hz) {
                        (Some(w), Some(rate)) => format!(
                            "within {:.1} s ({count} records at comrdtrate {rate} Hz plus the {:.1} s time limit)",
                            w.as_secs_f64(),
                            self.timeout.as_secs_f64()
                        ),
                        _ => format!(
                            "with {:.1} s without a record (netftapi2.xml gives no comrdtrate)",
                            self.timeout.as_secs_f64()
                        ),
                    };
                    return Err(device(
                        ErrorCode::Timeout,
                        true,
                        format!(
                            "{} of {count} RDT records {waited} (no reply, or another client took the stream)",
                            records.len(),
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
            if whole.is_none() {
                deadline = Instant::now() + self.timeout;
            }
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

/// What a record's status word means (`None`: a valid reading). Saturation (the
/// F/T or a gage out of range) is the load, not the box: `out_of_range` at once,
/// the row recorded. A broken gage or a corrupt calibration will not go away by
/// retrying: `not_ready` that stops. Busy, supply or temperature out of range, a
/// simulated error or another error: retried. Bit 16 (a monitor condition
/// latched) and other bits without the error bit are not errors.
pub fn status_error(status: u32) -> Option<RigError> {
    if status & STATUS_ERRORS == 0 {
        return None;
    }
    let named: Vec<&str> = [
        (STATUS_FT_OUT_OF_RANGE, "F/T out of range"),
        (STATUS_GAGE_OUT_OF_RANGE, "gage out of range"),
        (STATUS_BROKEN_GAGE, "broken gage"),
        (STATUS_CALIBRATION_CHECKSUM, "calibration checksum error"),
        (STATUS_BUSY, "busy"),
        (STATUS_SUPPLY_OUT_OF_RANGE, "supply voltage out of range"),
        (STATUS_TEMPERATURE_OUT_OF_RANGE, "temperature out of range"),
        (STATUS_SIMULATED_ERROR, "simulated error"),
        (STATUS_OTHER_ERROR, "other error"),
    ]
    .iter()
    .filter(|(bit, _)| status & bit != 0)
    .map(|(_, name)| *name)
    .collect();
    let what = if named.is_empty() {
        "error".to_string()
    } else {
        named.join(", ")
    };
    let (code, transient, meaning) =
        if status & (STATUS_FT_OUT_OF_RANGE | STATUS_GAGE_OUT_OF_RANGE) != 0 {
            (
                ErrorCode::OutOfRange,
                false,
                "the transducer is saturated (load beyond its range)",
            )
        } else if status & (STATUS_BROKEN_GAGE | STATUS_CALIBRATION_CHECKSUM) != 0 {
            (
                ErrorCode::NotReady,
                false,
                "the transducer or its calibration is faulty: check the box",
            )
        } else if status & STATUS_BUSY != 0 {
            (ErrorCode::Busy, true, "the box is busy")
        } else {
            (ErrorCode::NotReady, true, "the box reports an error")
        };
    Some(device(
        code,
        transient,
        format!("status 0x{status:08x} ({what}): {meaning}"),
    ))
}

/// A record's status and sequence, against the previous record of the request.
fn check_record(record: &Record, previous: Option<&Record>) -> Result<(), RigError> {
    if let Some(e) = status_error(record.status) {
        return Err(e);
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
            code(check_record(&r(1, 7, 0xC000_0000), None).unwrap_err()),
            ErrorCode::OutOfRange
        );
        assert!(check_record(&r(1, 7, 0x0001_0000), None).is_ok());
    }

    #[test]
    fn every_documented_status_word_has_its_meaning() {
        let meaning = |status: u32| {
            status_error(status).map(|e| (e.code().unwrap(), e.is_transient(), e.to_string()))
        };
        assert_eq!(meaning(0), None);
        assert_eq!(meaning(0x0001_0000), None, "a monitor condition latched");
        for (word, code, transient, words) in [
            (
                0x8800_0000u32,
                ErrorCode::OutOfRange,
                false,
                "gage out of range",
            ),
            (
                0xC000_0000,
                ErrorCode::OutOfRange,
                false,
                "F/T out of range",
            ),
            (
                0xA000_0000,
                ErrorCode::NotReady,
                false,
                "calibration checksum",
            ),
            (0x8000_0004, ErrorCode::NotReady, false, "broken gage"),
            (0x9000_0000, ErrorCode::NotReady, true, "simulated error"),
            (0x8000_0008, ErrorCode::Busy, true, "busy"),
            (0x8000_0002, ErrorCode::NotReady, true, "supply voltage"),
            (0x8000_0001, ErrorCode::NotReady, true, "temperature"),
            (0x8000_0020, ErrorCode::NotReady, true, "other error"),
            (0x8001_0000, ErrorCode::NotReady, true, "0x80010000 (error)"),
        ] {
            let (c, t, message) = meaning(word).unwrap();
            assert_eq!((c, t), (code, transient), "0x{word:08x}: {message}");
            assert!(message.contains(words), "0x{word:08x}: {message}");
        }
    }

    #[test]
    fn the_rdt_rate_is_read_when_given() {
        assert_eq!(parse_rdt_rate(XML).unwrap(), None);
        let with = XML.replace("</netft>", "<comrdtrate>100</comrdtrate></netft>");
        assert_eq!(parse_rdt_rate(&with).unwrap(), Some(100.0));
        let bad = XML.replace("</netft>", "<comrdtrate>0</comrdtrate></netft>");
        assert!(parse_rdt_rate(&bad).unwrap_err().contains("comrdtrate"));
    }
}
