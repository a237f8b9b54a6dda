//! A Leica laser tracker over emScon TPI (TCP port 700): packed little-endian C
//! structures (`#pragma pack(4)`, 32-bit `long`), each packet led by
//! `{i32 size, i32 type}`. Layouts, command numbers and result statuses follow
//! Leica's TPI header `ES_C_API_Def.h` (emScon TPI/SDK 3.6): `PacketHeaderT`,
//! `BasicCommandCT`/`RT` `{header, ES_Command command[, ES_ResultStatus status]}`,
//! `ErrorResponseT` (the same 16 bytes with type `ES_DT_Error`),
//! `SingleMeasResultT` (156 bytes: `ReturnDataT {header, status}`, `measMode`,
//! `bIsTryMode`, then 17 doubles from `dVal1`) and `GetReflectorsRT` (100 bytes:
//! `BasicCommandRT`, `int iTotalReflectors`, `int iInternalReflectorId`,
//! `enum ES_TargetType targetType`, `double dSurfaceOffset` at offset 28,
//! `unsigned short cReflectorName[32]`, UTF-16, at offset 36).
//!
//! Start-up: units (mm, degree, °C, mbar, %RH), environment, `Initialize`,
//! stationary measurement mode and its parameters, the reflector (checked
//! against the tracker's list). A measurement is `StartMeasurement`, answered by
//! a command reply and then a `SingleMeasResultT` with the point and the
//! tracker's own standard deviations, which the driver returns as `sigma_mm`.
//! A beam break (an error reply, or a point of zeros or NaN, which is never
//! reported as a point) is `beam_lost`; a tracker still warming up is
//! `not_ready`; a point closer than the tracker's minimum range means the units
//! were not applied (`unit_mismatch`).

use std::io::{Read, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::rig::RigError;
use crate::rig::protocol::ErrorCode;

/// The `[tracker]` table of a Leica tracker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct EmsconSettings {
    /// Host name or IP address of the emScon server.
    pub address: String,
    #[serde(default = "default_port")]
    #[schemars(range(min = 1, max = 65535))]
    pub port: u16,
    /// The tracker's internal id of the reflector (from its reflector list).
    pub reflector_id: i32,
    /// Stationary measurement time, ms.
    #[serde(default = "default_stationary_ms")]
    #[schemars(range(min = 1, max = 600_000))]
    pub stationary_time_ms: i32,
    /// Use the absolute distance meter in stationary measurements.
    #[serde(default = "default_true")]
    pub use_adm: bool,
    /// Air temperature, °C; pressure, mbar; relative humidity, %.
    #[serde(default = "default_temperature")]
    #[schemars(range(min = -40.0, max = 80.0))]
    pub temperature_c: f64,
    #[serde(default = "default_pressure")]
    #[schemars(range(min = 500.0, max = 1200.0))]
    pub pressure_mbar: f64,
    #[serde(default = "default_humidity")]
    #[schemars(range(min = 0.0, max = 100.0))]
    pub humidity_percent: f64,
    /// Longest wait for `Initialize`, s (trackers take a minute or more).
    #[serde(default = "default_initialize_timeout_s")]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub initialize_timeout_s: f64,
    /// Longest wait for a measurement, s (on top of the stationary time).
    #[serde(default = "default_measure_timeout_s")]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub measure_timeout_s: f64,
    /// The tracker's minimum range, mm: a point closer than this is not a point
    /// in millimetres (units not applied).
    #[serde(default = "default_min_distance_mm")]
    #[schemars(range(min = 0.0, max = 100_000.0))]
    pub min_distance_mm: f64,
    /// Time limit of other commands, s; the cell's `timeout_s` when absent.
    #[serde(default)]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub timeout_s: Option<f64>,
}

fn default_port() -> u16 {
    700
}
fn default_stationary_ms() -> i32 {
    1000
}
fn default_true() -> bool {
    true
}
fn default_temperature() -> f64 {
    20.0
}
fn default_pressure() -> f64 {
    1013.25
}
fn default_humidity() -> f64 {
    50.0
}
fn default_initialize_timeout_s() -> f64 {
    90.0
}
fn default_measure_timeout_s() -> f64 {
    30.0
}
fn default_min_distance_mm() -> f64 {
    500.0
}

