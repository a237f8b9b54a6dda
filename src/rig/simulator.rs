//! The simulated rig: a "true" robot (a parameter set, usually the spec's truth)
//! measured with seeded noise, so a whole campaign can run without hardware.
//!
//! What it models, each a setting:
//! * laser tracker noise per axis, plus a distance-proportional term;
//! * joint encoder noise (the row records the encoder reading, as in the lab);
//! * the cable robot's force-tracking error: the applied wrench differs from the
//!   commanded one, and the force/torque sensor reads the applied one with noise
//!   (the row records the sensor reading);
//! * unmodelled errors, so validation is not trivially perfect: transmission
//!   errors periodic in each joint angle (once and twice per turn), gear
//!   backlash (a half dead band on the side the joint approached from, see
//!   [`super::approach`]), a quadratic (hardening) compliance, and a smooth
//!   position residual no joint-space term expresses;
//! * transient failures (the tracker losing the beam) with a given probability.
//!
//! Each row draws from its own stream seeded by (seed, cw_id), so a resumed or
//! retried campaign reproduces exactly the rows of an uninterrupted one.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use std::collections::HashMap;

use super::approach::step_direction;
use super::{Rig, RigError};
use crate::robot::params::{ParamId, ParamKind};
use crate::robot::positioner::MAX_POSITIONER_AXES;
use crate::robot::{ConfWrench, MAX_JOINTS, ParamValues, Robot, Wrench};

/// Noise and error settings of the simulator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SimulatorSettings {
    /// Tracker noise, standard deviation per axis (mm).
    #[schemars(range(min = 0.0, max = 100.0))]
    pub tracker_noise_mm: f64,
    /// Distance-proportional tracker noise (mm per m of distance to the tracker), per axis.
    #[schemars(range(min = 0.0, max = 100.0))]
    pub tracker_noise_mm_per_m: f64,
    /// Joint encoder noise, standard deviation (deg).
    #[schemars(range(min = 0.0, max = 10.0))]
    pub encoder_noise_deg: f64,
    /// Cable-robot force tracking error, relative (applied = commanded·(1+e) + offset).
    #[schemars(range(min = 0.0, max = 1.0))]
    pub wrench_tracking_relative: f64,
    /// Cable-robot force tracking offset, standard deviation (N).
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub force_tracking_n: f64,
    /// Cable-robot moment tracking offset, standard deviation (N·m).
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub moment_tracking_nm: f64,
    /// Force/torque sensor noise on forces (N).
    #[schemars(range(min = 0.0, max = 10_000.0))]
    pub sensor_noise_n: f64,
    /// Force/torque sensor noise on moments (N·m).
    #[schemars(range(min = 0.0, max = 1000.0))]
    pub sensor_noise_nm: f64,
    /// Amplitude of an unmodelled transmission error `A·sin(2q + φ_i)` per joint (deg).
    #[schemars(range(min = 0.0, max = 10.0))]
    pub transmission_error_deg: f64,
    /// Amplitude of a once-per-turn transmission error `A·sin(q + ψ_i)` per
    /// joint (deg): an eccentric output bearing or gear. Reducers' published
    /// angular transmission errors are 0.3–1 arcmin (0.005–0.017°).
    #[schemars(range(min = 0.0, max = 10.0))]
    pub transmission_error_1_deg: f64,
    /// Amplitude at the joint of a transmission error at the motor's rate,
    /// `A·sin(N·q + χ_i)` with `N` the joint's `gear_ratio` in the robot file
    /// (deg): the motor-side gear's eccentricity seen through the reducer,
    /// one period per motor turn (360°/N of the joint, 3° at N = 121). Only
    /// joints with a `gear_ratio` have it; a value above 0 on a robot file
    /// without any is refused. Reducers' motor-rate components are a fraction
    /// of their 0.3–1 arcmin total, so 0.001–0.005°.
    #[schemars(range(min = 0.0, max = 10.0))]
    pub transmission_error_motor_deg: f64,
    /// Gear backlash of every joint, half its dead band (deg): the joint sits
    /// this far past its command in the direction it approached from. Cycloidal
    /// and RV reducers are specified at ≤ 1 arcmin lost motion, so 0.005–0.01°.
    #[schemars(range(min = 0.0, max = 10.0))]
    pub backlash_deg: f64,
    /// RMS per axis of a smooth position residual of joint space (mm), a
    /// random draw from a Gaussian process (random Fourier features) fixed by
    /// the truth: what whatever else a robot does looks like to a model.
    #[schemars(range(min = 0.0, max = 100.0))]
    pub residual_mm: f64,
    /// Length scale of that residual in every joint (deg).
    #[schemars(range(max = 3600.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub residual_length_deg: f64,
    /// Unmodelled hardening of joints 2 and 3: extra deflection `c·τ·|τ|` (deg/(N·m)²).
    #[schemars(range(min = 0.0, max = 1.0))]
    pub quadratic_compliance: f64,
    /// Probability that a tracker reading fails (beam lost); the row is retried.
    #[schemars(range(min = 0.0))]
    #[schemars(extend("exclusiveMaximum" = 1.0))]
    pub beam_loss_probability: f64,
    /// Simulated clock: time of row cw_id = start + cw_id · seconds_per_row (RFC 3339, UTC).
    pub clock_start: String,
    /// Simulated seconds between consecutive cw_ids.
    #[schemars(range(max = 86_400.0))]
    #[schemars(extend("exclusiveMinimum" = 0.0))]
    pub seconds_per_row: f64,
}

