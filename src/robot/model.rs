//! The elasto-geometric forward model (`../shared/spec/model.md` §1 and §3; paper
//! eqs. (1)–(17)): SMR position in the world frame for a parameter set, a joint
//! vector and an external wrench, with the load torques and the compliance
//! deflections they cause.
//!
//! Units cross here: robot-file and parameter values come in mm and degrees,
//! torques are computed with positions in metres (N·m), and compliances are
//! deg/(N·m), so a deflection is in degrees like every other joint angle.
//!
//! Torques are evaluated on the undeflected chain with the current geometric
//! parameters (first order, as in the paper); the position is evaluated on the
//! deflected chain.

use nalgebra::{Matrix3, Vector3};

use super::file::RobotSpec;
use super::frame::{Frame, rot_x};
use super::jacobian::ConfWrench;
use super::params::{MAX_HARMONIC_ORDER, MAX_TARGETS, PARAM_COUNT, ParamId, ParamValues};
use super::positioner::{
    MAX_POSITIONER_AXES, POSITIONER_TERM_COUNT, PositionerChain, PositionerModel, PositionerTerm,
};
use super::track::{Carriage, TrackErrors, TrackTerm};

/// Number of joints; the model is for six-axis arms only.
pub const JOINTS: usize = 6;

/// A wrench applied **to** the robot, in tool-frame axes, reduced to the tool origin.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Wrench {
    pub force_n: Vector3<f64>,
    pub moment_nm: Vector3<f64>,
}

impl Wrench {
    pub fn zero() -> Self {
        Self::default()
    }

    /// From the table columns `fx_n, fy_n, fz_n, mx_nm, my_nm, mz_nm`.
    pub fn from_array(w: [f64; 6]) -> Self {
        Wrench {
            force_n: Vector3::new(w[0], w[1], w[2]),
            moment_nm: Vector3::new(w[3], w[4], w[5]),
        }
    }

    /// In the order of the table columns and of the driver protocol's `wrench`.
    pub fn to_array(&self) -> [f64; 6] {
        let (f, m) = (&self.force_n, &self.moment_nm);
        [f.x, f.y, f.z, m.x, m.y, m.z]
    }
}

/// What the forward model predicts for one conf-wrench combination.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    /// SMR (tool origin) in the world (tracker) frame, mm.
    pub position_mm: Vector3<f64>,
    /// Load torque on each joint (gravity + external wrench), N·m.
    pub torques_nm: [f64; JOINTS],
    /// Compliance deflection `k_i·τ_i` of each joint, deg.
    pub deflections_deg: [f64; JOINTS],
}

/// A robot model built from a robot file: nominal MDH values in radians and
/// millimetres, and the link inertia in SI units.
#[derive(Debug, Clone)]
pub struct Robot {
    spec: RobotSpec,
    alpha_rad: [f64; JOINTS],
    a_mm: [f64; JOINTS],
    theta_offset_rad: [f64; JOINTS],
    d_mm: [f64; JOINTS],
    /// Link masses 1..6, then the payload.
    masses_kg: [f64; JOINTS + 1],
    /// Centres of gravity of links 1..6 in their own frames, then the payload in the tool frame, mm.
    cogs_mm: [Vector3<f64>; JOINTS + 1],
    gravity_mps2: Vector3<f64>,
}

/// Frames of one evaluation of the chain, all in the base frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Chain {
    /// `joints[0]` is the base itself, `joints[i]` is MDH frame i.
    pub joints: [Frame; JOINTS + 1],
    pub tool: Frame,
}

/// Load state on the undeflected chain: what the Jacobian needs besides the torques.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Loads {
    pub torques_nm: [f64; JOINTS],
    /// Suffix sums over bodies s..7 (links s..6 and the payload), 1-based `s`:
    /// total mass and first mass moment (kg·m) in the base frame. Index 7 is the payload alone.
    pub suffix_mass_kg: [f64; JOINTS + 2],
    pub suffix_moment_kgm: [Vector3<f64>; JOINTS + 2],
    /// External force and moment in base axes, N and N·m.
    pub force_base_n: Vector3<f64>,
    pub moment_base_nm: Vector3<f64>,
}

const DEG: f64 = std::f64::consts::PI / 180.0;
const MM: f64 = 1e-3;

