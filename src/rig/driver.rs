//! The external-driver adapter: starts the lab's driver program and speaks the
//! line-delimited JSON [`protocol`](super::protocol) over its stdin/stdout, each
//! request with a timeout.
//!
//! A reader thread forwards the driver's stdout lines over a channel so a request
//! can time out without blocking; a late reply to a timed-out request is recognised
//! by its id and dropped. The driver's stderr passes through to ours (its logs).

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::Duration;

use super::protocol::{Call, PROTOCOL_VERSION, Reply, ReplyResult, Request};
use super::{Rig, RigError};

/// A running driver process.
pub struct ExternalDriver {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<String>,
    next_id: u64,
    timeout: Duration,
    last_measured_at_us: i64,
    /// The driver's self-description from `hello`.
    pub name: String,
}

impl ExternalDriver {
    /// Starts `command` (program and arguments) and exchanges `hello`.
    pub fn start(command: &[String], timeout: Duration) -> Result<Self, RigError> {
        let (program, args) = command
            .split_first()
            .ok_or_else(|| RigError::Fatal("driver command is empty".into()))?;
        let mut child = Command::new(program)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| RigError::Fatal(format!("cannot start driver `{program}`: {e}")))?;
        let stdin = child
            .stdin
            .take()
            .ok_or_else(|| RigError::Fatal("driver has no stdin".into()))?;
        let stdout = child
            .stdout
            .take()
            .ok_or_else(|| RigError::Fatal("driver has no stdout".into()))?;
        let (sender, lines) = channel();
        std::thread::spawn(move || {
            // Bytes, not `lines()`: a reply that is not UTF-8 must reach the JSON
            // check as a malformed reply, not end the stream as if the driver died.
            let mut stdout = BufReader::new(stdout);
            let mut buffer = Vec::new();
            loop {
                buffer.clear();
                match stdout.read_until(b'\n', &mut buffer) {
                    Ok(0) | Err(_) => break,
                    Ok(_) => {
                        let line = String::from_utf8_lossy(&buffer).trim_end().to_string();
                        if sender.send(line).is_err() {
                            break;
                        }
                    }
                }
            }
        });
        let mut driver = ExternalDriver {
            child,
            stdin,
            lines,
            next_id: 1,
            timeout,
            last_measured_at_us: 0,
            name: String::new(),
        };
        let hello = driver.call(Call::Hello {
            protocol: PROTOCOL_VERSION,
        })?;
        match hello.protocol {
            Some(PROTOCOL_VERSION) => {}
            other => {
                return Err(RigError::Fatal(format!(
                    "driver speaks protocol {other:?}, egcal speaks {PROTOCOL_VERSION}"
                )));
            }
        }
        driver.name = hello.name.unwrap_or_else(|| program.clone());
        Ok(driver)
    }

    /// Sends one request and waits for its reply.
    fn call(&mut self, call: Call) -> Result<ReplyResult, RigError> {
        let id = self.next_id;
        self.next_id += 1;
        let method = serde_json::to_value(&call)
            .ok()
            .and_then(|v| v["method"].as_str().map(str::to_string))
            .unwrap_or_default();
        let line = serde_json::to_string(&Request { id, call }).expect("request serialises");
        writeln!(self.stdin, "{line}")
            .and_then(|_| self.stdin.flush())
            .map_err(|e| RigError::Fatal(format!("driver stopped reading ({method}): {e}")))?;
        loop {
            let line = match self.lines.recv_timeout(self.timeout) {
                Ok(line) => line,
                Err(RecvTimeoutError::Timeout) => {
                    return Err(RigError::Transient(format!(
                        "driver did not answer `{method}` within {:.1} s",
                        self.timeout.as_secs_f64()
                    )));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    let status = self.child.try_wait().ok().flatten();
                    return Err(RigError::Fatal(format!(
                        "driver exited during `{method}`{}",
                        status.map(|s| format!(" ({s})")).unwrap_or_default()
                    )));
                }
            };
            let reply: Reply = serde_json::from_str(&line).map_err(|e| {
                RigError::Fatal(format!(
                    "driver sent a malformed reply to `{method}`: {e}: {}",
                    excerpt(&line)
                ))
            })?;
            if reply.id < id {
                continue; // late answer to a request that already timed out
            }
            if reply.id != id {
                return Err(RigError::Fatal(format!(
                    "driver answered request {} while egcal waited for {id}",
                    reply.id
                )));
            }
            return match (reply.result, reply.error) {
                (_, Some(error)) if error.transient => Err(RigError::Transient(error.message)),
                (_, Some(error)) => Err(RigError::Transient(format!(
                    "driver error: {}",
                    error.message
                ))),
                (Some(result), None) => Ok(result),
                (None, None) => Ok(ReplyResult::default()),
            };
        }
    }

    fn missing(method: &str, field: &str) -> RigError {
        RigError::Fatal(format!("driver reply to `{method}` lacks `{field}`"))
    }
}