const DT_COMMAND: i32 = 0;
const DT_ERROR: i32 = 1;
const DT_SINGLE_MEAS_RESULT: i32 = 2;
const CMD_SET_UNITS: i32 = 5;
const CMD_INITIALIZE: i32 = 7;
const CMD_SET_ENVIRONMENT: i32 = 20;
const CMD_SET_MEASUREMENT_MODE: i32 = 24;
const CMD_SET_STATIONARY_PARAMS: i32 = 28;
const CMD_SET_REFLECTOR: i32 = 40;
const CMD_GET_REFLECTORS: i32 = 42;
const CMD_START_MEASUREMENT: i32 = 49;
const SINGLE_MEAS_RESULT_BYTES: usize = 156;
const GET_REFLECTORS_RT_BYTES: usize = 100;
const STATUS_OK: i32 = 0;
const STATUS_SERVER_BUSY: i32 = 1;
const STATUS_NOT_INITIALIZED: i32 = 39;
const STATUS_MEAS_NOT_READY: i32 = 10004;
const STATUS_NO_STATIONARY_RESULT: i32 = 10009;
const STATUS_NOT_WARMED_UP: i32 = 10012;
const STATUS_SYSTEM_NOT_READY: i32 = 10014;

fn device(code: ErrorCode, transient: bool, message: String) -> RigError {
    RigError::device(code, transient, format!("tracker: {message}"))
}

/// An emScon result status as an error (none for `AllOK`).
fn status_error(command: i32, status: i32) -> Option<RigError> {
    let (code, transient, meaning) = match status {
        STATUS_OK => return None,
        STATUS_SERVER_BUSY => (ErrorCode::Busy, true, "server busy"),
        STATUS_NO_STATIONARY_RESULT | STATUS_MEAS_NOT_READY => (
            ErrorCode::BeamLost,
            true,
            "no stationary result (beam broken or no reflector)",
        ),
        STATUS_NOT_WARMED_UP => (ErrorCode::NotReady, true, "the tracker is not warmed up"),
        STATUS_SYSTEM_NOT_READY => (
            ErrorCode::NotReady,
            true,
            "the system is not ready to measure",
        ),
        STATUS_NOT_INITIALIZED => (ErrorCode::NotReady, false, "the tracker is not initialised"),
        _ => (ErrorCode::NotReady, true, "emScon error"),
    };
    Some(device(
        code,
        transient,
        format!("{meaning} (command {command}, status {status})"),
    ))
}

/// A command packet: header, command, then the payload.
fn command_packet(command: i32, payload: &[u8]) -> Vec<u8> {
    let size = (12 + payload.len()) as i32;
    let mut packet = Vec::with_capacity(size as usize);
    packet.extend(size.to_le_bytes());
    packet.extend(DT_COMMAND.to_le_bytes());
    packet.extend(command.to_le_bytes());
    packet.extend(payload);
    packet
}

fn i32_at(bytes: &[u8], offset: usize) -> i32 {
    i32::from_le_bytes(bytes[offset..offset + 4].try_into().expect("4 bytes"))
}

fn f64_at(bytes: &[u8], offset: usize) -> f64 {
    f64::from_le_bytes(bytes[offset..offset + 8].try_into().expect("8 bytes"))
}

/// The point, its standard deviations and the result's status of a
/// `SingleMeasResultT`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub status: i32,
    pub position_mm: [f64; 3],
    pub std_mm: [f64; 3],
}

pub fn parse_single_result(packet: &[u8]) -> Result<Point, String> {
    if packet.len() != SINGLE_MEAS_RESULT_BYTES {
        return Err(format!(
            "a measurement result of {} bytes, expected {SINGLE_MEAS_RESULT_BYTES}",
            packet.len()
        ));
    }
    Ok(Point {
        status: i32_at(packet, 8),
        position_mm: [f64_at(packet, 20), f64_at(packet, 28), f64_at(packet, 36)],
        std_mm: [f64_at(packet, 44), f64_at(packet, 52), f64_at(packet, 60)],
    })
}

/// A connected, initialised tracker.
pub struct Emscon {
    settings: EmsconSettings,
    timeout: Duration,
    stream: TcpStream,
}

impl Emscon {
    pub fn connect(settings: &EmsconSettings, cell_timeout_s: f64) -> Result<Emscon, RigError> {
        let timeout = Duration::from_secs_f64(settings.timeout_s.unwrap_or(cell_timeout_s));
        let unreachable = |e: String| {
            device(
                ErrorCode::NotConnected,
                false,
                format!(
                    "cannot connect to {}:{}: {e}",
                    settings.address, settings.port
                ),
            )
        };
        let address = (settings.address.as_str(), settings.port)
            .to_socket_addrs()
            .map_err(|e| unreachable(e.to_string()))?
            .next()
            .ok_or_else(|| unreachable("no address".into()))?;
        let stream = TcpStream::connect_timeout(&address, timeout)
            .map_err(|e| unreachable(e.to_string()))?;
        let mut tracker = Emscon {
            settings: settings.clone(),
            timeout,
            stream,
        };
        tracker.start_up()?;
        Ok(tracker)
    }