impl Robot {
    pub fn new(spec: RobotSpec) -> Self {
        let j = &spec.joints;
        let mut cogs_mm = [Vector3::zeros(); JOINTS + 1];
        let mut masses_kg = [0.0; JOINTS + 1];
        for i in 0..JOINTS {
            cogs_mm[i] = Vector3::from(j[i].link_cog_mm);
            masses_kg[i] = j[i].link_mass_kg;
        }
        cogs_mm[JOINTS] = Vector3::from(spec.payload.cog_mm);
        masses_kg[JOINTS] = spec.payload.mass_kg;
        Robot {
            alpha_rad: std::array::from_fn(|i| j[i].alpha_deg * DEG),
            a_mm: std::array::from_fn(|i| j[i].a_mm),
            theta_offset_rad: std::array::from_fn(|i| j[i].theta_offset_deg * DEG),
            d_mm: std::array::from_fn(|i| j[i].d_mm),
            masses_kg,
            cogs_mm,
            gravity_mps2: Vector3::from(spec.gravity_mps2),
            spec,
        }
    }

    pub fn spec(&self) -> &RobotSpec {
        &self.spec
    }

    /// Joint limits `[min, max]` in degrees.
    pub fn limits_deg(&self, joint: usize) -> [f64; 2] {
        self.spec.joints[joint].limits_deg
    }

    pub fn within_limits(&self, q_deg: &[f64; JOINTS]) -> bool {
        (0..JOINTS).all(|i| {
            let [lo, hi] = self.limits_deg(i);
            q_deg[i] >= lo && q_deg[i] <= hi
        })
    }

    /// Nominal MDH values (alpha rad, a mm, theta offset rad, d mm) of joint `i`, for
    /// the closed-form inverse kinematics.
    pub(crate) fn nominal_mdh(&self, i: usize) -> (f64, f64, f64, f64) {
        (
            self.alpha_rad[i],
            self.a_mm[i],
            self.theta_offset_rad[i],
            self.d_mm[i],
        )
    }

    /// World ← base frame of a parameter set (eq. (3)).
    pub fn world_from_base(&self, p: &ParamValues) -> Frame {
        let v = &p.0;
        Frame::from_xyz_euler_then_translation(
            [v[3] * DEG, v[4] * DEG, v[5] * DEG],
            Vector3::new(v[0], v[1], v[2]),
        )
    }

    /// Flange → tool frame of `target` (0-based; spec §7) in a parameter set
    /// (eq. (4)): the set's tool rotation and that target's translation.
    pub fn flange_from_tool(&self, p: &ParamValues, target: usize) -> Frame {
        let v = &p.0;
        let t = |axis| v[ParamId::target_translation(target, axis).index()];
        Frame::from_xyz_euler_then_translation(
            [v[9] * DEG, v[10] * DEG, v[11] * DEG],
            Vector3::new(t(0), t(1), t(2)),
        )
    }

