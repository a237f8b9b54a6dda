//! A cable-robot controller over egcal's UDP protocol
//! (`schemas/cable-robot-udp.md`): fixed-size big-endian datagrams, one reply
//! per request with its sequence number, and the controller's state and limit
//! flags mapped to the driver protocol's errors.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use super::cell::CableUdpSettings;
use crate::rig::RigError;
use crate::rig::protocol::ErrorCode;

pub const MAGIC: u32 = 0x4543_4450;
pub const VERSION: u16 = 1;
pub const REQUEST_BYTES: usize = 64;
pub const REPLY_BYTES: usize = 136;

/// Request commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum Command {
    SetWrench = 1,
    Release = 2,
    Status = 3,
}

/// Controller states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    Idle,
    Ramping,
    Holding,
    Fault,
}

pub const FLAG_TENSION_LOW: u32 = 1 << 0;
pub const FLAG_TENSION_HIGH: u32 = 1 << 1;
pub const FLAG_INFEASIBLE: u32 = 1 << 2;
pub const FLAG_ESTOP: u32 = 1 << 3;
pub const FLAG_WORKSPACE: u32 = 1 << 4;

/// A decoded reply.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    pub command: u16,
    pub seq: u32,
    pub state: State,
    pub flags: u32,
    pub wrench: [f64; 6],
    pub tensions_n: Vec<f64>,
}

pub fn encode_request(command: Command, seq: u32, wrench: [f64; 6]) -> [u8; REQUEST_BYTES] {
    let mut bytes = [0u8; REQUEST_BYTES];
    bytes[0..4].copy_from_slice(&MAGIC.to_be_bytes());
    bytes[4..6].copy_from_slice(&VERSION.to_be_bytes());
    bytes[6..8].copy_from_slice(&(command as u16).to_be_bytes());
    bytes[8..12].copy_from_slice(&seq.to_be_bytes());
    for (k, value) in wrench.iter().enumerate() {
        bytes[12 + 8 * k..20 + 8 * k].copy_from_slice(&value.to_be_bytes());
    }
    bytes
}

pub fn decode_reply(datagram: &[u8]) -> Result<Reply, String> {
    if datagram.len() != REPLY_BYTES {
        return Err(format!(
            "a reply of {} bytes, expected {REPLY_BYTES}",
            datagram.len()
        ));
    }
    let u16_at = |i: usize| u16::from_be_bytes(datagram[i..i + 2].try_into().expect("2 bytes"));
    let u32_at = |i: usize| u32::from_be_bytes(datagram[i..i + 4].try_into().expect("4 bytes"));
    let f64_at = |i: usize| f64::from_be_bytes(datagram[i..i + 8].try_into().expect("8 bytes"));
    if u32_at(0) != MAGIC || u16_at(4) != VERSION {
        return Err(format!(
            "magic 0x{:08x} version {}, expected 0x{MAGIC:08x} version {VERSION}",
            u32_at(0),
            u16_at(4)
        ));
    }
    let state = match u32_at(12) {
        0 => State::Idle,
        1 => State::Ramping,
        2 => State::Holding,
        3 => State::Fault,
        other => return Err(format!("unknown state {other}")),
    };
    let cables = usize::from(u16_at(68));
    if cables > 8 {
        return Err(format!("{cables} cables, at most 8"));
    }
    let wrench: [f64; 6] = std::array::from_fn(|k| f64_at(20 + 8 * k));
    let tensions_n: Vec<f64> = (0..cables).map(|k| f64_at(72 + 8 * k)).collect();
    if wrench.iter().chain(&tensions_n).any(|v| !v.is_finite()) {
        return Err("a non-finite wrench or tension".into());
    }
    Ok(Reply {
        command: u16_at(6),
        seq: u32_at(8),
        state,
        flags: u32_at(16),
        wrench,
        tensions_n,
    })
}

fn device(code: ErrorCode, transient: bool, message: String) -> RigError {
    RigError::device(code, transient, format!("cable robot: {message}"))
}

/// A connected controller.
pub struct CableRobot {
    settings: CableUdpSettings,
    timeout: Duration,
    socket: UdpSocket,
    seq: u32,
}

impl CableRobot {
    pub fn connect(
        settings: &CableUdpSettings,
        cell_timeout_s: f64,
    ) -> Result<CableRobot, RigError> {
        let socket = super::udp::connect(&settings.address, settings.port).map_err(|e| {
            device(
                ErrorCode::NotConnected,
                false,
                format!("cannot reach {}:{}: {e}", settings.address, settings.port),
            )
        })?;
        let mut robot = CableRobot {
            settings: settings.clone(),
            timeout: Duration::from_secs_f64(settings.timeout_s.unwrap_or(cell_timeout_s)),
            socket,
            seq: 0,
        };
        robot.exchange(Command::Status, [0.0; 6])?;
        Ok(robot)
    }

    /// One request and its reply (replies to earlier requests are dropped).
    fn exchange(&mut self, command: Command, wrench: [f64; 6]) -> Result<Reply, RigError> {
        self.seq = self.seq.wrapping_add(1);
        self.socket
            .send(&encode_request(command, self.seq, wrench))
            .map_err(|e| device(ErrorCode::NotConnected, true, format!("sending: {e}")))?;
        let deadline = Instant::now() + self.timeout;
        let mut buffer = [0u8; 1500];
        loop {
            let n = match super::udp::recv_before(&self.socket, &mut buffer, deadline) {
                Ok(Some(n)) => n,
                Ok(None) => {
                    return Err(device(
                        ErrorCode::Timeout,
                        true,
                        format!(
                            "no reply to {command:?} within {:.1} s",
                            self.timeout.as_secs_f64()
                        ),
                    ));
                }
                Err(e) => {
                    return Err(device(
                        ErrorCode::NotConnected,
                        true,
                        format!("receiving: {e}"),
                    ));
                }
            };
            let reply =
                decode_reply(&buffer[..n]).map_err(|e| device(ErrorCode::Protocol, false, e))?;
            if reply.seq == self.seq {
                check_flags(&reply)?;
                return Ok(reply);
            }
        }
    }