impl SimulatorSettings {
    /// `clock_start` in microseconds since 1970, or why it is not a time.
    pub fn clock_start_us(&self) -> Result<i64, String> {
        crate::table::parse_rfc3339_us(&self.clock_start).ok_or_else(|| {
            format!(
                "`{}` is not an RFC 3339 time (2026-01-01T00:00:00Z)",
                self.clock_start
            )
        })
    }
}

impl Default for SimulatorSettings {
    fn default() -> Self {
        SimulatorSettings {
            tracker_noise_mm: 0.02,
            tracker_noise_mm_per_m: 0.0,
            encoder_noise_deg: 0.0005,
            wrench_tracking_relative: 0.02,
            force_tracking_n: 0.5,
            moment_tracking_nm: 0.05,
            sensor_noise_n: 0.1,
            sensor_noise_nm: 0.01,
            transmission_error_deg: 0.003,
            transmission_error_1_deg: 0.0,
            transmission_error_motor_deg: 0.0,
            backlash_deg: 0.0,
            residual_mm: 0.0,
            residual_length_deg: 60.0,
            quadratic_compliance: 0.0,
            beam_loss_probability: 0.0,
            clock_start: "2026-01-01T00:00:00Z".into(),
            seconds_per_row: 20.0,
        }
    }
}

/// A simulated rig around a true parameter set.
pub struct Simulator {
    robot: Robot,
    truth: ParamValues,
    settings: SimulatorSettings,
    seed: u64,
    clock_start_us: i64,
    phases_rad: [f64; MAX_JOINTS],
    once_phases_rad: [f64; MAX_JOINTS],
    motor_phases_rad: [f64; MAX_JOINTS],
    /// Each joint's reducer ratio from the robot file (None: no motor-rate error).
    gear_ratios: [Option<f64>; MAX_JOINTS],
    residual: SmoothResidual,
    rng: StdRng,
    cw_id: i64,
    commanded_q: Option<[f64; MAX_JOINTS]>,
    /// The track carriage's commanded position (mm); 0 without a track.
    commanded_track_mm: f64,
    /// The positioner's commanded axes (deg); 0 without one.
    commanded_positioner_deg: [f64; MAX_POSITIONER_AXES],
    /// The truth's target ids when it has several (sorted, as the
    /// parameters table holds them); empty for a one-target truth.
    targets: Vec<String>,
    /// The SMR the tracker measures ([`Rig::select_target`]): its slot in
    /// the truth, and whether it is a nest on the positioner's table.
    target_index: usize,
    on_nest: bool,
    /// Where each joint approached its command from ([`super::approach`]).
    approach: [i8; MAX_JOINTS],
    /// The campaign's own approach directions by cw_id, so a resumed campaign
    /// meets the backlash of an uninterrupted one; rows not in it take the
    /// direction of the move from the previous command.
    planned_approach: HashMap<i64, [i8; MAX_JOINTS]>,
    applied: [f64; 6],
}