    /// This robot at one parameter set, with the set's constant geometry computed
    /// once: the form every evaluation over many rows uses.
    pub fn prepare(&self, p: &ParamValues) -> PreparedRobot<'_> {
        let v = &p.0;
        let tool_rx = rot_x(v[9] * DEG);
        PreparedRobot {
            robot: self,
            values: *p,
            alpha_sin_cos: std::array::from_fn(|i| (self.alpha_rad[i] + v[18 + i] * DEG).sin_cos()),
            a_mm: std::array::from_fn(|i| self.a_mm[i] + v[24 + i]),
            d_mm: std::array::from_fn(|i| self.d_mm[i] + v[30 + i]),
            theta_zero_rad: std::array::from_fn(|i| v[12 + i] * DEG + self.theta_offset_rad[i]),
            flange_from_tool: std::array::from_fn(|target| self.flange_from_tool(p, target)),
            tool_rxy: tool_rx * super::frame::rot_y(v[10] * DEG),
            tool_rx,
            world_from_base: self.world_from_base(p),
            world_rotation_axes: world_rotation_axes(p),
            joint_terms: JointTerms::of(p),
            track: self.spec.track.map(|track| TrackErrors {
                length_mm: track.length_mm(),
                coefficients: std::array::from_fn(|slot| {
                    v[ParamId::track(TrackTerm::of_slot(slot)).index()]
                }),
            }),
            positioner: self.spec.positioner.as_ref().map(|spec| {
                let values: [f64; POSITIONER_TERM_COUNT] = std::array::from_fn(|slot| {
                    v[ParamId::positioner(PositionerTerm::of_slot(slot)).index()]
                });
                PositionerModel::new(spec, &values)
            }),
        }
    }

    /// Gravity and external-wrench torques on the chain (spec §3; paper eqs. (7)–(16)).
    pub(crate) fn loads(&self, chain: &Chain, wrench: &Wrench) -> Loads {
        let mut suffix_mass_kg = [0.0; JOINTS + 2];
        let mut suffix_moment_kgm = [Vector3::zeros(); JOINTS + 2];
        // Body b (1..=6 links, 7 payload) has its frame at joints[b] or the tool.
        for body in (1..=JOINTS + 1).rev() {
            let frame = if body <= JOINTS {
                &chain.joints[body]
            } else {
                &chain.tool
            };
            let cog_m = frame.transform_point(&self.cogs_mm[body - 1]) * MM;
            let mass = self.masses_kg[body - 1];
            suffix_mass_kg[body] = suffix_mass_kg.get(body + 1).copied().unwrap_or(0.0) + mass;
            suffix_moment_kgm[body] = suffix_moment_kgm
                .get(body + 1)
                .copied()
                .unwrap_or_else(Vector3::zeros)
                + cog_m * mass;
        }
        let force_base_n = chain.tool.rotation * wrench.force_n;
        let moment_base_nm = chain.tool.rotation * wrench.moment_nm;
        let tool_m = chain.tool.origin_mm * MM;
        let g = self.gravity_mps2;
        let torques_nm = std::array::from_fn(|j| {
            let frame = &chain.joints[j + 1];
            let z = frame.axis(2);
            let o = frame.origin_mm * MM;
            let gravity_lever = suffix_moment_kgm[j + 1] - o * suffix_mass_kg[j + 1];
            z.dot(&(gravity_lever.cross(&g) + (tool_m - o).cross(&force_base_n) + moment_base_nm))
        });
        Loads {
            torques_nm,
            suffix_mass_kg,
            suffix_moment_kgm,
            force_base_n,
            moment_base_nm,
        }
    }

    /// Load torques (N·m) and deflections (deg) for one conf-wrench row.
    pub fn deflections(
        &self,
        p: &ParamValues,
        q_deg: &[f64; JOINTS],
        wrench: &Wrench,
    ) -> ([f64; JOINTS], [f64; JOINTS]) {
        self.prepare(p).deflections(q_deg, wrench)
    }

    /// Tool pose in the world frame on the loaded (deflected) robot, each
    /// joint approached from `approach` (−1, 0, +1; spec §8: only a model with
    /// backlash tells them apart).
    pub fn tool_in_world(
        &self,
        p: &ParamValues,
        q_deg: &[f64; JOINTS],
        wrench: &Wrench,
        approach: &[i8; JOINTS],
    ) -> Frame {
        let prepared = self.prepare(p);
        prepared
            .world_from_base
            .compose(&prepared.loaded_chain(q_deg, wrench, approach))
    }

    /// [`Self::tool_in_world`] for a row: its target's tool (spec §7), its
    /// approach directions and, on a track, its carriage position.
    /// A positioner row's frame is the table's, moved to its nest.
    pub fn tool_in_world_of_row(&self, p: &ParamValues, row: &ConfWrench) -> Frame {
        let aimed = p.aimed_at(row.target);
        let prepared = self.prepare(&aimed);
        if let Some((chain, nest_mm)) = prepared.positioner_nest(row) {
            return prepared.world_from_base.compose(&Frame {
                rotation: chain.table().rotation,
                origin_mm: nest_mm,
            });
        }
        prepared
            .world_from_base_at(row.track_mm)
            .compose(&prepared.loaded_chain(&row.q_deg, &row.wrench, &row.approach))
    }

    /// Paper eq. (17): the SMR position with torques and deflections.
    pub fn predict(&self, p: &ParamValues, q_deg: &[f64; JOINTS], wrench: &Wrench) -> Prediction {
        self.prepare(p).predict(q_deg, wrench)
    }

    /// Frames of joints 0..=6 and of the tool in the base frame, unloaded: the
    /// geometry collision and visibility checks work on.
    pub fn frames_in_base(
        &self,
        p: &ParamValues,
        q_deg: &[f64; JOINTS],
    ) -> ([Frame; JOINTS + 1], Frame) {
        let chain = self.prepare(p).chain(q_deg, &[0.0; JOINTS]);
        (chain.joints, chain.tool)
    }

    /// Flange pose in the base frame of the nominal arm (zero errors, no load):
    /// the frame the closed-form inverse kinematics solves for.
    pub fn nominal_flange_in_base(&self, q_deg: &[f64; JOINTS]) -> Frame {
        let zero = ParamValues([0.0; PARAM_COUNT]);
        self.prepare(&zero).chain(q_deg, &[0.0; JOINTS]).joints[JOINTS]
    }
}