    /// Waits, polling the status, until `done` holds for a reply.
    fn wait(&mut self, what: &str, done: impl Fn(&Reply) -> bool) -> Result<Reply, RigError> {
        let deadline = Instant::now() + Duration::from_secs_f64(self.settings.settle_timeout_s);
        loop {
            let reply = self.exchange(Command::Status, [0.0; 6])?;
            if done(&reply) {
                return Ok(reply);
            }
            if Instant::now() >= deadline {
                return Err(device(
                    ErrorCode::Timeout,
                    true,
                    format!(
                        "{what} not reached within settle_timeout_s = {} s (state {:?}, achieved {:?})",
                        self.settings.settle_timeout_s, reply.state, reply.wrench
                    ),
                ));
            }
            std::thread::sleep(Duration::from_millis(self.settings.poll_ms));
        }
    }

    /// Applies `wrench` and waits until it is held within the tolerances.
    pub fn apply(&mut self, wrench: [f64; 6]) -> Result<(), RigError> {
        self.exchange(Command::SetWrench, wrench)?;
        let (force_tol, moment_tol) = (
            self.settings.force_tolerance_n,
            self.settings.moment_tolerance_nm,
        );
        self.wait("the set-point", |reply| {
            reply.state == State::Holding
                && (0..6).all(|k| {
                    let tol = if k < 3 { force_tol } else { moment_tol };
                    (reply.wrench[k] - wrench[k]).abs() <= tol
                })
        })?;
        Ok(())
    }

    /// Releases the tension and waits until the controller is idle.
    pub fn release(&mut self) -> Result<(), RigError> {
        self.exchange(Command::Release, [0.0; 6])?;
        self.wait("release", |reply| reply.state == State::Idle)?;
        Ok(())
    }
}

/// The controller's fault state and limit flags as errors.
fn check_flags(reply: &Reply) -> Result<(), RigError> {
    if reply.flags & FLAG_ESTOP != 0 || reply.state == State::Fault {
        return Err(device(
            ErrorCode::Estop,
            false,
            format!(
                "emergency stop or fault (state {:?}, flags 0x{:x})",
                reply.state, reply.flags
            ),
        ));
    }
    let limits = [
        (
            FLAG_INFEASIBLE,
            "the set-point is outside the wrench-feasible set; not applied",
        ),
        (
            FLAG_WORKSPACE,
            "the end effector is outside the cables' workspace",
        ),
        (FLAG_TENSION_HIGH, "a cable reached its upper tension limit"),
        (FLAG_TENSION_LOW, "a cable reached its lower tension limit"),
    ];
    for (flag, meaning) in limits {
        if reply.flags & flag != 0 {
            return Err(device(
                ErrorCode::OutOfRange,
                false,
                format!("{meaning} (tensions {:?} N)", reply.tensions_n),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply_bytes(state: u32, flags: u32, seq: u32) -> Vec<u8> {
        let mut b = Vec::new();
        b.extend(MAGIC.to_be_bytes());
        b.extend(VERSION.to_be_bytes());
        b.extend(3u16.to_be_bytes());
        b.extend(seq.to_be_bytes());
        b.extend(state.to_be_bytes());
        b.extend(flags.to_be_bytes());
        for v in [10.0f64, 0.0, -5.0, 0.0, 1.0, 0.0] {
            b.extend(v.to_be_bytes());
        }
        b.extend(4u16.to_be_bytes());
        b.extend(0u16.to_be_bytes());
        for k in 0..8 {
            b.extend((if k < 4 { 100.0f64 } else { 0.0 }).to_be_bytes());
        }
        b
    }

    #[test]
    fn the_layouts_follow_the_protocol_document() {
        let request = encode_request(Command::SetWrench, 9, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert_eq!(&request[0..4], b"ECDP");
        assert_eq!(&request[6..8], &[0, 1]);
        assert_eq!(&request[8..12], &[0, 0, 0, 9]);
        assert_eq!(&request[12..20], &1.0f64.to_be_bytes());
        assert_eq!(&request[52..60], &6.0f64.to_be_bytes());
        let reply = decode_reply(&reply_bytes(2, 0, 9)).unwrap();
        assert_eq!((reply.seq, reply.state), (9, State::Holding));
        assert_eq!(reply.wrench[2], -5.0);
        assert_eq!(reply.tensions_n, [100.0; 4]);
        assert!(decode_reply(&reply_bytes(2, 0, 9)[..100]).is_err());
        let mut bad = reply_bytes(2, 0, 9);
        bad[0] = 0;
        assert!(decode_reply(&bad).is_err());
    }

    #[test]
    fn flags_become_the_protocols_errors() {
        let code = |state, flags| {
            check_flags(&decode_reply(&reply_bytes(state, flags, 1)).unwrap())
                .err()
                .and_then(|e| e.code())
        };
        assert_eq!(code(2, 0), None);
        assert_eq!(code(2, FLAG_ESTOP), Some(ErrorCode::Estop));
        assert_eq!(code(3, 0), Some(ErrorCode::Estop));
        assert_eq!(code(1, FLAG_INFEASIBLE), Some(ErrorCode::OutOfRange));
        assert_eq!(code(2, FLAG_TENSION_HIGH), Some(ErrorCode::OutOfRange));
    }
}
