//! The cell file of `egcal lab-driver`: which devices the cell has, where they
//! are and how to talk to them. Parsed strictly (unknown keys are errors, with the
//! file and key); a device left out makes the methods that need it answer
//! `not_connected`. JSON Schema: `schemas/cell.schema.json`.
//!
//! ```toml
//! [cell]
//! name = "cell_3"
//!
//! [force_sensor]
//! kind = "ati_netft"
//! address = "192.168.1.1"
//! samples = 100
//!
//! [cable_robot]
//! kind = "egcal_udp"
//! address = "192.168.1.20"
//! ```

use std::path::{Path, PathBuf};

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// The `[cell]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CellHeader {
    /// Name of the cell, in the driver's `hello` reply and in logs.
    pub name: String,
    /// Time limit of one exchange with a device, s (a device's own `timeout_s`
    /// overrides it).
    #[serde(default = "default_timeout_s")]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub timeout_s: f64,
}

fn default_timeout_s() -> f64 {
    2.0
}

/// Force units an ATI box can be configured for (its `cfgfu` codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum ForceUnit {
    #[serde(rename = "lbf")]
    Lbf,
    #[serde(rename = "N")]
    Newton,
    #[serde(rename = "klbf")]
    Klbf,
    #[serde(rename = "kN")]
    KiloNewton,
    #[serde(rename = "kgf")]
    Kgf,
    #[serde(rename = "gf")]
    Gf,
}

/// Torque units an ATI box can be configured for (its `cfgtu` codes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum TorqueUnit {
    #[serde(rename = "lbf-in")]
    LbfIn,
    #[serde(rename = "lbf-ft")]
    LbfFt,
    #[serde(rename = "N-m")]
    NewtonMetre,
    #[serde(rename = "N-mm")]
    NewtonMillimetre,
    #[serde(rename = "kgf-cm")]
    KgfCm,
    #[serde(rename = "kN-m")]
    KiloNewtonMetre,
}

impl ForceUnit {
    /// The unit of an ATI `cfgfu` code.
    pub fn from_code(code: u32) -> Option<ForceUnit> {
        [
            ForceUnit::Lbf,
            ForceUnit::Newton,
            ForceUnit::Klbf,
            ForceUnit::KiloNewton,
            ForceUnit::Kgf,
            ForceUnit::Gf,
        ]
        .get((code as usize).wrapping_sub(1))
        .copied()
    }

    /// The unit as the cell file spells it.
    pub fn label(self) -> &'static str {
        match self {
            ForceUnit::Lbf => "lbf",
            ForceUnit::Newton => "N",
            ForceUnit::Klbf => "klbf",
            ForceUnit::KiloNewton => "kN",
            ForceUnit::Kgf => "kgf",
            ForceUnit::Gf => "gf",
        }
    }

    /// One of this unit in newtons.
    pub fn newtons(self) -> f64 {
        match self {
            ForceUnit::Lbf => 4.448_221_615_260_5,
            ForceUnit::Newton => 1.0,
            ForceUnit::Klbf => 4_448.221_615_260_5,
            ForceUnit::KiloNewton => 1_000.0,
            ForceUnit::Kgf => 9.806_65,
            ForceUnit::Gf => 0.009_806_65,
        }
    }
}

impl TorqueUnit {
    /// The unit of an ATI `cfgtu` code.
    pub fn from_code(code: u32) -> Option<TorqueUnit> {
        [
            TorqueUnit::LbfIn,
            TorqueUnit::LbfFt,
            TorqueUnit::NewtonMetre,
            TorqueUnit::NewtonMillimetre,
            TorqueUnit::KgfCm,
            TorqueUnit::KiloNewtonMetre,
        ]
        .get((code as usize).wrapping_sub(1))
        .copied()
    }

    /// The unit as the cell file spells it.
    pub fn label(self) -> &'static str {
        match self {
            TorqueUnit::LbfIn => "lbf-in",
            TorqueUnit::LbfFt => "lbf-ft",
            TorqueUnit::NewtonMetre => "N-m",
            TorqueUnit::NewtonMillimetre => "N-mm",
            TorqueUnit::KgfCm => "kgf-cm",
            TorqueUnit::KiloNewtonMetre => "kN-m",
        }
    }

    /// One of this unit in newton-metres.
    pub fn newton_metres(self) -> f64 {
        match self {
            TorqueUnit::LbfIn => 0.112_984_829_027_616_7,
            TorqueUnit::LbfFt => 1.355_817_948_331_400_4,
            TorqueUnit::NewtonMetre => 1.0,
            TorqueUnit::NewtonMillimetre => 0.001,
            TorqueUnit::KgfCm => 0.098_066_5,
            TorqueUnit::KiloNewtonMetre => 1_000.0,
        }
    }
}

