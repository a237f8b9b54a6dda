//! The external-driver adapter: starts the lab's driver program and speaks the
//! line-delimited JSON [`protocol`](super::protocol) over its stdin/stdout, each
//! request with a timeout.
//!
//! A reader thread forwards the driver's stdout lines over a channel so a request
//! can time out without blocking; a late reply to a timed-out request is recognised
//! by its id and dropped. The driver's stderr passes through to ours (its logs).
//!
//! The driver runs in the job file's folder, so a job and its driver script move
//! together. When its pipes break, egcal waits briefly for the process and says
//! how it ended (exit status or signal): "stopped reading" alone sends the lab
//! looking in the wrong place.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::time::Duration;

use super::protocol::{Call, PROTOCOL_VERSION, Reply, ReplyResult, Request};
use super::{Rig, RigError};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{MAX_JOINTS, joint_array};

/// A running driver process.
pub struct ExternalDriver {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<String>,
    next_id: u64,
    timeout: Duration,
    last_measured_at_us: i64,
    last_sigma_mm: Option<[f64; 3]>,
    /// The driver's self-description from `hello`.
    pub name: String,
    /// The methods `hello` announced (empty when it announced none).
    pub capabilities: Vec<String>,
    /// How many axis values `move_positioner` sends and `read_positioner`
    /// expects: the robot file's positioner's.
    positioner_axes: usize,
}

impl ExternalDriver {
    /// Starts `command` (program and arguments) in `dir`, the job file's folder,
    /// and exchanges `hello`. A relative program path with a `/` in it
    /// (`./driver.sh`, `bin/driver`) is taken relative to `dir`, the way a lab
    /// writes it in its job file; a bare name (`python3`) is looked up on `PATH`.
    /// Every failure names the command, since nothing else has been learned of the
    /// driver yet.
    pub fn start(command: &[String], dir: &Path, timeout: Duration) -> Result<Self, RigError> {
        let (program, args) = command
            .split_first()
            .ok_or_else(|| RigError::Fatal("driver command is empty".into()))?;
        let shown = command.join(" ");
        // Absolute, because a relative program path combined with `current_dir`
        // is resolved differently on different platforms (std::process::Command).
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let dir = std::path::absolute(dir).map_err(|e| {
            RigError::Fatal(format!(
                "cannot start driver `{shown}` in {}: {e}",
                dir.display()
            ))
        })?;
        let program_path = if program.contains('/') {
            dir.join(program)
        } else {
            PathBuf::from(program)
        };
        let mut child = Command::new(&program_path)
            .args(args)
            .current_dir(&dir)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| {
                RigError::Fatal(format!(
                    "cannot start driver `{shown}` in {}: {}: {e}",
                    dir.display(),
                    program_path.display()
                ))
            })?;
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
            last_sigma_mm: None,
            name: String::new(),
            capabilities: Vec::new(),
            positioner_axes: 0,
        };
        let at_start =
            |problem: String| RigError::Fatal(format!("starting driver `{shown}`: {problem}"));
        let hello = match driver.call(Call::Hello {
            protocol: PROTOCOL_VERSION,
        }) {
            Ok(hello) => hello,
            Err(e) => {
                // No polite `shutdown` to a driver that failed `hello`: it may hang.
                let _ = driver.child.kill();
                let _ = driver.child.wait();
                return Err(at_start(e.to_string()));
            }
        };
        match hello.protocol {
            Some(PROTOCOL_VERSION) => {}
            other => {
                return Err(at_start(format!(
                    "it speaks protocol {}, egcal speaks {PROTOCOL_VERSION}",
                    other.map_or("(none given)".into(), |v| v.to_string())
                )));
            }
        }
        driver.name = hello.name.unwrap_or(shown);
        driver.capabilities = hello.capabilities.unwrap_or_default();
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
        // A driver that never answers its first request is usually one that does
        // not read stdin line by line or does not flush its replies.
        let hint = if matches!(call, Call::Hello { .. }) {
            "; does it read requests from stdin and flush each reply line?"
        } else {
            ""
        };
        let line = serde_json::to_string(&Request { id, call }).expect("request serialises");
        if let Err(e) = writeln!(self.stdin, "{line}").and_then(|_| self.stdin.flush()) {
            return Err(RigError::Fatal(match self.exit_status() {
                Some(status) => format!("driver {} during `{method}`", describe_exit(status)),
                None => format!("driver stopped reading its stdin during `{method}`: {e}"),
            }));
        }
        loop {
            let line = match self.lines.recv_timeout(self.timeout) {
                Ok(line) => line,
                Err(RecvTimeoutError::Timeout) => {
                    return Err(RigError::Transient(format!(
                        "driver did not answer `{method}` within {:.1} s{hint}",
                        self.timeout.as_secs_f64()
                    )));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(RigError::Fatal(match self.exit_status() {
                        Some(status) => {
                            format!("driver {} during `{method}`", describe_exit(status))
                        }
                        None => format!("driver closed its stdout during `{method}`"),
                    }));
                }
            };
            let reply = parse_reply(&line, &method)?;
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
                (_, Some(error)) => Err(reply_error(error)),
                (Some(result), None) => Ok(result),
                (None, None) => Ok(ReplyResult::default()),
            };
        }
    }

    /// The driver's exit status once its pipes broke: it has usually exited but
    /// may not have been reaped yet, so this waits up to a second for it; `None`
    /// when it is still running (it closed a pipe but lives on).
    fn exit_status(&mut self) -> Option<ExitStatus> {
        for _ in 0..EXIT_POLLS {
            match self.child.try_wait() {
                Ok(Some(status)) => return Some(status),
                Ok(None) => std::thread::sleep(EXIT_POLL_INTERVAL),
                Err(_) => return None,
            }
        }
        None
    }

    fn missing(method: &str, field: &str) -> RigError {
        RigError::Fatal(format!("driver reply to `{method}` lacks `{field}`"))
    }

    /// Whether `hello` announced a linear track's methods.
    pub fn drives_a_track(&self) -> bool {
        super::protocol::TRACK_METHODS
            .iter()
            .all(|m| self.capabilities.iter().any(|c| c == m))
    }

    /// The robot file's positioner axes count, for `move_positioner` and
    /// `read_positioner`.
    pub fn with_positioner_axes(mut self, axes: usize) -> Self {
        self.positioner_axes = axes;
        self
    }

    /// Whether `hello` announced every method of a campaign measuring a
    /// positioner's nests.
    pub fn drives_a_positioner(&self) -> bool {
        super::protocol::POSITIONER_METHODS
            .iter()
            .all(|m| self.capabilities.iter().any(|c| c == m))
    }
}