/// Random Fourier features of joint space, per axis: `Σ_k a_k·cos(ω_k·q + b_k)`,
/// a draw from a Gaussian process with a squared-exponential kernel of variance
/// `residual_mm²` and length scale `residual_length_deg`.
struct SmoothResidual {
    frequencies_per_rad: Vec<[f64; MAX_JOINTS]>,
    offsets_rad: Vec<f64>,
    /// Per feature, the weight on x, y and z (mm).
    weights_mm: Vec<[f64; 3]>,
}

/// Features of the smooth residual: enough for a draw that looks like a GP's.
const RESIDUAL_FEATURES: usize = 64;

impl SmoothResidual {
    /// The residual of an arm with `joints` joints (it depends on those only).
    fn new(truth: &ParamValues, settings: &SimulatorSettings, joints: usize) -> Self {
        let mut rng = StdRng::seed_from_u64(truth_seed(truth, joints) ^ 0x7265_7369_6475_616c);
        let length_rad = settings.residual_length_deg.to_radians();
        let amplitude = settings.residual_mm * (2.0 / RESIDUAL_FEATURES as f64).sqrt();
        let normal = Normal::new(0.0, 1.0).expect("unit normal");
        let mut frequencies_per_rad = Vec::with_capacity(RESIDUAL_FEATURES);
        let mut offsets_rad = Vec::with_capacity(RESIDUAL_FEATURES);
        let mut weights_mm = Vec::with_capacity(RESIDUAL_FEATURES);
        for _ in 0..RESIDUAL_FEATURES {
            frequencies_per_rad.push(std::array::from_fn(|i| {
                if i < joints {
                    normal.sample(&mut rng) / length_rad
                } else {
                    0.0
                }
            }));
            offsets_rad.push(rng.random_range(0.0..std::f64::consts::TAU));
            weights_mm.push(std::array::from_fn(|_| amplitude * normal.sample(&mut rng)));
        }
        SmoothResidual {
            frequencies_per_rad,
            offsets_rad,
            weights_mm,
        }
    }

    fn at(&self, q_deg: &[f64; MAX_JOINTS]) -> [f64; 3] {
        let mut residual = [0.0; 3];
        for ((omega, offset), weight) in self
            .frequencies_per_rad
            .iter()
            .zip(&self.offsets_rad)
            .zip(&self.weights_mm)
        {
            let phase: f64 = omega
                .iter()
                .zip(q_deg)
                .map(|(w, q)| w * q.to_radians())
                .sum::<f64>()
                + offset;
            let c = phase.cos();
            for axis in 0..3 {
                residual[axis] += weight[axis] * c;
            }
        }
        residual
    }
}

impl Simulator {
    pub fn new(
        robot: Robot,
        truth: ParamValues,
        settings: SimulatorSettings,
        seed: u64,
    ) -> Result<Self, String> {
        let clock_start_us = settings.clock_start_us()?;
        let gear_ratios: [Option<f64>; MAX_JOINTS] =
            std::array::from_fn(|i| robot.spec().joints.get(i).and_then(|j| j.gear_ratio));
        if settings.transmission_error_motor_deg > 0.0 && gear_ratios.iter().all(Option::is_none) {
            return Err(format!(
                "simulator setting `transmission_error_motor_deg` = {} needs the motor's rate: \
                 give `gear_ratio` (motor turns per joint turn) to the joints of robot file {}",
                settings.transmission_error_motor_deg,
                robot.spec().path.display()
            ));
        }
        let joints = robot.joint_count();
        let [phases_rad, once_phases_rad, motor_phases_rad] =
            transmission_phases_rad(&truth, joints);
        let residual = SmoothResidual::new(&truth, &settings, joints);
        Ok(Simulator {
            robot,
            truth,
            settings,
            seed,
            clock_start_us,
            phases_rad,
            once_phases_rad,
            motor_phases_rad,
            gear_ratios,
            residual,
            rng: StdRng::seed_from_u64(seed),
            cw_id: 0,
            commanded_q: None,
            commanded_track_mm: 0.0,
            commanded_positioner_deg: [0.0; MAX_POSITIONER_AXES],
            targets: Vec::new(),
            target_index: 0,
            on_nest: false,
            approach: [0; MAX_JOINTS],
            planned_approach: HashMap::new(),
            applied: [0.0; 6],
        })
    }

