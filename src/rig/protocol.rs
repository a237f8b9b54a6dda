//! The driver protocol: one JSON object per line over the driver's stdin/stdout.
//!
//! egcal sends `{"id": N, "method": "...", "params": {...}}` and waits (with a
//! timeout) for `{"id": N, "result": {...}}` or
//! `{"id": N, "error": {"message": "...", "transient": true}}`. A transient error
//! makes egcal retry the row; any other error, a malformed reply or a timeout is
//! recorded against the row. `schemas/driver-protocol.md` is the prose version and
//! `schemas/driver-protocol.schema.json` the message shapes, generated from here.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Protocol version sent in `hello`.
pub const PROTOCOL_VERSION: u32 = 1;

/// A request from egcal to the driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct Request {
    pub id: u64,
    #[serde(flatten)]
    pub call: Call,
}

/// The methods and their parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "method", content = "params", rename_all = "snake_case")]
pub enum Call {
    /// First message: protocol version; the reply names the driver and its capabilities.
    Hello { protocol: u32 },
    /// Move the robot to joint commands (deg) for conf-wrench row `cw_id`; reply when settled.
    MoveJoints { cw_id: i64, q_deg: [f64; 6] },
    /// Apply a wrench with the cable robot: fx, fy, fz (N), mx, my, mz (N·m), tool axes, tool origin.
    ApplyWrench { wrench: [f64; 6] },
    /// Release the cable tension.
    ReleaseWrench {},
    /// Read the force/torque sensor (same order and frame as apply_wrench).
    ReadWrench {},
    /// Read the joint encoders (deg).
    ReadJoints {},
    /// Measure the SMR with the laser tracker (mm, tracker frame).
    Measure {},
    /// Move a linear track's carriage to `e_mm` for row `cw_id` (robots on a
    /// track; sent before `move_joints`); reply when settled.
    MoveTrack { cw_id: i64, e_mm: f64 },
    /// Read the track's position encoder (mm).
    ReadTrack {},
    /// Point the tracker at the SMR `target_id` for the following `measure`s:
    /// the arm's SMR or a nest on the positioner's table (campaigns that
    /// measure a positioner's nests; sent first in every row).
    SelectTarget { target_id: String },
    /// Move the positioner's axes to `p_deg` (deg, one per axis) for row
    /// `cw_id` (rows measuring a nest; sent before `move_joints`); reply
    /// when settled.
    MovePositioner { cw_id: i64, p_deg: Vec<f64> },
    /// Read the positioner's axis encoders (deg, one per axis).
    ReadPositioner {},
    /// Park and exit.
    Shutdown {},
}

/// A reply from the driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Reply {
    pub id: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub result: Option<ReplyResult>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<ReplyError>,
}

/// The result fields; which are present depends on the method.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ReplyResult {
    /// hello: the protocol version the driver speaks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub protocol: Option<u32>,
    /// hello: a name for logs ("ABB IRC5 + FARO Vantage + cable robot v2").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// hello: the methods it implements.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub capabilities: Option<Vec<String>>,
    /// read_wrench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wrench: Option<[f64; 6]>,
    /// read_joints.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub q_deg: Option<[f64; 6]>,
    /// read_track: the carriage's position (mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub e_mm: Option<f64>,
    /// read_positioner: the axes' positions (deg, one per axis).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p_deg: Option<Vec<f64>>,
    /// measure.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_mm: Option<[f64; 3]>,
    /// measure: time of the reading, µs since the epoch, UTC (egcal's clock when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_at_us: Option<i64>,
    /// measure: the tracker's own 1-σ uncertainty of the point along x, y, z
    /// (mm, > 0), stored as `sigma_x_mm` … (spec §7) when given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_mm: Option<[f64; 3]>,
}

/// An error reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ReplyError {
    pub message: String,
    /// True when retrying the row may succeed (beam lost, busy).
    #[serde(default)]
    pub transient: bool,
    /// What went wrong, from a small vocabulary (optional: version 1 drivers
    /// may send only `message` and `transient`, and such errors are retried).
    /// `estop`, `not_connected`, `exclusive_owner`, `unit_mismatch` and
    /// `protocol` stop the campaign (it resumes on the next run); with another
    /// code the row is retried when `transient`, else recorded as failed at once.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub code: Option<ErrorCode>,
}

/// The error vocabulary of driver replies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// A device did not answer in time.
    Timeout,
    /// A device the method needs is not configured or not reachable.
    NotConnected,
    /// The device is doing something else; try again.
    Busy,
    /// The device is not ready yet (warming up, motors off, program stopped).
    NotReady,
    /// The tracker lost the beam or saw no reflector.
    BeamLost,
    /// Another client holds the device (mastership, a stolen stream).
    ExclusiveOwner,
    /// The request or a reading is outside what the device can do.
    OutOfRange,
    /// The reading is old (a stalled or backward sequence counter).
    StaleData,
    /// Samples were lost between readings.
    SequenceGap,
    /// The device reports other units than were configured.
    UnitMismatch,
    /// The device's reply broke its protocol.
    Protocol,
    /// The emergency stop is pressed or the controller is in a safety stop.
    Estop,
}