/// Axes of the world frame's x, y, z rotations of eq. (3): x, then y after Rot(x),
/// then z after Rot(x)·Rot(y).
fn world_rotation_axes(p: &ParamValues) -> [Vector3<f64>; 3] {
    let rx = rot_x(p.0[3] * DEG);
    let rxy = rx * super::frame::rot_y(p.0[4] * DEG);
    [
        Vector3::x(),
        rx.column(1).into_owned(),
        rxy.column(2).into_owned(),
    ]
}

/// The joint-error terms of a parameter set beyond the paper (issue #29): an
/// angle added to each joint's reading, like a compliance deflection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct JointTerms {
    /// Half dead band per joint, deg, signed by the approach direction.
    backlash_deg: [f64; JOINTS],
    /// Per joint and order 1..: coefficients (deg) of sin(n·q) and cos(n·q).
    harmonics_deg: [[(f64, f64); MAX_HARMONIC_ORDER]; JOINTS],
    /// Whether any harmonic coefficient is non-zero: the elasto-geometric
    /// model skips their trigonometry.
    any_harmonic: bool,
}

impl JointTerms {
    fn of(p: &ParamValues) -> Self {
        let harmonics_deg: [[(f64, f64); MAX_HARMONIC_ORDER]; JOINTS] =
            std::array::from_fn(|joint| {
                std::array::from_fn(|o| {
                    (
                        p.get(ParamId::harmonic(joint, o + 1, false)),
                        p.get(ParamId::harmonic(joint, o + 1, true)),
                    )
                })
            });
        let mut backlash = ParamId::backlashes();
        JointTerms {
            backlash_deg: std::array::from_fn(|_| backlash.next().map_or(0.0, |id| p.get(id))),
            any_harmonic: harmonics_deg
                .iter()
                .flatten()
                .any(|(s, c)| *s != 0.0 || *c != 0.0),
            harmonics_deg,
        }
    }

    /// The angle (deg) each joint sits past its reading `q_deg` when it
    /// approached from `approach`.
    pub(crate) fn angles_deg(
        &self,
        q_deg: &[f64; JOINTS],
        approach: &[i8; JOINTS],
    ) -> [f64; JOINTS] {
        std::array::from_fn(|joint| {
            let mut angle = self.backlash_deg[joint] * f64::from(approach[joint]);
            if self.any_harmonic {
                for (n, (sine, cosine)) in harmonic_basis(q_deg[joint]).iter().enumerate() {
                    let (a, b) = self.harmonics_deg[joint][n];
                    angle += a * sine + b * cosine;
                }
            }
            angle
        })
    }
}

/// `(sin(n·q), cos(n·q))` for n = 1..=[`MAX_HARMONIC_ORDER`], by the angle-sum
/// recurrence from one `sin_cos`.
pub(crate) fn harmonic_basis(q_deg: f64) -> [(f64, f64); MAX_HARMONIC_ORDER] {
    let (s1, c1) = (q_deg * DEG).sin_cos();
    let mut basis = [(s1, c1); MAX_HARMONIC_ORDER];
    for n in 1..MAX_HARMONIC_ORDER {
        let (s, c) = basis[n - 1];
        basis[n] = (s * c1 + c * s1, c * c1 - s * s1);
    }
    basis
}