    fn start_up(&mut self) -> Result<(), RigError> {
        let s = self.settings.clone();
        // Millimetre, degree, Celsius, mbar, %RH.
        let units: Vec<u8> = [1i32, 1, 0, 0, 0]
            .iter()
            .flat_map(|u| u.to_le_bytes())
            .collect();
        self.command(CMD_SET_UNITS, &units, self.timeout)?;
        let environment: Vec<u8> = [s.temperature_c, s.pressure_mbar, s.humidity_percent]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        self.command(CMD_SET_ENVIRONMENT, &environment, self.timeout)?;
        self.command(
            CMD_INITIALIZE,
            &[],
            Duration::from_secs_f64(s.initialize_timeout_s),
        )?;
        self.command(CMD_SET_MEASUREMENT_MODE, &0i32.to_le_bytes(), self.timeout)?;
        let stationary: Vec<u8> = [s.stationary_time_ms, i32::from(s.use_adm)]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        self.command(CMD_SET_STATIONARY_PARAMS, &stationary, self.timeout)?;
        let reflectors = self.reflectors()?;
        if !reflectors.iter().any(|(id, _)| *id == s.reflector_id) {
            let known: Vec<String> = reflectors
                .iter()
                .map(|(id, name)| format!("{id} ({name})"))
                .collect();
            return Err(device(
                ErrorCode::NotConnected,
                false,
                format!(
                    "reflector_id = {} is not among the tracker's reflectors: {}",
                    s.reflector_id,
                    if known.is_empty() {
                        "(none)".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
        self.command(
            CMD_SET_REFLECTOR,
            &s.reflector_id.to_le_bytes(),
            self.timeout,
        )?;
        Ok(())
    }

    /// Reads one whole packet before `deadline`.
    fn read_packet(&mut self, deadline: Instant) -> Result<Vec<u8>, RigError> {
        let mut header = [0u8; 8];
        self.read_exact_before(&mut header, deadline)?;
        let size = i32_at(&header, 0);
        if !(8..=65_536).contains(&size) {
            return Err(device(
                ErrorCode::Protocol,
                false,
                format!("a packet of size {size}"),
            ));
        }
        let mut packet = header.to_vec();
        packet.resize(size as usize, 0);
        self.read_exact_before(&mut packet[8..], deadline)?;
        Ok(packet)
    }

    fn read_exact_before(&mut self, buffer: &mut [u8], deadline: Instant) -> Result<(), RigError> {
        let mut filled = 0;
        while filled < buffer.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(device(ErrorCode::Timeout, true, "no reply in time".into()));
            }
            self.stream
                .set_read_timeout(Some(left))
                .map_err(|e| device(ErrorCode::NotConnected, false, e.to_string()))?;
            match self.stream.read(&mut buffer[filled..]) {
                Ok(0) => {
                    return Err(device(
                        if filled == 0 {
                            ErrorCode::NotConnected
                        } else {
                            ErrorCode::Protocol
                        },
                        false,
                        if filled == 0 {
                            "the server closed the connection".to_string()
                        } else {
                            format!(
                                "the server closed the connection after {filled} of {} bytes",
                                buffer.len()
                            )
                        },
                    ));
                }
                Ok(n) => filled += n,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(device(ErrorCode::NotConnected, false, e.to_string())),
            }
        }
        Ok(())
    }

    fn send(&mut self, command: i32, payload: &[u8]) -> Result<(), RigError> {
        self.stream
            .write_all(&command_packet(command, payload))
            .map_err(|e| device(ErrorCode::NotConnected, false, format!("sending: {e}")))
    }

    /// Sends a command and waits for its reply (unsolicited packets are skipped).
    fn command(&mut self, command: i32, payload: &[u8], wait: Duration) -> Result<(), RigError> {
        self.send(command, payload)?;
        let deadline = Instant::now() + wait;
        loop {
            let packet = self.read_packet(deadline)?;
            if let Some(status) = reply_status(&packet, command) {
                return status_error(command, status).map_or(Ok(()), Err);
            }
        }
    }

    /// The tracker's reflectors: (internal id, name).
    ///
    /// The header's answer to `GetReflectors` is the `GetReflectorsRT` record
    /// itself, one per reflector, each carrying the command's status and
    /// `iTotalReflectors`; servers that also send a status-only
    /// `BasicCommandRT`, before or after the records, are accepted too.
    fn reflectors(&mut self) -> Result<Vec<(i32, String)>, RigError> {
        self.send(CMD_GET_REFLECTORS, &[])?;
        let deadline = Instant::now() + self.timeout;
        let mut found: Vec<(i32, String)> = Vec::new();
        let mut acknowledged = false;
        loop {
            let packet = match self.read_packet(deadline) {
                Ok(packet) => packet,
                // A status-only answer and then nothing: the list is empty.
                Err(e) if acknowledged && found.is_empty() && is_timeout(&e) => {
                    return Ok(found);
                }
                Err(e) if is_timeout(&e) => {
                    return Err(device(
                        ErrorCode::Timeout,
                        true,
                        format!(
                            "GetReflectors: {} reflector record(s) within {:.1} s, and no end of the list",
                            found.len(),
                            self.timeout.as_secs_f64()
                        ),
                    ));
                }
                Err(e) => return Err(e),
            };
            if let Some(status) = reply_status(&packet, CMD_GET_REFLECTORS) {
                if let Some(e) = status_error(CMD_GET_REFLECTORS, status) {
                    return Err(e);
                }
                acknowledged = true;
                continue;
            }
            let Some(record) = parse_reflector(&packet) else {
                continue; // an unsolicited packet
            };
            let record = record.map_err(|e| device(ErrorCode::Protocol, false, e))?;
            if let Some(e) = status_error(CMD_GET_REFLECTORS, record.status) {
                return Err(e);
            }
            if record.total == 0 {
                return Ok(found); // an empty list, told by its one record
            }
            if !found.iter().any(|(id, _)| *id == record.id) {
                found.push((record.id, record.name));
            }
            if found.len() as i64 >= i64::from(record.total) {
                return Ok(found);
            }
        }
    }

    /// A stationary measurement: the point (mm) and its standard deviations.
    pub fn measure(&mut self) -> Result<([f64; 3], Option<[f64; 3]>), RigError> {
        self.send(CMD_START_MEASUREMENT, &[])?;
        let wait = Duration::from_millis(self.settings.stationary_time_ms as u64)
            + Duration::from_secs_f64(self.settings.measure_timeout_s);
        let deadline = Instant::now() + wait;
        loop {
            let packet = self.read_packet(deadline)?;
            if let Some(status) = reply_status(&packet, CMD_START_MEASUREMENT) {
                if let Some(e) = status_error(CMD_START_MEASUREMENT, status) {
                    return Err(e);
                }
                continue; // the command was accepted; the result follows
            }
            if i32_at(&packet, 4) != DT_SINGLE_MEAS_RESULT {
                continue;
            }
            let point =
                parse_single_result(&packet).map_err(|e| device(ErrorCode::Protocol, false, e))?;
            return self.check_point(point);
        }
    }

    fn check_point(&self, point: Point) -> Result<([f64; 3], Option<[f64; 3]>), RigError> {
        if let Some(e) = status_error(CMD_START_MEASUREMENT, point.status) {
            return Err(e);
        }
        let p = point.position_mm;
        if p.iter().any(|v| !v.is_finite()) || p.iter().all(|v| *v == 0.0) {
            return Err(device(
                ErrorCode::BeamLost,
                true,
                format!("the tracker reported {p:?}, which is not a point (beam lost)"),
            ));
        }
        let distance = p.iter().map(|v| v * v).sum::<f64>().sqrt();
        if distance < self.settings.min_distance_mm {
            return Err(device(
                ErrorCode::UnitMismatch,
                false,
                format!(
                    "a point {distance:.3} mm from the tracker, closer than its minimum range (min_distance_mm = {}): the units (mm) were not applied",
                    self.settings.min_distance_mm
                ),
            ));
        }
        let sigma = point
            .std_mm
            .iter()
            .all(|s| s.is_finite() && *s > 0.0)
            .then_some(point.std_mm);
        Ok((p, sigma))
    }
}

fn is_timeout(e: &RigError) -> bool {
    e.code() == Some(ErrorCode::Timeout)
}

/// One `GetReflectorsRT` record.
#[derive(Debug, Clone, PartialEq)]
struct ReflectorRecord {
    status: i32,
    total: i32,
    id: i32,
    name: String,
}

/// A `GetReflectorsRT` record (`None`: the packet is not one), or why it is
/// malformed.
fn parse_reflector(packet: &[u8]) -> Option<Result<ReflectorRecord, String>> {
    if packet.len() != GET_REFLECTORS_RT_BYTES
        || i32_at(packet, 4) != DT_COMMAND
        || i32_at(packet, 8) != CMD_GET_REFLECTORS
    {
        return None;
    }
    let total = i32_at(packet, 16);
    if !(0..=1000).contains(&total) {
        return Some(Err(format!(
            "GetReflectors: iTotalReflectors is {total}, expected 0 to 1000"
        )));
    }
    let name: Vec<u16> = (0..32)
        .map(|k| u16::from_le_bytes([packet[36 + 2 * k], packet[37 + 2 * k]]))
        .take_while(|c| *c != 0)
        .collect();
    Some(Ok(ReflectorRecord {
        status: i32_at(packet, 12),
        total,
        id: i32_at(packet, 20),
        name: String::from_utf16_lossy(&name),
    }))
}

/// The status of a reply to `command`: a `BasicCommandRT` or an `ErrorResponseT`.
fn reply_status(packet: &[u8], command: i32) -> Option<i32> {
    let kind = i32_at(packet, 4);
    (packet.len() == 16 && (kind == DT_COMMAND || kind == DT_ERROR) && i32_at(packet, 8) == command)
        .then(|| i32_at(packet, 12))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_are_packed_little_endian() {
        let units = command_packet(CMD_SET_UNITS, &[1, 0, 0, 0]);
        assert_eq!(&units[0..4], &16i32.to_le_bytes());
        assert_eq!(&units[4..8], &0i32.to_le_bytes());
        assert_eq!(&units[8..12], &5i32.to_le_bytes());
        let mut result = vec![0u8; SINGLE_MEAS_RESULT_BYTES];
        result[0..4].copy_from_slice(&156i32.to_le_bytes());
        result[4..8].copy_from_slice(&2i32.to_le_bytes());
        for (k, v) in [1000.0f64, -250.5, 800.25, 0.005, 0.006, 0.01]
            .iter()
            .enumerate()
        {
            result[20 + 8 * k..28 + 8 * k].copy_from_slice(&v.to_le_bytes());
        }
        let point = parse_single_result(&result).unwrap();
        assert_eq!(point.position_mm, [1000.0, -250.5, 800.25]);
        assert_eq!(point.std_mm, [0.005, 0.006, 0.01]);
        assert!(parse_single_result(&result[..100]).is_err());
        let mut rt = vec![];
        for v in [16i32, 1, 49, 10009] {
            rt.extend(v.to_le_bytes());
        }
        assert_eq!(reply_status(&rt, 49), Some(10009));
        assert_eq!(reply_status(&rt, 7), None);
    }

    #[test]
    fn reflector_records_follow_the_header_layout() {
        // GetReflectorsRT: BasicCommandRT {100, 0, 42, status}, iTotalReflectors,
        // iInternalReflectorId, targetType, dSurfaceOffset at 28, name at 36.
        let mut record = vec![];
        for v in [100i32, 0, 42, 0, 2, 7, 5] {
            record.extend(v.to_le_bytes());
        }
        record.extend(19.05f64.to_le_bytes());
        let mut name: Vec<u8> = "RRR 1.5in"
            .encode_utf16()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        name.resize(64, 0);
        record.extend(name);
        assert_eq!(record.len(), GET_REFLECTORS_RT_BYTES);
        let r = parse_reflector(&record).unwrap().unwrap();
        assert_eq!((r.status, r.total, r.id), (0, 2, 7));
        assert_eq!(r.name, "RRR 1.5in");
        // Not a record: a status-only answer, or another command's packet.
        assert!(parse_reflector(&record[..16]).is_none());
        record[8..12].copy_from_slice(&41i32.to_le_bytes());
        assert!(parse_reflector(&record).is_none());
        record[8..12].copy_from_slice(&42i32.to_le_bytes());
        record[16..20].copy_from_slice(&(-1i32).to_le_bytes());
        assert!(parse_reflector(&record).unwrap().is_err());
    }

    #[test]
    fn statuses_map_to_the_protocols_codes() {
        let code = |s| status_error(49, s).map(|e| (e.code().unwrap(), e.is_transient()));
        assert_eq!(code(0), None);
        assert_eq!(code(10009), Some((ErrorCode::BeamLost, true)));
        assert_eq!(code(10012), Some((ErrorCode::NotReady, true)));
        assert_eq!(code(39), Some((ErrorCode::NotReady, false)));
    }
}