/// An ATI Net F/T or Ethernet Axia box.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct NetFtSettings {
    /// Host name or IP address of the box.
    pub address: String,
    /// Port of its web server (`netftapi2.xml`, the calibration and units).
    #[serde(default = "default_http_port")]
    #[schemars(range(min = 1, max = 65535))]
    pub http_port: u16,
    /// Port of its RDT (UDP) stream.
    #[serde(default = "default_rdt_port")]
    #[schemars(range(min = 1, max = 65535))]
    pub rdt_port: u16,
    /// RDT records averaged into one reading (at the box's RDT rate, e.g. 100
    /// records at 1 kHz = 0.1 s).
    #[serde(default = "default_samples")]
    #[schemars(range(min = 1, max = 100_000))]
    pub samples: u32,
    /// The force unit the box must be configured for; another is refused
    /// (`unit_mismatch`) rather than converted, since a changed configuration
    /// usually means a changed calibration too.
    #[serde(default = "default_force_unit")]
    pub force_unit: ForceUnit,
    /// The torque unit the box must be configured for.
    #[serde(default = "default_torque_unit")]
    pub torque_unit: TorqueUnit,
    /// Zero the sensor (software bias, RDT command 0x0042) when the driver
    /// starts, unloaded; verified by fresh readings within the tolerances below.
    #[serde(default)]
    pub bias_at_start: bool,
    /// Largest force a reading right after the bias may show, N.
    #[serde(default = "default_bias_tolerance_n")]
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub bias_tolerance_n: f64,
    /// Largest moment a reading right after the bias may show, N·m.
    #[serde(default = "default_bias_tolerance_nm")]
    #[schemars(range(min = 0.0, max = 100.0))]
    pub bias_tolerance_nm: f64,
    /// Time limit of one exchange, s; the cell's `timeout_s` when absent.
    #[serde(default)]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub timeout_s: Option<f64>,
}

fn default_http_port() -> u16 {
    80
}
fn default_rdt_port() -> u16 {
    49152
}
fn default_samples() -> u32 {
    100
}
fn default_force_unit() -> ForceUnit {
    ForceUnit::Newton
}
fn default_torque_unit() -> TorqueUnit {
    TorqueUnit::NewtonMetre
}
fn default_bias_tolerance_n() -> f64 {
    0.5
}
fn default_bias_tolerance_nm() -> f64 {
    0.05
}

/// The force/torque sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ForceSensor {
    /// ATI Net F/T or Ethernet Axia: calibration over HTTP, readings over RDT (UDP).
    AtiNetft(NetFtSettings),
}

/// A cable-robot controller speaking egcal's UDP protocol
/// (`schemas/cable-robot-udp.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CableUdpSettings {
    pub address: String,
    #[serde(default = "default_cable_port")]
    #[schemars(range(min = 1, max = 65535))]
    pub port: u16,
    /// Largest difference between achieved and set force for "holding", N.
    #[serde(default = "default_force_tolerance_n")]
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub force_tolerance_n: f64,
    /// Largest difference between achieved and set moment for "holding", N·m.
    #[serde(default = "default_moment_tolerance_nm")]
    #[schemars(range(min = 0.0, max = 100.0))]
    pub moment_tolerance_nm: f64,
    /// Longest wait for the set-point to be held (or the tension released), s.
    #[serde(default = "default_settle_timeout_s")]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub settle_timeout_s: f64,
    /// Interval between status requests while waiting, ms.
    #[serde(default = "default_poll_ms")]
    #[schemars(range(min = 1, max = 10_000))]
    pub poll_ms: u64,
    /// Time limit of one request, s; the cell's `timeout_s` when absent.
    #[serde(default)]
    #[schemars(range(min = 0.001, max = 3600.0))]
    pub timeout_s: Option<f64>,
}

fn default_cable_port() -> u16 {
    30500
}
fn default_force_tolerance_n() -> f64 {
    2.0
}
fn default_moment_tolerance_nm() -> f64 {
    0.2
}
fn default_settle_timeout_s() -> f64 {
    10.0
}
fn default_poll_ms() -> u64 {
    20
}

/// The cable robot that loads the end effector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum CableRobot {
    /// A controller speaking egcal's UDP protocol (`schemas/cable-robot-udp.md`).
    EgcalUdp(CableUdpSettings),
}