    /// The unmodelled effects of the settings as the parameters of the
    /// `eg_harmonic` model would hold them: each joint's backlash, and the
    /// coefficients of sin(n·q) and cos(n·q) of its transmission errors
    /// (`A·sin(n·q + φ) = A·cos φ·sin(n·q) + A·sin φ·cos(n·q)`). What a test
    /// of a rung compares its estimates with.
    pub fn joint_terms_truth(&self) -> Vec<(ParamId, f64)> {
        let joints = self.robot.joint_count();
        let angular = |id: &ParamId| id.joint().is_none_or(|j| !self.robot.is_prismatic(j));
        let mut terms: Vec<(ParamId, f64)> = ParamId::backlashes(joints)
            .map(|id| {
                (
                    id,
                    if angular(&id) {
                        self.settings.backlash_deg
                    } else {
                        0.0
                    },
                )
            })
            .collect();
        for joint in (0..joints).filter(|&j| !self.robot.is_prismatic(j)) {
            for (order, amplitude, phase) in [
                (
                    1,
                    self.settings.transmission_error_1_deg,
                    self.once_phases_rad[joint],
                ),
                (
                    2,
                    self.settings.transmission_error_deg,
                    self.phases_rad[joint],
                ),
            ] {
                terms.push((
                    ParamId::harmonic(joint, order, false),
                    amplitude * phase.cos(),
                ));
                terms.push((
                    ParamId::harmonic(joint, order, true),
                    amplitude * phase.sin(),
                ));
            }
        }
        terms
    }

    /// The campaign's approach directions by cw_id (see `planned_approach`).
    pub fn with_planned_approach(mut self, planned: HashMap<i64, [i8; MAX_JOINTS]>) -> Self {
        self.planned_approach = planned;
        self
    }

    /// The truth's target ids (a parameters set's `targets`), so that
    /// [`Rig::select_target`] finds each SMR's slot, the nests' included.
    pub fn with_targets(mut self, targets: Vec<String>) -> Self {
        self.targets = targets;
        self
    }

    fn gauss(&mut self, sigma: f64) -> f64 {
        if sigma <= 0.0 {
            return 0.0;
        }
        Normal::new(0.0, sigma).map_or(0.0, |n| n.sample(&mut self.rng))
    }