/// A robot at one parameter set: the MDH link rotations about x and offsets, the
/// tool and the world frames are fixed by the set, so they are computed once and a
/// row only evaluates its six joint rotations (a third of the trigonometry).
#[derive(Debug, Clone, Copy)]
pub struct PreparedRobot<'r> {
    robot: &'r Robot,
    pub(crate) values: ParamValues,
    /// (sin, cos) of each link twist alpha_i.
    alpha_sin_cos: [(f64, f64); JOINTS],
    a_mm: [f64; JOINTS],
    d_mm: [f64; JOINTS],
    /// Joint angle at q_i = 0: offset error plus the nominal theta offset.
    theta_zero_rad: [f64; JOINTS],
    /// Flange → tool of each target (one rotation, a translation per target).
    flange_from_tool: [Frame; MAX_TARGETS],
    /// Tool rotation about x, then about y, of eq. (4) (before the z rotation), in
    /// the flange frame: the axes of the tool's beta and gamma parameters.
    pub(crate) tool_rx: Matrix3<f64>,
    pub(crate) tool_rxy: Matrix3<f64>,
    pub(crate) world_from_base: Frame,
    /// Axes (world frame, through the world origin) of the world rotations of eq. (3).
    pub(crate) world_rotation_axes: [Vector3<f64>; 3],
    pub(crate) joint_terms: JointTerms,
    /// The track's errors, when the robot file has a track.
    pub(crate) track: Option<TrackErrors>,
    /// The positioner, when the robot file has one.
    pub(crate) positioner: Option<PositionerModel>,
}

impl<'r> PreparedRobot<'r> {
    pub fn robot(&self) -> &'r Robot {
        self.robot
    }

    /// The carriage at `track_mm` (`None` without a track).
    pub(crate) fn carriage(&self, track_mm: f64) -> Option<Carriage> {
        self.track.as_ref().map(|t| t.carriage(track_mm))
    }

    /// World ← base with the carriage at `track_mm` (the world frame alone
    /// without a track).
    pub fn world_from_base_at(&self, track_mm: f64) -> Frame {
        match self.carriage(track_mm) {
            Some(carriage) => self.world_from_base.compose(&carriage.frame),
            None => self.world_from_base,
        }
    }

    /// For a positioner row (its SMR a nest on the table): the positioner's
    /// frames at the row's axis values and the nest's position, robot base
    /// (the nest's translation is in the table's frame). `None` for a row
    /// on the arm, or without a positioner.
    pub(crate) fn positioner_nest(
        &self,
        row: &ConfWrench,
    ) -> Option<(PositionerChain, Vector3<f64>)> {
        let q_deg: [f64; MAX_POSITIONER_AXES] = row.positioner_deg?;
        let chain = self.positioner.as_ref()?.chain(&q_deg);
        let t = |axis| {
            self.values
                .get(ParamId::target_translation(row.target, axis))
        };
        let nest_mm = chain
            .table()
            .transform_point(&Vector3::new(t(0), t(1), t(2)));
        Some((chain, nest_mm))
    }

    /// Compliance of joint `i`, deg/(N·m).
    pub(crate) fn compliance(&self, joint: usize) -> f64 {
        self.values.0[36 + joint]
    }

    /// Forward chain in the base frame for joint commands `q_deg` plus extra joint
    /// angles `extra_deg` (the compliance deflections, or zero), to target 0.
    pub(crate) fn chain(&self, q_deg: &[f64; JOINTS], extra_deg: &[f64; JOINTS]) -> Chain {
        self.chain_at(
            &std::array::from_fn(|i| {
                ((q_deg[i] + extra_deg[i]) * DEG + self.theta_zero_rad[i]).sin_cos()
            }),
            0,
        )
    }

    /// Tool frame (base frame, target 0) of the loaded robot: the compliance
    /// deflections and the joint-error terms added to the readings.
    pub(crate) fn loaded_chain(
        &self,
        q_deg: &[f64; JOINTS],
        wrench: &Wrench,
        approach: &[i8; JOINTS],
    ) -> Frame {
        let (_, deflections) = self.deflections(q_deg, wrench);
        let terms = self.joint_terms.angles_deg(q_deg, approach);
        self.chain(q_deg, &std::array::from_fn(|i| deflections[i] + terms[i]))
            .tool
    }

    /// Forward chain for the (sin, cos) of each joint angle, to `target`'s tool frame.
    fn chain_at(&self, joint_sin_cos: &[(f64, f64); JOINTS], target: usize) -> Chain {
        let mut joints = [Frame::identity(); JOINTS + 1];
        for i in 0..JOINTS {
            let (sa, ca) = self.alpha_sin_cos[i];
            let (st, ct) = joint_sin_cos[i];
            // Rot(x, alpha) · Rot(z, theta) and Trans(x, a) · Rot(x, alpha) · Trans(z, d), expanded.
            let local = Frame {
                rotation: Matrix3::new(ct, -st, 0.0, ca * st, ca * ct, -sa, sa * st, sa * ct, ca),
                origin_mm: Vector3::new(self.a_mm[i], -sa * self.d_mm[i], ca * self.d_mm[i]),
            };
            joints[i + 1] = joints[i].compose(&local);
        }
        Chain {
            tool: joints[JOINTS].compose(&self.flange_from_tool[target]),
            joints,
        }
    }

    /// Both chains of one conf-wrench row to its target's tool frame: the
    /// undeflected one (the readings) with its loads, and the deflected one
    /// (compliance deflections and joint-error terms added). The deflected joint
    /// angles reuse the undeflected sines and cosines through the angle-sum
    /// formula, which halves the trigonometry. The row's tool frame carries the
    /// payload and the wrench.
    pub(crate) fn loaded_chains(&self, row: &ConfWrench) -> LoadedChains {
        let ConfWrench {
            q_deg,
            wrench,
            target,
            approach,
            ..
        } = row;
        let target = *target;
        let undeflected_sin_cos: [(f64, f64); JOINTS] =
            std::array::from_fn(|i| (q_deg[i] * DEG + self.theta_zero_rad[i]).sin_cos());
        let undeflected = self.chain_at(&undeflected_sin_cos, target);
        let loads = self.robot.loads(&undeflected, wrench);
        let deflections_deg: [f64; JOINTS] =
            std::array::from_fn(|i| self.compliance(i) * loads.torques_nm[i]);
        let terms_deg = self.joint_terms.angles_deg(q_deg, approach);
        let deflected = self.chain_at(
            &std::array::from_fn(|i| {
                add_angle(
                    undeflected_sin_cos[i],
                    (deflections_deg[i] + terms_deg[i]) * DEG,
                )
            }),
            target,
        );
        LoadedChains {
            undeflected,
            loads,
            deflections_deg,
            deflected,
        }
    }

    /// Load torques (N·m) and deflections (deg) for one conf-wrench row.
    pub fn deflections(
        &self,
        q_deg: &[f64; JOINTS],
        wrench: &Wrench,
    ) -> ([f64; JOINTS], [f64; JOINTS]) {
        let undeflected = self.chain(q_deg, &[0.0; JOINTS]);
        let torques = self.robot.loads(&undeflected, wrench).torques_nm;
        let deflections = std::array::from_fn(|i| self.compliance(i) * torques[i]);
        (torques, deflections)
    }

    /// Paper eq. (17): the SMR position with torques and deflections (target 0,
    /// no approach direction).
    pub fn predict(&self, q_deg: &[f64; JOINTS], wrench: &Wrench) -> Prediction {
        self.predict_row(&ConfWrench::new(*q_deg, *wrench))
    }

    /// [`Self::predict`] for a row: its target's SMR (spec §7) and its
    /// approach directions (spec §8).
    /// A positioner row's SMR is its nest on the table; nothing loads it.
    pub fn predict_row(&self, row: &ConfWrench) -> Prediction {
        if let Some((_, nest_mm)) = self.positioner_nest(row) {
            return Prediction {
                position_mm: self.world_from_base.transform_point(&nest_mm),
                torques_nm: [0.0; JOINTS],
                deflections_deg: [0.0; JOINTS],
            };
        }
        let chains = self.loaded_chains(row);
        Prediction {
            position_mm: self
                .world_from_base_at(row.track_mm)
                .transform_point(&chains.deflected.tool.origin_mm),
            torques_nm: chains.loads.torques_nm,
            deflections_deg: chains.deflections_deg,
        }
    }
}