impl Rig for ExternalDriver {
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; MAX_JOINTS]) -> Result<(), RigError> {
        // The protocol moves six joints; `measure` refuses a seven-joint arm
        // on a driver.
        let q_deg = std::array::from_fn(|i| q_deg[i]);
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

    fn read_joints(&mut self) -> Result<[f64; MAX_JOINTS], RigError> {
        self.call(Call::ReadJoints {})?
            .q_deg
            .map(|q| joint_array(&q))
            .ok_or_else(|| Self::missing("read_joints", "q_deg"))
    }

    fn measure(&mut self) -> Result<[f64; 3], RigError> {
        let result = self.call(Call::Measure {})?;
        self.last_measured_at_us = result.measured_at_us.unwrap_or_else(now_us);
        self.last_sigma_mm = match result.sigma_mm {
            Some(sigma) if sigma.iter().all(|s| s.is_finite() && *s > 0.0) => Some(sigma),
            Some(sigma) => {
                return Err(RigError::Fatal(format!(
                    "driver replied to measure with sigma_mm {sigma:?}: expected three positive finite values (mm)"
                )));
            }
            None => None,
        };
        result
            .position_mm
            .ok_or_else(|| Self::missing("measure", "position_mm"))
    }

    fn measured_sigma_mm(&self) -> Option<[f64; 3]> {
        self.last_sigma_mm
    }

    fn move_track(&mut self, cw_id: i64, e_mm: f64) -> Result<(), RigError> {
        self.call(Call::MoveTrack { cw_id, e_mm }).map(|_| ())
    }

    fn read_track(&mut self) -> Result<f64, RigError> {
        self.call(Call::ReadTrack {})?
            .e_mm
            .ok_or_else(|| Self::missing("read_track", "e_mm"))
    }

    fn select_target(&mut self, target_id: &str) -> Result<(), RigError> {
        self.call(Call::SelectTarget {
            target_id: target_id.to_string(),
        })
        .map(|_| ())
    }

    fn move_positioner(
        &mut self,
        cw_id: i64,
        p_deg: [f64; MAX_POSITIONER_AXES],
    ) -> Result<(), RigError> {
        let p_deg = p_deg[..self.positioner_axes].to_vec();
        self.call(Call::MovePositioner { cw_id, p_deg }).map(|_| ())
    }

    fn read_positioner(&mut self) -> Result<[f64; MAX_POSITIONER_AXES], RigError> {
        let read = self
            .call(Call::ReadPositioner {})?
            .p_deg
            .ok_or_else(|| Self::missing("read_positioner", "p_deg"))?;
        if read.len() != self.positioner_axes {
            return Err(RigError::Fatal(format!(
                "driver replied to read_positioner with {} value(s), expected one per axis of the robot file's positioner ({})",
                read.len(),
                self.positioner_axes
            )));
        }
        let mut p_deg = [0.0; MAX_POSITIONER_AXES];
        p_deg[..read.len()].copy_from_slice(&read);
        Ok(p_deg)
    }

    fn release_wrench(&mut self) -> Result<(), RigError> {
        self.call(Call::ReleaseWrench {}).map(|_| ())
    }

    fn measured_at_us(&self) -> i64 {
        self.last_measured_at_us
    }
}