impl Rig for ExternalDriver {
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; 6]) -> Result<(), RigError> {
        self.call(Call::MoveJoints { cw_id, q_deg }).map(|_| ())
    }

    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError> {
        self.call(Call::ApplyWrench { wrench }).map(|_| ())
    }

    fn read_wrench(&mut self) -> Result<[f64; 6], RigError> {
        self.call(Call::ReadWrench {})?
            .wrench
            .ok_or_else(|| Self::missing("read_wrench", "wrench"))
    }

    fn read_joints(&mut self) -> Result<[f64; 6], RigError> {
        self.call(Call::ReadJoints {})?
            .q_deg
            .ok_or_else(|| Self::missing("read_joints", "q_deg"))
    }

    fn measure(&mut self) -> Result<[f64; 3], RigError> {
        let result = self.call(Call::Measure {})?;
        self.last_measured_at_us = result.measured_at_us.unwrap_or_else(now_us);
        result
            .position_mm
            .ok_or_else(|| Self::missing("measure", "position_mm"))
    }

    fn release_wrench(&mut self) -> Result<(), RigError> {
        self.call(Call::ReleaseWrench {}).map(|_| ())
    }

    fn measured_at_us(&self) -> i64 {
        self.last_measured_at_us
    }
}

impl Drop for ExternalDriver {
    fn drop(&mut self) {
        let _ = self.call(Call::Shutdown {});
        for _ in 0..50 {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A reply line for an error message: quoted with control characters escaped (a
/// garbage reply may hold any bytes), and cut short.
fn excerpt(line: &str) -> String {
    const SHOWN_CHARS: usize = 200;
    match line.char_indices().nth(SHOWN_CHARS) {
        Some((end, _)) => format!("{:?}… ({} bytes)", &line[..end], line.len()),
        None => format!("{line:?}"),
    }
}

fn now_us() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as i64)
}

/// Serves a rig over the protocol on the given streams until `shutdown` or EOF:
/// the server side, used by `egcal sim-driver` and by tests.
pub fn serve(
    rig: &mut dyn Rig,
    name: &str,
    input: impl BufRead,
    mut output: impl Write,
) -> std::io::Result<()> {
    for line in input.lines() {
        let line = line?;
        if line.trim().is_empty() {
            continue;
        }
        let request: Request = match serde_json::from_str(&line) {
            Ok(r) => r,
            Err(e) => {
                let reply = serde_json::json!({"id": 0, "error": {"message": format!("malformed request: {e}"), "transient": false}});
                writeln!(output, "{reply}")?;
                output.flush()?;
                continue;
            }
        };
        let mut result = ReplyResult::default();
        let outcome: Result<(), RigError> = match request.call {
            Call::Hello { .. } => {
                result.protocol = Some(PROTOCOL_VERSION);
                result.name = Some(name.to_string());
                result.capabilities = Some(
                    super::protocol::METHODS
                        .iter()
                        .map(|m| m.to_string())
                        .collect(),
                );
                Ok(())
            }
            Call::MoveJoints { cw_id, q_deg } => rig.move_joints(cw_id, q_deg),
            Call::ApplyWrench { wrench } => rig.apply_wrench(wrench),
            Call::ReleaseWrench {} => rig.release_wrench(),
            Call::ReadWrench {} => rig.read_wrench().map(|w| result.wrench = Some(w)),
            Call::ReadJoints {} => rig.read_joints().map(|q| result.q_deg = Some(q)),
            Call::Measure {} => rig.measure().map(|p| {
                result.position_mm = Some(p);
                result.measured_at_us = Some(rig.measured_at_us());
            }),
            Call::Shutdown {} => {
                writeln!(
                    output,
                    "{}",
                    serde_json::to_string(&Reply {
                        id: request.id,
                        result: Some(result),
                        error: None
                    })?
                )?;
                output.flush()?;
                return Ok(());
            }
        };
        let reply = match outcome {
            Ok(()) => Reply {
                id: request.id,
                result: Some(result),
                error: None,
            },
            Err(e) => Reply {
                id: request.id,
                result: None,
                error: Some(super::protocol::ReplyError {
                    message: e.to_string(),
                    transient: e.is_transient(),
                }),
            },
        };
        writeln!(output, "{}", serde_json::to_string(&reply)?)?;
        output.flush()?;
    }
    Ok(())
}