impl ErrorCode {
    /// Errors after which the campaign stops rather than failing the row.
    pub fn stops_campaign(self) -> bool {
        matches!(
            self,
            ErrorCode::Estop
                | ErrorCode::NotConnected
                | ErrorCode::ExclusiveOwner
                | ErrorCode::Protocol
                | ErrorCode::UnitMismatch
        )
    }

    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::Timeout => "timeout",
            ErrorCode::NotConnected => "not_connected",
            ErrorCode::Busy => "busy",
            ErrorCode::NotReady => "not_ready",
            ErrorCode::BeamLost => "beam_lost",
            ErrorCode::ExclusiveOwner => "exclusive_owner",
            ErrorCode::OutOfRange => "out_of_range",
            ErrorCode::StaleData => "stale_data",
            ErrorCode::SequenceGap => "sequence_gap",
            ErrorCode::UnitMismatch => "unit_mismatch",
            ErrorCode::Protocol => "protocol",
            ErrorCode::Estop => "estop",
        }
    }
}

/// The methods of a linear track's axis: a driver of a robot on a track
/// announces them in `hello`'s capabilities.
pub const TRACK_METHODS: [&str; 2] = ["move_track", "read_track"];

/// The methods of a campaign that measures a positioner's nests: a driver
/// of such a cell announces them in `hello`'s capabilities.
pub const POSITIONER_METHODS: [&str; 3] = ["select_target", "move_positioner", "read_positioner"];

/// Method names, as capabilities (the track's are [`TRACK_METHODS`], the
/// positioner's [`POSITIONER_METHODS`]).
pub const METHODS: [&str; 8] = [
    "hello",
    "move_joints",
    "apply_wrench",
    "release_wrench",
    "read_wrench",
    "read_joints",
    "measure",
    "shutdown",
];

/// JSON Schema of both message kinds, for `schemas/driver-protocol.schema.json`.
pub fn schema_json() -> String {
    let schema = serde_json::json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "egcal driver protocol v1",
        "description": "One JSON object per line. egcal writes Request objects to the driver's stdin and reads Reply objects from its stdout.",
        "$defs": {
            "Request": schemars::schema_for!(Request),
            "Reply": schemars::schema_for!(Reply),
        },
    });
    let mut text = serde_json::to_string_pretty(&schema).expect("schema serialises");
    text.push('\n');
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_format_is_stable() {
        let request = Request {
            id: 3,
            call: Call::MoveJoints {
                cw_id: 12,
                q_deg: [0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
            },
        };
        let line = serde_json::to_string(&request).unwrap();
        assert_eq!(
            line,
            r#"{"id":3,"method":"move_joints","params":{"cw_id":12,"q_deg":[0.0,1.0,2.0,3.0,4.0,5.0]}}"#
        );
        assert_eq!(serde_json::from_str::<Request>(&line).unwrap(), request);
        let measure: Request =
            serde_json::from_str(r#"{"id":4,"method":"measure","params":{}}"#).unwrap();
        assert_eq!(measure.call, Call::Measure {});
        let reply: Reply =
            serde_json::from_str(r#"{"id":4,"error":{"message":"beam lost","transient":true}}"#)
                .unwrap();
        assert!(reply.error.unwrap().transient);
    }

    #[test]
    fn coded_errors_and_sigmas_are_optional_additions_to_version_1() {
        let coded: Reply = serde_json::from_str(
            r#"{"id":5,"error":{"message":"no reflector","transient":true,"code":"beam_lost"}}"#,
        )
        .unwrap();
        assert_eq!(coded.error.unwrap().code, Some(ErrorCode::BeamLost));
        let measured: Reply = serde_json::from_str(
            r#"{"id":6,"result":{"position_mm":[1,2,3],"sigma_mm":[0.01,0.01,0.02]}}"#,
        )
        .unwrap();
        assert_eq!(measured.result.unwrap().sigma_mm, Some([0.01, 0.01, 0.02]));
        let unknown =
            serde_json::from_str::<Reply>(r#"{"id":5,"error":{"message":"x","code":"on_fire"}}"#);
        assert!(
            unknown.is_err(),
            "codes outside the vocabulary are protocol errors"
        );
        let line = serde_json::to_string(&ReplyError {
            message: "m".into(),
            transient: false,
            code: None,
        })
        .unwrap();
        assert_eq!(
            line, r#"{"message":"m","transient":false}"#,
            "version 1 shape kept"
        );
    }
}