    /// The joint-side errors of the settings at command `q` (deg): the
    /// transmission errors at twice, once and the motor's rate per turn, and
    /// the backlash on the side of the current approach. The settings are
    /// angles: a prismatic joint has none of them.
    fn joint_errors_deg(&self, q: &[f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        std::array::from_fn(|i| {
            if self.robot.is_prismatic(i) {
                return 0.0;
            }
            let angle = q[i].to_radians();
            let motor = self.gear_ratios[i].map_or(0.0, |ratio| {
                self.settings.transmission_error_motor_deg
                    * (ratio * angle + self.motor_phases_rad[i]).sin()
            });
            self.settings.transmission_error_deg * (2.0 * angle + self.phases_rad[i]).sin()
                + self.settings.transmission_error_1_deg * (angle + self.once_phases_rad[i]).sin()
                + motor
                + self.settings.backlash_deg * f64::from(self.approach[i])
        })
    }

    fn position_now(&self, q: &[f64; MAX_JOINTS]) -> [f64; 3] {
        let wrench = Wrench::from_array(self.applied);
        let (torques, _) = self.robot.deflections(&self.truth, q, &wrench);
        let errors = self.joint_errors_deg(q);
        let mut actual: [f64; MAX_JOINTS] = std::array::from_fn(|i| q[i] + errors[i]);
        for i in [1, 2] {
            if !self.robot.is_prismatic(i) {
                actual[i] += self.settings.quadratic_compliance * torques[i] * torques[i].abs();
            }
        }
        // Joint-error terms of the truth file itself (backlash3 = …) see the
        // same approach as the settings' backlash.
        let p = self
            .robot
            .prepare(&self.truth)
            .predict_row(&ConfWrench {
                approach: self.approach,
                track_mm: self.commanded_track_mm,
                target: self.target_index,
                positioner_deg: self.on_nest.then_some(self.commanded_positioner_deg),
                ..ConfWrench::new(actual, wrench)
            })
            .position_mm;
        // The arm's unmodelled errors do not move a nest on the table.
        let residual = if self.settings.residual_mm > 0.0 && !self.on_nest {
            self.residual.at(q)
        } else {
            [0.0; 3]
        };
        [p.x + residual[0], p.y + residual[1], p.z + residual[2]]
    }
}

/// The phases of the unmodelled transmission errors, twice-per-turn,
/// once-per-turn and at the motor's rate, in that order (drawn in that order,
/// so adding a kind kept the earlier ones). They belong to the simulated
/// robot, not to the stage that measures it: every measure stage over the
/// same truth (the calibration campaign, then the compensated commands) meets
/// the same gearboxes, so they are drawn from [`truth_seed`].
fn transmission_phases_rad(truth: &ParamValues, joints: usize) -> [[f64; MAX_JOINTS]; 3] {
    let mut phase_rng = StdRng::seed_from_u64(truth_seed(truth, joints));
    std::array::from_fn(|_| {
        std::array::from_fn(|i| {
            if i < joints {
                phase_rng.random_range(0.0..std::f64::consts::TAU)
            } else {
                0.0
            }
        })
    })
}

/// A seed from the truth's arm parameters (not its frames: moving the tracker
/// does not change the gearboxes).
fn truth_seed(truth: &ParamValues, joints: usize) -> u64 {
    let mut hasher = blake3::Hasher::new();
    for id in ParamId::of_arm(joints) {
        if !matches!(
            id.kind(),
            ParamKind::WorldTranslation(_)
                | ParamKind::WorldRotation(_)
                | ParamKind::ToolTranslation { .. }
                | ParamKind::ToolRotation(_)
        ) {
            hasher.update(&truth.0[id.index()].to_le_bytes());
        }
    }
    let bytes = hasher.finalize();
    let mut seed = [0u8; 8];
    seed.copy_from_slice(&bytes.as_bytes()[..8]);
    u64::from_le_bytes(seed)
}

impl Rig for Simulator {
    fn move_joints(&mut self, cw_id: i64, q_deg: [f64; MAX_JOINTS]) -> Result<(), RigError> {
        let mut hasher = blake3::Hasher::new();
        hasher.update(&self.seed.to_le_bytes());
        hasher.update(&cw_id.to_le_bytes());
        let bytes = hasher.finalize();
        self.rng = StdRng::seed_from_u64(u64::from_le_bytes(
            bytes.as_bytes()[..8].try_into().expect("8 bytes"),
        ));
        self.cw_id = cw_id;
        self.approach = match self.planned_approach.get(&cw_id) {
            Some(planned) => *planned,
            None => step_direction(self.commanded_q.as_ref(), &q_deg, self.approach),
        };
        self.commanded_q = Some(q_deg);
        self.applied = [0.0; 6];
        Ok(())
    }

    fn apply_wrench(&mut self, wrench: [f64; 6]) -> Result<(), RigError> {
        let relative = self.gauss(self.settings.wrench_tracking_relative);
        for (i, commanded) in wrench.iter().enumerate() {
            let offset = self.gauss(if i < 3 {
                self.settings.force_tracking_n
            } else {
                self.settings.moment_tracking_nm
            });
            self.applied[i] = commanded * (1.0 + relative) + offset;
        }
        Ok(())
    }

    fn read_wrench(&mut self) -> Result<[f64; 6], RigError> {
        let mut reading = self.applied;
        for (i, value) in reading.iter_mut().enumerate() {
            *value += self.gauss(if i < 3 {
                self.settings.sensor_noise_n
            } else {
                self.settings.sensor_noise_nm
            });
        }
        Ok(reading)
    }

    fn read_joints(&mut self) -> Result<[f64; MAX_JOINTS], RigError> {
        let q = self
            .commanded_q
            .ok_or_else(|| RigError::Fatal("read_joints before move_joints".into()))?;
        let mut reading = q;
        for value in reading.iter_mut().take(self.robot.joint_count()) {
            *value += self.gauss(self.settings.encoder_noise_deg);
        }
        Ok(reading)
    }