/// What an error reply means for the campaign: a coded error keeps its code
/// (which decides between retrying, failing the row and stopping, see
/// [`RigError::disposition`]); an uncoded one (protocol version 1) is retried.
fn reply_error(error: super::protocol::ReplyError) -> RigError {
    match error.code {
        Some(code) => RigError::device(code, error.transient, error.message),
        None if error.transient => RigError::Transient(error.message),
        None => RigError::Transient(format!("driver error: {}", error.message)),
    }
}

impl Drop for ExternalDriver {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return; // already exited (died, or killed after a failed `hello`)
        }
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

/// One reply line as the driver sent it (any bytes, made UTF-8 lossily): a
/// [`Reply`], or a fatal error quoting the line. Never panics, whatever the line.
fn parse_reply(line: &str, method: &str) -> Result<Reply, RigError> {
    serde_json::from_str(line).map_err(|e| {
        RigError::Fatal(format!(
            "driver sent a malformed reply to `{method}`: {e}: {}",
            excerpt(line)
        ))
    })
}

/// How long [`ExternalDriver::exit_status`] waits for a driver whose pipes broke.
const EXIT_POLLS: u32 = 50;
const EXIT_POLL_INTERVAL: Duration = Duration::from_millis(20);

/// How a driver ended, for messages: "exited with status 3", "was killed by
/// signal 9 (SIGKILL)". A signal says more than a missing status code: the lab's
/// driver crashed (SIGSEGV, SIGABRT) or was killed by someone (SIGKILL, SIGTERM).
fn describe_exit(status: ExitStatus) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(signal) = status.signal() {
            let name = match signal {
                1 => " (SIGHUP)",
                2 => " (SIGINT)",
                6 => " (SIGABRT)",
                9 => " (SIGKILL)",
                11 => " (SIGSEGV)",
                13 => " (SIGPIPE)",
                15 => " (SIGTERM)",
                _ => "",
            };
            let core = if status.core_dumped() {
                ", core dumped"
            } else {
                ""
            };
            return format!("was killed by signal {signal}{name}{core}");
        }
    }
    match status.code() {
        Some(code) => format!("exited with status {code}"),
        None => format!("exited ({status})"),
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
/// the server side, used by `egcal sim-driver`, `egcal lab-driver` and by tests.
/// `capabilities`: the methods `hello` announces.
pub fn serve(
    rig: &mut dyn Rig,
    name: &str,
    capabilities: &[String],
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
            Call::Hello { .. } => rig.ready().map(|()| {
                result.protocol = Some(PROTOCOL_VERSION);
                result.name = Some(name.to_string());
                result.capabilities = Some(capabilities.to_vec());
            }),
            Call::MoveJoints { cw_id, q_deg } => rig.move_joints(cw_id, joint_array(&q_deg)),
            Call::ApplyWrench { wrench } => rig.apply_wrench(wrench),
            Call::ReleaseWrench {} => rig.release_wrench(),
            Call::ReadWrench {} => rig.read_wrench().map(|w| result.wrench = Some(w)),
            Call::ReadJoints {} => rig
                .read_joints()
                .map(|q| result.q_deg = Some(std::array::from_fn(|i| q[i]))),
            Call::MoveTrack { cw_id, e_mm } => rig.move_track(cw_id, e_mm),
            Call::ReadTrack {} => rig.read_track().map(|e| result.e_mm = Some(e)),
            Call::SelectTarget { target_id } => rig.select_target(&target_id),
            Call::MovePositioner { cw_id, p_deg } => {
                if p_deg.is_empty() || p_deg.len() > MAX_POSITIONER_AXES {
                    Err(RigError::Fatal(format!(
                        "move_positioner: {} axis value(s), expected 1 to {MAX_POSITIONER_AXES}",
                        p_deg.len()
                    )))
                } else {
                    let mut padded = [0.0; MAX_POSITIONER_AXES];
                    padded[..p_deg.len()].copy_from_slice(&p_deg);
                    rig.move_positioner(cw_id, padded)
                }
            }
            Call::ReadPositioner {} => rig
                .read_positioner()
                .map(|p| result.p_deg = Some(p[..rig.positioner_axes()].to_vec())),
            Call::Measure {} => rig.measure().map(|p| {
                result.position_mm = Some(p);
                result.measured_at_us = Some(rig.measured_at_us());
                result.sigma_mm = rig.measured_sigma_mm();
            }),
            Call::Shutdown {} => {
                rig.shutdown();
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
                    message: match &e {
                        RigError::Device { message, .. } => message.clone(),
                        other => other.to_string(),
                    },
                    transient: e.is_transient(),
                    code: e.code(),
                }),
            },
        };
        writeln!(output, "{}", serde_json::to_string(&reply)?)?;
        output.flush()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn any_reply_line_parses_or_is_a_fatal_error_quoting_it() {
        let deep = "[".repeat(100_000);
        // Unterminated: a driver that died mid-line, or a reply cut at a pipe buffer.
        let long = format!(r#"{{"id": 1, "result": {{"name": "{}"#, "é".repeat(100_000));
        let lossy = String::from_utf8_lossy(b"\xff\xfe\x00\x01{\"id\":1}\xc3").into_owned();
        let nasty = [
            "",
            " ",
            "null",
            "[]",
            "{}",
            "1",
            "\"text\"",
            deep.as_str(),
            long.as_str(),
            lossy.as_str(),
            "{\"id\": -1}",
            "{\"id\": 1e30}",
            "{\"id\": 18446744073709551616}",
            "{\"id\": \"1\"}",
            "{\"id\": 1, \"id\": 2}",
            "{\"id\": 1, \"surprise\": true}",
            "{\"id\": 1, \"result\": {\"position_mm\": [1e400, 0, 0]}}",
            "{\"id\": 1, \"result\": {\"position_mm\": [NaN, 0, 0]}}",
            "{\"id\": 1, \"result\": {\"q_deg\": [1, 2, 3, 4, 5, 6, 7]}}",
            "{\"id\": 1, \"result\": {\"name\": \"\\ud800\"}}",
            "{\"id\": 1, \"error\": {\"message\": null}}",
            "{\"id\": 1, \"result\": {}} trailing",
            "{\"id\": 1, \"result\": {\"wrench\": [0,0,0,0,0,0]}}",
        ];
        let mut parsed = 0;
        for line in nasty {
            match parse_reply(line, "measure") {
                Ok(reply) => {
                    assert_eq!(reply.id, 1, "{line:.80}");
                    parsed += 1;
                }
                Err(RigError::Fatal(message)) => {
                    assert!(
                        message.starts_with("driver sent a malformed reply to `measure`: ")
                            && message.len() < 1000,
                        "{message}"
                    );
                }
                Err(other) => panic!("{other:?} for {line:.80}"),
            }
        }
        // The last line above, the one well-formed reply, and only it, parses.
        assert_eq!(parsed, 1);
        assert!(parse_reply(nasty[nasty.len() - 1], "measure").is_ok());
        // Cut on a character boundary, with the full length given.
        let message = parse_reply(&long, "hello").map_or_else(|e| e.to_string(), |_| String::new());
        assert!(
            message.ends_with(&format!("… ({} bytes)", long.len())),
            "{message:.300}"
        );
    }

    #[cfg(unix)]
    #[test]
    fn an_exit_is_described_by_its_status_or_signal() {
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(
            describe_exit(ExitStatus::from_raw(3 << 8)),
            "exited with status 3"
        );
        assert_eq!(
            describe_exit(ExitStatus::from_raw(9)),
            "was killed by signal 9 (SIGKILL)"
        );
        assert_eq!(
            describe_exit(ExitStatus::from_raw(11 | 0x80)),
            "was killed by signal 11 (SIGSEGV), core dumped"
        );
        assert_eq!(
            describe_exit(ExitStatus::from_raw(64)),
            "was killed by signal 64"
        );
    }
}