/// The robot controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Robot {
    /// An ABB IRC5 or OmniCore controller over Robot Web Services, moving
    /// through the RAPID server loop of `jobs/lab/EgcalServer.mod`.
    AbbRws(super::rws::RwsSettings),
}

/// The laser tracker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Tracker {
    /// A Leica tracker over emScon TPI (TCP port 700).
    LeicaEmscon(super::emscon::EmsconSettings),
}

/// The whole cell file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CellFile {
    pub cell: CellHeader,
    #[serde(default)]
    pub robot: Option<Robot>,
    #[serde(default)]
    pub tracker: Option<Tracker>,
    #[serde(default)]
    pub force_sensor: Option<ForceSensor>,
    #[serde(default)]
    pub cable_robot: Option<CableRobot>,
}

/// The file as parsed before each device's `kind` picks its settings type (so
/// that a problem in a device's table is named by its key, which serde's tagged
/// enums lose).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CellFileRaw {
    cell: CellHeader,
    #[serde(default)]
    robot: Option<toml::Table>,
    #[serde(default)]
    tracker: Option<toml::Table>,
    #[serde(default)]
    force_sensor: Option<toml::Table>,
    #[serde(default)]
    cable_robot: Option<toml::Table>,
}

/// The `kind` of a device table, one of `kinds`.
fn device_kind<'a>(
    table: &toml::Table,
    key: &str,
    kinds: &[&'a str],
) -> Result<&'a str, (String, String)> {
    let kind = table
        .get("kind")
        .and_then(toml::Value::as_str)
        .ok_or_else(|| {
            (
                format!("{key}.kind"),
                format!("required: one of {}", kinds.join(", ")),
            )
        })?;
    kinds.iter().find(|k| **k == kind).copied().ok_or_else(|| {
        (
            format!("{key}.kind"),
            format!("`{kind}`: expected one of {}", kinds.join(", ")),
        )
    })
}

/// A device table without its `kind` as settings of type `T`, problems by key.
fn device_settings<T: serde::de::DeserializeOwned>(
    mut table: toml::Table,
    key: &str,
) -> Result<T, (String, String)> {
    table.remove("kind");
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        (
            format!("{key}.{}", e.path()),
            e.inner().message().to_string(),
        )
    })
}

/// Whether `value` is an IP address or a host name (RFC 1123 labels of
/// letters, digits and `-`, at most 63 characters each, 253 in all).
fn is_host(value: &str) -> bool {
    if value.parse::<std::net::IpAddr>().is_ok() {
        return true;
    }
    value.len() <= 253
        && value.split('.').all(|label| {
            (1..=63).contains(&label.len())
                && !label.starts_with('-')
                && !label.ends_with('-')
                && label.chars().all(|c| c.is_ascii_alphanumeric() || c == '-')
        })
}

/// A bad cell file: the file, the key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}{}: {message}", file.display(), if key.is_empty() { String::new() } else { format!(": {key}") })]
pub struct CellFileError {
    pub file: PathBuf,
    pub key: String,
    pub message: String,
}