    fn measure(&mut self) -> Result<[f64; 3], RigError> {
        let q = self
            .commanded_q
            .ok_or_else(|| RigError::Fatal("measure before move_joints".into()))?;
        if self.settings.beam_loss_probability > 0.0
            && self.rng.random::<f64>() < self.settings.beam_loss_probability
        {
            return Err(RigError::Transient("tracker lost the beam".into()));
        }
        let position = self.position_now(&q);
        let distance_m = position.iter().map(|v| v * v).sum::<f64>().sqrt() / 1000.0;
        let sigma =
            self.settings.tracker_noise_mm + self.settings.tracker_noise_mm_per_m * distance_m;
        Ok(position.map(|v| v + self.gauss(sigma)))
    }

    fn release_wrench(&mut self) -> Result<(), RigError> {
        self.applied = [0.0; 6];
        Ok(())
    }

    /// The carriage reaches its command exactly as its encoder counts it:
    /// where it really stands (scale, straightness, angles) is the truth's
    /// track errors.
    fn move_track(&mut self, _cw_id: i64, e_mm: f64) -> Result<(), RigError> {
        let Some(track) = self.robot.spec().track else {
            return Err(RigError::Fatal(format!(
                "move_track: the simulated robot ({}) has no [track]",
                self.robot.spec().path.display()
            )));
        };
        let [lo, hi] = track.travel_mm;
        if !(e_mm >= lo && e_mm <= hi) {
            return Err(RigError::Row(format!(
                "move_track: {e_mm} mm is outside the track's travel [{lo}, {hi}] mm"
            )));
        }
        self.commanded_track_mm = e_mm;
        Ok(())
    }

    fn read_track(&mut self) -> Result<f64, RigError> {
        match self.robot.spec().track {
            Some(_) => Ok(self.commanded_track_mm),
            None => Err(RigError::Fatal(
                "read_track: the simulated robot has no [track]".into(),
            )),
        }
    }

    fn select_target(&mut self, target_id: &str) -> Result<(), RigError> {
        let on_nest = self
            .robot
            .spec()
            .positioner
            .as_ref()
            .is_some_and(|p| p.nests.iter().any(|n| n == target_id));
        let index = if self.targets.is_empty() && !on_nest {
            Some(0)
        } else {
            self.targets.iter().position(|t| t == target_id)
        };
        let Some(index) = index else {
            return Err(RigError::Fatal(format!(
                "select_target: the simulator's truth has no target `{target_id}` (its targets: {}); give the truth parameters a position for it",
                if self.targets.is_empty() {
                    "one, unnamed".to_string()
                } else {
                    self.targets.join(", ")
                }
            )));
        };
        self.target_index = index;
        self.on_nest = on_nest;
        Ok(())
    }

    /// The positioner reaches its command exactly as its encoders count
    /// it: where the table really stands is the truth's positioner terms.
    fn move_positioner(
        &mut self,
        _cw_id: i64,
        p_deg: [f64; MAX_POSITIONER_AXES],
    ) -> Result<(), RigError> {
        let Some(positioner) = &self.robot.spec().positioner else {
            return Err(RigError::Fatal(format!(
                "move_positioner: the simulated robot ({}) has no [positioner]",
                self.robot.spec().path.display()
            )));
        };
        for (k, (axis, value)) in positioner.axes.iter().zip(p_deg).enumerate() {
            let [lo, hi] = axis.limits_deg;
            if !(value >= lo && value <= hi) {
                return Err(RigError::Row(format!(
                    "move_positioner: axis {} to {value} deg is outside its limits [{lo}, {hi}] deg",
                    k + 1
                )));
            }
        }
        self.commanded_positioner_deg = p_deg;
        Ok(())
    }

    fn positioner_axes(&self) -> usize {
        self.robot
            .spec()
            .positioner
            .as_ref()
            .map_or(0, |p| p.axes.len())
    }

    fn read_positioner(&mut self) -> Result<[f64; MAX_POSITIONER_AXES], RigError> {
        match self.robot.spec().positioner {
            Some(_) => Ok(self.commanded_positioner_deg),
            None => Err(RigError::Fatal(
                "read_positioner: the simulated robot has no [positioner]".into(),
            )),
        }
    }