/// The chains of one loaded conf-wrench row (see [`PreparedRobot::loaded_chains`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct LoadedChains {
    pub undeflected: Chain,
    /// Loads on the undeflected chain (first order, as in the paper).
    pub loads: Loads,
    pub deflections_deg: [f64; JOINTS],
    pub deflected: Chain,
}

/// (sin, cos) of `θ + δ` from (sin θ, cos θ): for the small compliance deflections δ
/// the series of sin δ and cos δ are exact to rounding (next terms below 1e-17 for
/// |δ| ≤ 0.05 rad) and much cheaper than another `sin_cos`.
fn add_angle((sin_theta, cos_theta): (f64, f64), delta_rad: f64) -> (f64, f64) {
    let (sin_delta, cos_delta) = if delta_rad.abs() <= 0.05 {
        let d2 = delta_rad * delta_rad;
        (
            delta_rad * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0))),
            1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0))),
        )
    } else {
        delta_rad.sin_cos()
    };
    (
        sin_theta * cos_delta + cos_theta * sin_delta,
        cos_theta * cos_delta - sin_theta * sin_delta,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::test_support::{irb1600, random_q, random_wrench, truth_params};
    use rand::SeedableRng;
    use rand::rngs::StdRng;

    /// jobs/robots/ur10.toml (MDH) against UR's standard DH chain, computed
    /// independently by fixtures/tools/ur10_fk.py (its output pasted here).
    #[test]
    // The script's output verbatim, digits and all.
    #[allow(clippy::excessive_precision, clippy::approx_constant)]
    fn ur10_file_matches_urs_standard_dh_forward_kinematics() {
        /// q (deg), flange position (mm), flange rotation rows.
        type Case = ([f64; 6], [f64; 3], [[f64; 3]; 3]);
        let robot = crate::robot::test_support::ur10();
        #[rustfmt::skip]
        let cases: [Case; 5] = [
            ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
             [-1184.300000000000, -256.141000000000, 11.600000000000],
             [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
            ([0.0, -90.0, 0.0, -90.0, 0.0, 0.0],
             [0.0, -256.141000000000, 1427.300000000000],
             [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]]),
            ([30.0, -60.0, 45.0, -120.0, 60.0, 90.0],
             [-660.676611078140, -623.976275034970, 943.702679782685],
             [[0.612372435695795, -0.126826484044322, 0.780330085889910],
              [0.353553390593274, 0.926776695296637, -0.126826484044322],
              [-0.707106781186547, 0.353553390593274, 0.612372435695795]]),
            ([-135.0, -20.0, -110.0, 200.0, -75.0, 300.0],
             [-84.684360218904, 180.910767639029, 819.139316753273],
             [[-0.265232523315719, 0.869529842574827, -0.416616804086648],
              [-0.948245225207938, -0.313482859317392, -0.050591400302210],
              [-0.174592959325177, 0.381636410456325, 0.907673371190369]]),
            ([10.0, 20.0, 30.0, 40.0, 50.0, 60.0],
             [-775.931988151950, -363.467074923329, -591.052860167870],
             [[-0.786357421172699, -0.607604499644464, 0.111618897048950],
              [-0.527586986548180, 0.566511110779744, -0.633022221559489],
              [0.321393804843270, -0.556670399226419, -0.766044443118978]]),
        ];
        for (q, position, rows) in cases {
            let flange = robot.nominal_flange_in_base(&q);
            let error = (flange.origin_mm - Vector3::from(position)).norm();
            assert!(error < 1e-9, "{q:?}: {:?}, {error:e} mm", flange.origin_mm);
            let rotation = Matrix3::from_fn(|r, c| rows[r][c]);
            assert!((flange.rotation - rotation).norm() < 1e-12, "{q:?}");
        }
    }

    #[test]
    fn spec_flange_check_positions() {
        let robot = irb1600();
        let cases = [
            ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [815.0, 0.0, 1186.5]),
            ([0.0, 30.0, 0.0, 0.0, 0.0, 0.0], [1075.907, 0.0, 760.218]),
            ([0.0, 0.0, 30.0, 0.0, 0.0, 0.0], [725.907, 0.0, 854.000]),
        ];
        for (q, expected) in cases {
            let flange = robot.nominal_flange_in_base(&q);
            // The spec prints three decimals; the exact values follow from its geometry.
            let exact = exact_flange(q[1], q[2]);
            for k in 0..3 {
                assert!(
                    (flange.origin_mm[k] - exact[k]).abs() < 1e-6,
                    "{q:?}: {flange:?}"
                );
                assert!(
                    (flange.origin_mm[k] - expected[k]).abs() < 5e-4,
                    "{q:?}: {flange:?}"
                );
            }
        }
        let home = robot.nominal_flange_in_base(&[0.0; 6]);
        assert!((home.axis(2) - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
    }

    /// Planar closed form of the IRB 1600 with q1 = q4 = q5 = q6 = 0 (x forward, z up):
    /// shoulder at (150, 486.5), upper arm 700 leaning forward by q2, forearm 600 + flange 65
    /// horizontal when q3 = 0 and lowered by q3.
    fn exact_flange(q2_deg: f64, q3_deg: f64) -> [f64; 3] {
        let (q2, q23) = (q2_deg * DEG, (q2_deg + q3_deg) * DEG);
        [
            150.0 + 700.0 * q2.sin() + 665.0 * q23.cos(),
            0.0,
            486.5 + 700.0 * q2.cos() - 665.0 * q23.sin(),
        ]
    }

    #[test]
    fn angle_sum_equals_sin_cos_of_the_sum() {
        use rand::Rng;
        let mut rng = StdRng::seed_from_u64(4);
        for _ in 0..10_000 {
            let theta: f64 = rng.random_range(-7.0..7.0);
            // Both sides of the series' 0.05 rad switch, and large deflections.
            let delta: f64 = rng.random_range(-0.2..0.2);
            let (s, c) = add_angle(theta.sin_cos(), delta);
            // The reference rounds theta + delta itself (ulp 9e-16 near 7 rad).
            let (s_ref, c_ref) = (theta + delta).sin_cos();
            assert!(
                (s - s_ref).abs() < 2e-15 && (c - c_ref).abs() < 2e-15,
                "{theta} {delta}: {} {}",
                s - s_ref,
                c - c_ref
            );
        }
    }

    #[test]
    fn gravity_torque_on_joint_1_is_zero_for_a_level_base() {
        let robot = irb1600();
        let mut rng = StdRng::seed_from_u64(1);
        for _ in 0..100 {
            let q = random_q(&robot, &mut rng);
            let (torques, _) = robot.deflections(&truth_params(&robot), &q, &Wrench::zero());
            assert!(torques[0].abs() < 1e-9, "{torques:?}");
            assert!(torques[1].abs() > 1.0);
        }
    }

    #[test]
    fn external_torques_equal_geometric_jacobian_transpose_times_wrench() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let mut rng = StdRng::seed_from_u64(2);
        for _ in 0..100 {
            let q = random_q(&robot, &mut rng);
            let w = random_wrench(&mut rng);
            let (with_load, _) = robot.deflections(&p, &q, &w);
            let (gravity_only, _) = robot.deflections(&p, &q, &Wrench::zero());
            let chain = robot.prepare(&p).chain(&q, &[0.0; 6]);
            let f = chain.tool.rotation * w.force_n;
            let m = chain.tool.rotation * w.moment_nm;
            for i in 0..6 {
                // Column i of the geometric Jacobian at the tool origin (metres).
                let z = chain.joints[i + 1].axis(2);
                let linear =
                    z.cross(&((chain.tool.origin_mm - chain.joints[i + 1].origin_mm) * MM));
                let jt_w = linear.dot(&f) + z.dot(&m);
                assert!((with_load[i] - gravity_only[i] - jt_w).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn zero_compliance_gives_the_kinematic_model() {
        let robot = irb1600();
        let mut p = truth_params(&robot);
        for i in 0..6 {
            p.0[36 + i] = 0.0;
        }
        let mut rng = StdRng::seed_from_u64(3);
        for _ in 0..50 {
            let q = random_q(&robot, &mut rng);
            let loaded = robot.predict(&p, &q, &random_wrench(&mut rng));
            let kinematic = robot
                .world_from_base(&p)
                .transform_point(&robot.prepare(&p).chain(&q, &[0.0; 6]).tool.origin_mm);
            assert_eq!(loaded.position_mm, kinematic);
            assert_eq!(loaded.deflections_deg, [0.0; 6]);
        }
    }

    #[test]
    fn deflection_moves_the_tool_by_compliance_times_torque() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let q = [10.0, 20.0, -30.0, 40.0, 50.0, 60.0];
        let w = Wrench::from_array([0.0, 0.0, 100.0, 0.0, 0.0, 5.0]);
        let prediction = robot.predict(&p, &q, &w);
        let q_deflected: [f64; 6] = std::array::from_fn(|i| q[i] + prediction.deflections_deg[i]);
        let mut rigid = p;
        for i in 0..6 {
            rigid.0[36 + i] = 0.0;
        }
        let moved = robot
            .predict(&rigid, &q_deflected, &Wrench::zero())
            .position_mm;
        assert!((moved - prediction.position_mm).norm() < 1e-9);
        assert!(prediction.deflections_deg[5].abs() > 0.1);
    }

    #[test]
    fn world_frame_maps_base_to_tracker() {
        let robot = irb1600();
        let p = ParamValues::nominal(robot.spec());
        // Base origin in the world: Rot(x, -180) applied to (1326, 1362, -1476).
        let base = robot.world_from_base(&p).origin_mm;
        assert!((base - Vector3::new(1326.0, -1362.0, 1476.0)).norm() < 1e-9);
    }
}