impl CellFile {
    pub fn load(path: &Path) -> Result<CellFile, CellFileError> {
        let bad = |key: &str, message: String| CellFileError {
            file: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        let text = std::fs::read_to_string(path)
            .map_err(|e| bad("", format!("cannot read the cell file: {e}")))?;
        let raw: CellFileRaw = crate::toml_error::from_str_strict(&text).map_err(|e| match e {
            crate::toml_error::StrictError::Syntax(message) => {
                bad("", format!("invalid TOML: {message}"))
            }
            crate::toml_error::StrictError::Invalid { key, message } => bad(&key, message),
        })?;
        let cell = CellFile {
            cell: raw.cell,
            robot: raw
                .robot
                .map(|table| {
                    device_kind(&table, "robot", &["abb_rws"])?;
                    device_settings(table, "robot").map(Robot::AbbRws)
                })
                .transpose()
                .map_err(|(key, message)| bad(&key, message))?,
            tracker: raw
                .tracker
                .map(|table| {
                    device_kind(&table, "tracker", &["leica_emscon"])?;
                    device_settings(table, "tracker").map(Tracker::LeicaEmscon)
                })
                .transpose()
                .map_err(|(key, message)| bad(&key, message))?,
            force_sensor: raw
                .force_sensor
                .map(|table| {
                    device_kind(&table, "force_sensor", &["ati_netft"])?;
                    device_settings(table, "force_sensor").map(ForceSensor::AtiNetft)
                })
                .transpose()
                .map_err(|(key, message)| bad(&key, message))?,
            cable_robot: raw
                .cable_robot
                .map(|table| {
                    device_kind(&table, "cable_robot", &["egcal_udp"])?;
                    device_settings(table, "cable_robot").map(CableRobot::EgcalUdp)
                })
                .transpose()
                .map_err(|(key, message)| bad(&key, message))?,
        };
        cell.check().map_err(|(key, message)| bad(&key, message))?;
        Ok(cell)
    }

    /// Ranges the types cannot express; (key, message) of the first problem.
    fn check(&self) -> Result<(), (String, String)> {
        let positive = |key: &str, value: f64, max: f64| {
            if value.is_finite() && value > 0.0 && value <= max {
                Ok(())
            } else {
                Err((
                    key.to_string(),
                    format!("{value}: expected > 0 and ≤ {max}"),
                ))
            }
        };
        let within = |key: &str, value: f64, max: f64| {
            if value.is_finite() && (0.0..=max).contains(&value) {
                Ok(())
            } else {
                Err((key.to_string(), format!("{value}: expected 0 to {max}")))
            }
        };
        let address = |key: &str, value: &str| {
            if value.trim().is_empty() {
                Err((
                    key.to_string(),
                    "required: a host name or IP address".to_string(),
                ))
            } else if !is_host(value) {
                Err((
                    key.to_string(),
                    format!(
                        "`{value}`: expected a host name or IP address alone (the port is a key of its own)"
                    ),
                ))
            } else {
                Ok(())
            }
        };
        let port = |key: &str, value: u16| {
            if value == 0 {
                Err((key.to_string(), "0: expected a port 1 to 65535".to_string()))
            } else {
                Ok(())
            }
        };
        positive("cell.timeout_s", self.cell.timeout_s, 3600.0)?;
        if let Some(Robot::AbbRws(s)) = &self.robot {
            address("robot.address", &s.address)?;
            if !(1..=2).contains(&s.rws_version) {
                return Err((
                    "robot.rws_version".into(),
                    format!(
                        "{}: expected 1 (IRC5, RobotWare 6) or 2 (OmniCore, RobotWare 7)",
                        s.rws_version
                    ),
                ));
            }
            if let Some(p) = s.port {
                port("robot.port", p)?;
            }
            positive("robot.move_timeout_s", s.move_timeout_s, 3600.0)?;
            within(
                "robot.in_position_tolerance_deg",
                s.in_position_tolerance_deg,
                10.0,
            )?;
            if !(1..=10_000).contains(&s.poll_ms) {
                return Err((
                    "robot.poll_ms".into(),
                    format!("{}: expected 1 to 10000", s.poll_ms),
                ));
            }
            if let Some(t) = s.timeout_s {
                positive("robot.timeout_s", t, 3600.0)?;
            }
        }
        if let Some(Tracker::LeicaEmscon(s)) = &self.tracker {
            address("tracker.address", &s.address)?;
            port("tracker.port", s.port)?;
            if s.reflector_id < 0 {
                return Err((
                    "tracker.reflector_id".into(),
                    format!(
                        "{}: expected a reflector id ≥ 0, as the tracker lists them",
                        s.reflector_id
                    ),
                ));
            }
            if !(1..=600_000).contains(&s.stationary_time_ms) {
                return Err((
                    "tracker.stationary_time_ms".into(),
                    format!("{}: expected 1 to 600000", s.stationary_time_ms),
                ));
            }
            for (key, value, lo, hi) in [
                ("tracker.temperature_c", s.temperature_c, -40.0, 80.0),
                ("tracker.pressure_mbar", s.pressure_mbar, 500.0, 1200.0),
                ("tracker.humidity_percent", s.humidity_percent, 0.0, 100.0),
                ("tracker.min_distance_mm", s.min_distance_mm, 0.0, 100_000.0),
            ] {
                if !(value.is_finite() && (lo..=hi).contains(&value)) {
                    return Err((key.to_string(), format!("{value}: expected {lo} to {hi}")));
                }
            }
            positive(
                "tracker.initialize_timeout_s",
                s.initialize_timeout_s,
                3600.0,
            )?;
            positive("tracker.measure_timeout_s", s.measure_timeout_s, 3600.0)?;
            if let Some(t) = s.timeout_s {
                positive("tracker.timeout_s", t, 3600.0)?;
            }
        }
        if let Some(ForceSensor::AtiNetft(s)) = &self.force_sensor {
            address("force_sensor.address", &s.address)?;
            port("force_sensor.http_port", s.http_port)?;
            port("force_sensor.rdt_port", s.rdt_port)?;
            if !(1..=100_000).contains(&s.samples) {
                return Err((
                    "force_sensor.samples".into(),
                    format!("{}: expected 1 to 100000", s.samples),
                ));
            }
            within("force_sensor.bias_tolerance_n", s.bias_tolerance_n, 1000.0)?;
            within("force_sensor.bias_tolerance_nm", s.bias_tolerance_nm, 100.0)?;
            if let Some(t) = s.timeout_s {
                positive("force_sensor.timeout_s", t, 3600.0)?;
            }
        }
        if let Some(CableRobot::EgcalUdp(s)) = &self.cable_robot {
            address("cable_robot.address", &s.address)?;
            port("cable_robot.port", s.port)?;
            within("cable_robot.force_tolerance_n", s.force_tolerance_n, 1000.0)?;
            within(
                "cable_robot.moment_tolerance_nm",
                s.moment_tolerance_nm,
                100.0,
            )?;
            positive("cable_robot.settle_timeout_s", s.settle_timeout_s, 3600.0)?;
            if !(1..=10_000).contains(&s.poll_ms) {
                return Err((
                    "cable_robot.poll_ms".into(),
                    format!("{}: expected 1 to 10000", s.poll_ms),
                ));
            }
            if let Some(t) = s.timeout_s {
                positive("cable_robot.timeout_s", t, 3600.0)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> Result<CellFile, CellFileError> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cell.toml");
        std::fs::write(&path, text).unwrap();
        CellFile::load(&path)
    }

    #[test]
    fn defaults_fill_what_is_left_out() {
        let cell = load(
            "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"ati_netft\"\naddress = \"10.0.0.2\"\n",
        )
        .unwrap();
        let Some(ForceSensor::AtiNetft(s)) = cell.force_sensor else {
            panic!("ati")
        };
        assert_eq!((s.http_port, s.rdt_port, s.samples), (80, 49152, 100));
        assert_eq!(s.torque_unit, TorqueUnit::NewtonMetre);
        assert!(cell.cable_robot.is_none());
    }

    #[test]
    fn problems_name_the_file_and_key() {
        let cases = [
            (
                "[cell]\nname = \"c\"\ntimeout = 1\n",
                "unknown field `timeout`",
            ),
            ("[cell]\nname = \"c\"\ntimeout_s = -1\n", "cell.timeout_s"),
            (
                "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"jr3\"\naddress = \"a\"\n",
                "force_sensor",
            ),
            (
                "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"ati_netft\"\naddress = \"a\"\nsamples = 0\n",
                "force_sensor.samples",
            ),
            (
                "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"ati_netft\"\naddress = \"a\"\ntorque_unit = \"Nm\"\n",
                "unknown variant `Nm`, expected one of `lbf-in`, `lbf-ft`, `N-m`",
            ),
            (
                "[cell]\nname = \"c\"\n[cable_robot]\nkind = \"egcal_udp\"\naddress = \" \"\n",
                "cable_robot.address",
            ),
            (
                "[cell]\nname = \"c\"\n[cable_robot]\nkind = \"egcal_udp\"\naddress = \"a\"\nport = 70000\n",
                "port",
            ),
        ];
        let cases = cases.into_iter().chain([
            (
                "[cell]\nname = \"c\"\n[cable_robot]\nkind = \"egcal_udp\"\naddress = \"10.0.0.2:30500\"\n",
                "cable_robot.address",
            ),
            (
                "[cell]\nname = \"c\"\n[force_sensor]\nkind = \"ati_netft\"\naddress = \"not an address\"\n",
                "force_sensor.address",
            ),
        ]);
        for (text, expected) in cases {
            let message = load(text).unwrap_err().to_string();
            assert!(
                message.contains("cell.toml") && message.contains(expected),
                "{text}: {message}"
            );
        }
    }

    #[test]
    fn ati_unit_codes_follow_the_manual() {
        assert_eq!(ForceUnit::from_code(2), Some(ForceUnit::Newton));
        assert_eq!(TorqueUnit::from_code(3), Some(TorqueUnit::NewtonMetre));
        assert_eq!(TorqueUnit::from_code(4), Some(TorqueUnit::NewtonMillimetre));
        assert_eq!(ForceUnit::from_code(0), None);
        assert_eq!(TorqueUnit::from_code(7), None);
    }
}