    fn measured_at_us(&self) -> i64 {
        self.clock_start_us + (self.cw_id as f64 * self.settings.seconds_per_row * 1e6) as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::joint_array;
    use crate::robot::test_support::{irb1600, truth_params};

    fn quiet() -> SimulatorSettings {
        SimulatorSettings {
            tracker_noise_mm: 0.0,
            encoder_noise_deg: 0.0,
            wrench_tracking_relative: 0.0,
            force_tracking_n: 0.0,
            moment_tracking_nm: 0.0,
            sensor_noise_n: 0.0,
            sensor_noise_nm: 0.0,
            transmission_error_deg: 0.0,
            ..SimulatorSettings::default()
        }
    }

    #[test]
    fn noiseless_simulator_measures_the_truth_model() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let mut sim = Simulator::new(robot.clone(), truth, quiet(), 1).unwrap();
        let q = [10.0, 20.0, -20.0, 30.0, 40.0, 50.0];
        let w = [50.0, -30.0, 80.0, 2.0, -3.0, 4.0];
        sim.move_joints(7, joint_array(&q)).unwrap();
        sim.apply_wrench(w).unwrap();
        assert_eq!(sim.read_wrench().unwrap(), w);
        assert_eq!(sim.read_joints().unwrap(), joint_array(&q));
        let expected = robot
            .predict(&truth, &joint_array(&q), &Wrench::from_array(w))
            .position_mm;
        let measured = sim.measure().unwrap();
        for k in 0..3 {
            assert!((measured[k] - expected[k]).abs() < 1e-12);
        }
        assert_eq!(sim.measured_at_us(), 1_767_225_600_000_000 + 140_000_000);
    }

    #[test]
    fn rows_are_reproducible_whatever_came_before() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let row = |sim: &mut Simulator| {
            sim.move_joints(3, [0.0, 10.0, 10.0, 0.0, 30.0, 0.0, 0.0])
                .unwrap();
            sim.apply_wrench([10.0, 0.0, 0.0, 0.0, 0.0, 1.0]).unwrap();
            (
                sim.read_wrench().unwrap(),
                sim.read_joints().unwrap(),
                sim.measure().unwrap(),
            )
        };
        let mut a = Simulator::new(robot.clone(), truth, SimulatorSettings::default(), 9).unwrap();
        let mut b = Simulator::new(robot, truth, SimulatorSettings::default(), 9).unwrap();
        b.move_joints(99, [0.0; 7]).unwrap();
        b.measure().unwrap();
        assert_eq!(row(&mut a), row(&mut b));
    }

    /// The position the truth model gives at joint angles `q` without load.
    fn truth_at(robot: &Robot, truth: &ParamValues, q: &[f64; MAX_JOINTS]) -> [f64; 3] {
        let p = robot.predict(truth, q, &Wrench::zero()).position_mm;
        [p.x, p.y, p.z]
    }

    fn close(a: [f64; 3], b: [f64; 3], tolerance_mm: f64) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < tolerance_mm)
    }

    /// Backlash: the joints sit a half dead band past their command, on the
    /// side they came from; a planned direction overrides the move's own.
    #[test]
    fn backlash_puts_each_joint_past_its_command_on_the_side_it_came_from() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let settings = SimulatorSettings {
            backlash_deg: 0.01,
            ..quiet()
        };
        let q = [10.0, 20.0, -20.0, 30.0, 40.0, 50.0];
        let below = q.map(|v| v - 1.0);
        let above = q.map(|v| v + 1.0);
        let mut sim = Simulator::new(robot.clone(), truth, settings.clone(), 1).unwrap();
        sim.move_joints(1, joint_array(&below)).unwrap();
        sim.move_joints(2, joint_array(&q)).unwrap();
        let from_below = sim.measure().unwrap();
        assert!(close(
            from_below,
            truth_at(&robot, &truth, &joint_array(&q.map(|v| v + 0.01))),
            1e-9
        ));
        sim.move_joints(3, joint_array(&above)).unwrap();
        sim.move_joints(4, joint_array(&q)).unwrap();
        let from_above = sim.measure().unwrap();
        assert!(close(
            from_above,
            truth_at(&robot, &truth, &joint_array(&q.map(|v| v - 0.01))),
            1e-9
        ));
        // A 0.01° half band moves this tool by a few hundredths of a mm.
        let moved: f64 = (0..3)
            .map(|k| (from_below[k] - from_above[k]).powi(2))
            .sum();
        assert!(moved.sqrt() > 0.05, "{}", moved.sqrt());
        // A fresh simulator with the campaign's plan meets the same backlash.
        let mut resumed = Simulator::new(robot.clone(), truth, settings, 1)
            .unwrap()
            .with_planned_approach(HashMap::from([(4, [-1; MAX_JOINTS])]));
        resumed.move_joints(4, joint_array(&q)).unwrap();
        assert!(close(resumed.measure().unwrap(), from_above, 1e-12));
    }

    /// The motor-rate error repeats every motor turn (360°/N of the joint),
    /// has its amplitude, is only on joints with a gear ratio, and the
    /// reading is the truth at the command plus it; without any gear ratio
    /// in the robot file the setting is refused.
    #[test]
    fn the_motor_rate_error_has_the_gear_ratio_s_period_and_its_amplitude() {
        let settings = SimulatorSettings {
            transmission_error_motor_deg: 0.002,
            ..quiet()
        };
        let robot = irb1600();
        let truth = truth_params(&robot);
        let refused = Simulator::new(robot.clone(), truth, settings.clone(), 1)
            .err()
            .unwrap_or_default();
        assert!(refused.contains("gear_ratio"), "{refused}");
        let mut spec = robot.spec().clone();
        spec.joints[1].gear_ratio = Some(121.0);
        let robot = Robot::new(spec);
        let mut sim = Simulator::new(robot.clone(), truth, settings, 1).unwrap();
        let q = [10.0, 20.0, -20.0, 30.0, 40.0, 50.0, 0.0];
        let period_deg = 360.0 / 121.0;
        let errors = sim.joint_errors_deg(&joint_array(&q));
        let mut turned = q;
        turned[1] += 7.0 * period_deg;
        assert!((sim.joint_errors_deg(&joint_array(&turned))[1] - errors[1]).abs() < 1e-12);
        assert!(errors.iter().enumerate().all(|(i, e)| i == 1 || *e == 0.0));
        let peak = (0..1000)
            .map(|k| {
                let mut at = q;
                at[1] += period_deg * k as f64 / 1000.0;
                sim.joint_errors_deg(&joint_array(&at))[1].abs()
            })
            .fold(0.0, f64::max);
        assert!((peak - 0.002).abs() < 1e-7, "{peak}");
        sim.move_joints(1, joint_array(&q)).unwrap();
        let expected = truth_at(&robot, &truth, &std::array::from_fn(|i| q[i] + errors[i]));
        assert!(close(sim.measure().unwrap(), expected, 1e-9));
    }

    /// The smooth residual has the RMS asked for, is smooth (a 0.1° move
    /// changes it by far less than its size) and is the same robot's in every
    /// simulator of the same truth.
    #[test]
    fn the_smooth_residual_has_its_rms_and_is_smooth() {
        let robot = irb1600();
        let truth = truth_params(&robot);
        let settings = SimulatorSettings {
            residual_mm: 0.05,
            ..quiet()
        };
        let mut sim = Simulator::new(robot.clone(), truth, settings.clone(), 1).unwrap();
        let mut again = Simulator::new(robot.clone(), truth, settings, 2).unwrap();
        let mut rng = StdRng::seed_from_u64(5);
        let (mut squares, mut steps, rows) = (0.0, 0.0f64, 2000);
        for k in 0..rows {
            let q: [f64; MAX_JOINTS] = std::array::from_fn(|_| rng.random_range(-150.0..150.0));
            sim.move_joints(k, q).unwrap();
            let measured = sim.measure().unwrap();
            let model = truth_at(&robot, &truth, &q);
            squares += (0..3)
                .map(|a| (measured[a] - model[a]).powi(2))
                .sum::<f64>();
            again.move_joints(k, q).unwrap();
            assert_eq!(again.measure().unwrap(), measured);
            let nudged = q.map(|v| v + 0.1);
            sim.move_joints(k, nudged).unwrap();
            let step = sim.measure().unwrap();
            let model_step = truth_at(&robot, &truth, &nudged);
            steps = steps.max(
                (0..3)
                    .map(|a| ((step[a] - model_step[a]) - (measured[a] - model[a])).powi(2))
                    .sum::<f64>()
                    .sqrt(),
            );
        }
        let rms_per_axis = (squares / (3.0 * rows as f64)).sqrt();
        assert!(
            (rms_per_axis - 0.05).abs() < 0.015,
            "RMS per axis {rms_per_axis}"
        );
        assert!(steps < 0.005, "largest change over 0.1° {steps}");
    }
}
