//! The elasto-geometric forward model (`../shared/spec/model.md` §1 and §3; paper
//! eqs. (1)–(17)): SMR position in the world frame for a parameter set, a joint
//! vector and an external wrench, with the load torques and the compliance
//! deflections they cause.
//!
//! Units cross here: robot-file and parameter values come in mm and degrees,
//! torques are computed with positions in metres (N·m), and compliances are
//! deg/(N·m), so a deflection is in degrees like every other joint angle.
//!
//! A prismatic joint (`kind = "prismatic"`) carries millimetres where a
//! revolute joint carries degrees, in every joint vector (the `q_deg`
//! arrays), deflection and joint-error term: its value is added to the MDH
//! offset d, its load is the force along its axis (N, in the `torques_nm`
//! arrays) and its compliance is mm/N.
//!
//! Torques are evaluated on the undeflected chain with the current geometric
//! parameters (first order, as in the paper); the position is evaluated on the
//! deflected chain.

use nalgebra::{Matrix3, Vector3};

use super::file::RobotSpec;
use super::frame::{Frame, rot_x};
use super::jacobian::ConfWrench;
use super::params::{
    JointParam, MAX_HARMONIC_ORDER, MAX_TARGETS, PARAM_COUNT, ParamId, ParamValues,
};
use super::positioner::{
    MAX_POSITIONER_AXES, POSITIONER_TERM_COUNT, PositionerChain, PositionerModel, PositionerTerm,
};
use super::track::{Carriage, TrackErrors, TrackTerm};

/// Most joints an arm has: six-axis arms and seven-axis ones (issue #30).
/// Joint vectors are arrays of this length; an arm with fewer joints leaves
/// the last entries zero and the model's loops stop at
/// [`Robot::joint_count`], so a six-joint arm computes exactly what it did
/// before seven-joint arms existed.
pub const MAX_JOINTS: usize = 7;

/// A joint vector of the first `values.len()` joints (at most
/// [`MAX_JOINTS`]), zeros past them: a six-joint table row or setting as the
/// model's joint vector.
pub fn joint_array<T: Copy + Default>(values: &[T]) -> [T; MAX_JOINTS] {
    std::array::from_fn(|i| values.get(i).copied().unwrap_or_default())
}

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
    pub torques_nm: [f64; MAX_JOINTS],
    /// Compliance deflection `k_i·τ_i` of each joint, deg.
    pub deflections_deg: [f64; MAX_JOINTS],
}

/// A robot model built from a robot file: nominal MDH values in radians and
/// millimetres, and the link inertia in SI units.
#[derive(Debug, Clone)]
pub struct Robot {
    spec: RobotSpec,
    /// Joints of this arm (6 or 7); entries past it are unused zeros.
    joint_count: usize,
    alpha_rad: [f64; MAX_JOINTS],
    a_mm: [f64; MAX_JOINTS],
    theta_offset_rad: [f64; MAX_JOINTS],
    d_mm: [f64; MAX_JOINTS],
    /// Which joints slide along their axis: their value is added to `d`
    /// (mm), their θ is fixed, their compliance is mm/N and their load a
    /// force (N) along the axis.
    prismatic: [bool; MAX_JOINTS],
    /// Link masses 1..n, then the payload (at index `joint_count`).
    masses_kg: [f64; MAX_JOINTS + 1],
    /// Centres of gravity of links 1..n in their own frames, then the payload in the tool frame, mm.
    cogs_mm: [Vector3<f64>; MAX_JOINTS + 1],
    gravity_mps2: Vector3<f64>,
}

/// Frames of one evaluation of the chain, all in the base frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Chain {
    /// `joints[0]` is the base itself, `joints[i]` is MDH frame i; the
    /// flange is `joints[joint_count]` and frames past it are the identity.
    pub joints: [Frame; MAX_JOINTS + 1],
    pub tool: Frame,
    /// Joints of the arm: the index of the flange in `joints`.
    pub joint_count: usize,
}

impl Chain {
    /// The flange (last MDH frame), base frame.
    pub fn flange(&self) -> &Frame {
        &self.joints[self.joint_count]
    }
}

/// Load state on the undeflected chain: what the Jacobian needs besides the torques.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Loads {
    pub torques_nm: [f64; MAX_JOINTS],
    /// Suffix sums over bodies s..n+1 (links s..n and the payload), 1-based
    /// `s`, n the joint count: total mass and first mass moment (kg·m) in the
    /// base frame. Index n+1 is the payload alone.
    pub suffix_mass_kg: [f64; MAX_JOINTS + 2],
    pub suffix_moment_kgm: [Vector3<f64>; MAX_JOINTS + 2],
    /// External force and moment in base axes, N and N·m.
    pub force_base_n: Vector3<f64>,
    pub moment_base_nm: Vector3<f64>,
}

const DEG: f64 = std::f64::consts::PI / 180.0;
const MM: f64 = 1e-3;

impl Robot {
    /// A robot of a validated file (6 or 7 joints).
    pub fn new(spec: RobotSpec) -> Self {
        let j = &spec.joints;
        let joint_count = j.len().min(MAX_JOINTS);
        let mut cogs_mm = [Vector3::zeros(); MAX_JOINTS + 1];
        let mut masses_kg = [0.0; MAX_JOINTS + 1];
        for i in 0..joint_count {
            cogs_mm[i] = Vector3::from(j[i].link_cog_mm);
            masses_kg[i] = j[i].link_mass_kg;
        }
        cogs_mm[joint_count] = Vector3::from(spec.payload.cog_mm);
        masses_kg[joint_count] = spec.payload.mass_kg;
        let per_joint = |f: fn(&super::file::JointSpec) -> f64| -> [f64; MAX_JOINTS] {
            std::array::from_fn(|i| j.get(i).map_or(0.0, f))
        };
        Robot {
            joint_count,
            alpha_rad: per_joint(|j| j.alpha_deg * DEG),
            a_mm: per_joint(|j| j.a_mm),
            theta_offset_rad: per_joint(|j| j.theta_offset_deg * DEG),
            d_mm: per_joint(|j| j.d_mm),
            prismatic: spec.prismatic_joints(),
            masses_kg,
            cogs_mm,
            gravity_mps2: Vector3::from(spec.gravity_mps2),
            spec,
        }
    }

    pub fn spec(&self) -> &RobotSpec {
        &self.spec
    }

    /// Joints of this arm: 6 or 7.
    pub fn joint_count(&self) -> usize {
        self.joint_count
    }

    /// A joint vector with `f(i)` for each joint of this arm and zeros past
    /// them.
    pub fn joint_vector(&self, mut f: impl FnMut(usize) -> f64) -> [f64; MAX_JOINTS] {
        std::array::from_fn(|i| if i < self.joint_count { f(i) } else { 0.0 })
    }

    /// Joint limits `[min, max]` in the joint's unit: degrees, or
    /// millimetres for a prismatic joint.
    pub fn joint_limits(&self, joint: usize) -> [f64; 2] {
        self.spec.joints[joint].limits()
    }

    /// Whether joint `joint` slides along its axis (its value in mm) rather
    /// than turning about it.
    pub fn is_prismatic(&self, joint: usize) -> bool {
        self.prismatic[joint]
    }

    /// Which joints are prismatic, as a joint vector's mask.
    pub fn prismatic_joints(&self) -> [bool; MAX_JOINTS] {
        self.prismatic
    }

    /// Whether any joint of the arm is prismatic.
    pub fn has_prismatic_joint(&self) -> bool {
        self.prismatic.iter().any(|&p| p)
    }

    pub fn within_limits(&self, q_deg: &[f64; MAX_JOINTS]) -> bool {
        (0..self.joint_count).all(|i| {
            let [lo, hi] = self.joint_limits(i);
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
            alpha_sin_cos: std::array::from_fn(|i| {
                (self.alpha_rad[i] + p.get(ParamId::of_joint(JointParam::Alpha, i)) * DEG).sin_cos()
            }),
            a_mm: std::array::from_fn(|i| {
                self.a_mm[i] + p.get(ParamId::of_joint(JointParam::A, i))
            }),
            d_mm: std::array::from_fn(|i| {
                self.d_mm[i] + p.get(ParamId::of_joint(JointParam::D, i))
            }),
            theta_zero_rad: std::array::from_fn(|i| {
                p.get(ParamId::of_joint(JointParam::Theta, i)) * DEG + self.theta_offset_rad[i]
            }),
            flange_from_tool: std::array::from_fn(|target| self.flange_from_tool(p, target)),
            tool_rxy: tool_rx * super::frame::rot_y(v[10] * DEG),
            tool_rx,
            world_from_base: self.world_from_base(p),
            world_rotation_axes: world_rotation_axes(p),
            joint_terms: JointTerms::of(p, self.joint_count, &self.prismatic),
            theta_zero_sin_cos: std::array::from_fn(|i| {
                (p.get(ParamId::of_joint(JointParam::Theta, i)) * DEG + self.theta_offset_rad[i])
                    .sin_cos()
            }),
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
        let n = self.joint_count;
        let mut suffix_mass_kg = [0.0; MAX_JOINTS + 2];
        let mut suffix_moment_kgm = [Vector3::zeros(); MAX_JOINTS + 2];
        // Body b (1..=n links, n+1 payload) has its frame at joints[b] or the tool.
        for body in (1..=n + 1).rev() {
            let frame = if body <= n {
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
            if j >= n {
                return 0.0;
            }
            let frame = &chain.joints[j + 1];
            let z = frame.axis(2);
            if self.prismatic[j] {
                // The force along the axis of everything the joint carries.
                return z.dot(&(g * suffix_mass_kg[j + 1] + force_base_n));
            }
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
        q_deg: &[f64; MAX_JOINTS],
        wrench: &Wrench,
    ) -> ([f64; MAX_JOINTS], [f64; MAX_JOINTS]) {
        self.prepare(p).deflections(q_deg, wrench)
    }

    /// Tool pose in the world frame on the loaded (deflected) robot, each
    /// joint approached from `approach` (−1, 0, +1; spec §8: only a model with
    /// backlash tells them apart).
    pub fn tool_in_world(
        &self,
        p: &ParamValues,
        q_deg: &[f64; MAX_JOINTS],
        wrench: &Wrench,
        approach: &[i8; MAX_JOINTS],
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
    pub fn predict(
        &self,
        p: &ParamValues,
        q_deg: &[f64; MAX_JOINTS],
        wrench: &Wrench,
    ) -> Prediction {
        self.prepare(p).predict(q_deg, wrench)
    }

    /// Frames of joints 0..=n and of the tool in the base frame, unloaded: the
    /// geometry collision and visibility checks work on (frames past the
    /// flange are the identity).
    pub fn frames_in_base(
        &self,
        p: &ParamValues,
        q_deg: &[f64; MAX_JOINTS],
    ) -> ([Frame; MAX_JOINTS + 1], Frame) {
        let chain = self.prepare(p).chain(q_deg, &[0.0; MAX_JOINTS]);
        (chain.joints, chain.tool)
    }

    /// Flange pose in the base frame of the nominal arm (zero errors, no load):
    /// the frame the closed-form inverse kinematics solves for.
    pub fn nominal_flange_in_base(&self, q_deg: &[f64; MAX_JOINTS]) -> Frame {
        let zero = ParamValues([0.0; PARAM_COUNT]);
        *self
            .prepare(&zero)
            .chain(q_deg, &[0.0; MAX_JOINTS])
            .flange()
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
    backlash_deg: [f64; MAX_JOINTS],
    /// Per joint and order 1..: coefficients (deg) of sin(n·q) and cos(n·q).
    harmonics_deg: [[(f64, f64); MAX_HARMONIC_ORDER]; MAX_JOINTS],
    /// Whether any harmonic coefficient is non-zero: the elasto-geometric
    /// model skips their trigonometry.
    any_harmonic: bool,
}

impl JointTerms {
    /// A prismatic joint takes a backlash (mm) but no harmonics: a screw's
    /// error repeats with its lead, not with a turn of the joint.
    fn of(p: &ParamValues, joints: usize, prismatic: &[bool; MAX_JOINTS]) -> Self {
        let harmonics_deg: [[(f64, f64); MAX_HARMONIC_ORDER]; MAX_JOINTS] =
            std::array::from_fn(|joint| {
                std::array::from_fn(|o| {
                    if joint >= joints || prismatic[joint] {
                        return (0.0, 0.0);
                    }
                    (
                        p.get(ParamId::harmonic(joint, o + 1, false)),
                        p.get(ParamId::harmonic(joint, o + 1, true)),
                    )
                })
            });
        let mut backlash = ParamId::backlashes(joints);
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
        q_deg: &[f64; MAX_JOINTS],
        approach: &[i8; MAX_JOINTS],
    ) -> [f64; MAX_JOINTS] {
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
    alpha_sin_cos: [(f64, f64); MAX_JOINTS],
    a_mm: [f64; MAX_JOINTS],
    d_mm: [f64; MAX_JOINTS],
    /// Joint angle at q_i = 0: offset error plus the nominal theta offset.
    theta_zero_rad: [f64; MAX_JOINTS],
    /// Its (sin, cos): a prismatic joint's fixed angle.
    theta_zero_sin_cos: [(f64, f64); MAX_JOINTS],
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

    /// Compliance of joint `i`, deg/(N·m), or mm/N for a prismatic joint.
    pub(crate) fn compliance(&self, joint: usize) -> f64 {
        self.values
            .get(ParamId::of_joint(JointParam::Compliance, joint))
    }

    /// Forward chain in the base frame for joint commands `q_deg` plus extra joint
    /// angles `extra_deg` (the compliance deflections, or zero), to target 0.
    pub(crate) fn chain(&self, q_deg: &[f64; MAX_JOINTS], extra_deg: &[f64; MAX_JOINTS]) -> Chain {
        let values: [f64; MAX_JOINTS] = std::array::from_fn(|i| q_deg[i] + extra_deg[i]);
        self.chain_at(&self.joint_sin_cos(&values), &values, 0)
    }

    /// (sin, cos) of each joint's MDH angle at joint values `q_deg`; a
    /// prismatic joint's angle does not move.
    fn joint_sin_cos(&self, q_deg: &[f64; MAX_JOINTS]) -> [(f64, f64); MAX_JOINTS] {
        std::array::from_fn(|i| {
            if self.robot.prismatic[i] {
                self.theta_zero_sin_cos[i]
            } else {
                (q_deg[i] * DEG + self.theta_zero_rad[i]).sin_cos()
            }
        })
    }

    /// Tool frame (base frame, target 0) of the loaded robot: the compliance
    /// deflections and the joint-error terms added to the readings.
    pub(crate) fn loaded_chain(
        &self,
        q_deg: &[f64; MAX_JOINTS],
        wrench: &Wrench,
        approach: &[i8; MAX_JOINTS],
    ) -> Frame {
        let (_, deflections) = self.deflections(q_deg, wrench);
        let terms = self.joint_terms.angles_deg(q_deg, approach);
        self.chain(q_deg, &std::array::from_fn(|i| deflections[i] + terms[i]))
            .tool
    }

    /// Forward chain for the (sin, cos) of each joint angle and the travel
    /// (mm) of each prismatic joint (read only for those), to `target`'s
    /// tool frame.
    // Always inlined, as `loaded_chains` is: returned through memory, each
    // chain's 800 bytes of frames were copied twice per row (issue #31).
    #[inline(always)]
    fn chain_at(
        &self,
        joint_sin_cos: &[(f64, f64); MAX_JOINTS],
        travel_mm: &[f64; MAX_JOINTS],
        target: usize,
    ) -> Chain {
        let n = self.robot.joint_count;
        let mut joints = [Frame::identity(); MAX_JOINTS + 1];
        for i in 0..n {
            let (sa, ca) = self.alpha_sin_cos[i];
            let (st, ct) = joint_sin_cos[i];
            let d_mm = if self.robot.prismatic[i] {
                self.d_mm[i] + travel_mm[i]
            } else {
                self.d_mm[i]
            };
            // Rot(x, alpha) · Rot(z, theta) and Trans(x, a) · Rot(x, alpha) · Trans(z, d), expanded.
            let local = Frame {
                rotation: Matrix3::new(ct, -st, 0.0, ca * st, ca * ct, -sa, sa * st, sa * ct, ca),
                origin_mm: Vector3::new(self.a_mm[i], -sa * d_mm, ca * d_mm),
            };
            joints[i + 1] = joints[i].compose(&local);
        }
        Chain {
            tool: joints[n].compose(&self.flange_from_tool[target]),
            joints,
            joint_count: n,
        }
    }

    /// Both chains of one conf-wrench row to its target's tool frame: the
    /// undeflected one (the readings) with its loads, and the deflected one
    /// (compliance deflections and joint-error terms added). The deflected joint
    /// angles reuse the undeflected sines and cosines through the angle-sum
    /// formula, which halves the trigonometry. The row's tool frame carries the
    /// payload and the wrench.
    #[inline(always)]
    pub(crate) fn loaded_chains(&self, row: &ConfWrench) -> LoadedChains {
        let ConfWrench {
            q_deg,
            wrench,
            target,
            approach,
            ..
        } = row;
        let target = *target;
        let undeflected_sin_cos = self.joint_sin_cos(q_deg);
        let undeflected = self.chain_at(&undeflected_sin_cos, q_deg, target);
        let loads = self.robot.loads(&undeflected, wrench);
        let deflections_deg: [f64; MAX_JOINTS] =
            std::array::from_fn(|i| self.compliance(i) * loads.torques_nm[i]);
        let terms_deg = self.joint_terms.angles_deg(q_deg, approach);
        let extra: [f64; MAX_JOINTS] = std::array::from_fn(|i| deflections_deg[i] + terms_deg[i]);
        let deflected = self.chain_at(
            &std::array::from_fn(|i| {
                if self.robot.prismatic[i] {
                    undeflected_sin_cos[i]
                } else {
                    add_angle(undeflected_sin_cos[i], extra[i] * DEG)
                }
            }),
            &std::array::from_fn(|i| q_deg[i] + extra[i]),
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
        q_deg: &[f64; MAX_JOINTS],
        wrench: &Wrench,
    ) -> ([f64; MAX_JOINTS], [f64; MAX_JOINTS]) {
        let undeflected = self.chain(q_deg, &[0.0; MAX_JOINTS]);
        let torques = self.robot.loads(&undeflected, wrench).torques_nm;
        let deflections = std::array::from_fn(|i| self.compliance(i) * torques[i]);
        (torques, deflections)
    }

    /// Paper eq. (17): the SMR position with torques and deflections (target 0,
    /// no approach direction).
    pub fn predict(&self, q_deg: &[f64; MAX_JOINTS], wrench: &Wrench) -> Prediction {
        self.predict_row(&ConfWrench::new(*q_deg, *wrench))
    }

    /// [`Self::predict`] for a row: its target's SMR (spec §7) and its
    /// approach directions (spec §8).
    /// A positioner row's SMR is its nest on the table; nothing loads it.
    pub fn predict_row(&self, row: &ConfWrench) -> Prediction {
        if let Some((_, nest_mm)) = self.positioner_nest(row) {
            return Prediction {
                position_mm: self.world_from_base.transform_point(&nest_mm),
                torques_nm: [0.0; MAX_JOINTS],
                deflections_deg: [0.0; MAX_JOINTS],
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
    pub deflections_deg: [f64; MAX_JOINTS],
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

    /// The nominal flange of `robot` at joint values `q` is at `position`
    /// (mm, to 1e-9) with rotation `rows` (to 1e-12): an independent
    /// script's output.
    fn assert_flange_is(robot: &Robot, q: &[f64], position: [f64; 3], rows: [[f64; 3]; 3]) {
        let flange = robot.nominal_flange_in_base(&crate::robot::joint_array(q));
        let error = (flange.origin_mm - Vector3::from(position)).norm();
        assert!(error < 1e-9, "{q:?}: {:?}, {error:e} mm", flange.origin_mm);
        let rotation = Matrix3::from_fn(|r, c| rows[r][c]);
        assert!((flange.rotation - rotation).norm() < 1e-12, "{q:?}");
    }

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
            assert_flange_is(&robot, &q, position, rows);
        }
    }

    /// jobs/robots/panda.toml (MDH, seven joints) against the URDF chain of
    /// franka_description, computed independently by
    /// fixtures/tools/panda_fk.py (its output pasted here).
    #[test]
    // The script's output verbatim, digits and all.
    #[allow(clippy::excessive_precision, clippy::approx_constant)]
    fn panda_file_matches_the_urdf_chain_of_franka_description() {
        /// q (deg), flange position (mm), flange rotation rows.
        type Case = ([f64; 7], [f64; 3], [[f64; 3]; 3]);
        let robot = crate::robot::test_support::panda();
        assert_eq!(robot.joint_count(), 7);
        #[rustfmt::skip]
        let cases: [Case; 5] = [
            ([0.0, 0.0, 0.0, -90.0, 0.0, 90.0, 0.0],
             [554.500000000000, 0.0, 624.500000000000],
             [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]),
            ([0.0, -45.0, 0.0, -135.0, 0.0, 90.0, 45.0],
             [306.890566592941, 0.0, 590.282052302839],
             [[0.707106781186547, -0.707106781186548, 0.0],
              [-0.707106781186548, -0.707106781186547, 0.0],
              [0.0, 0.0, -1.0]]),
            ([30.0, 20.0, -40.0, -100.0, 60.0, 120.0, -70.0],
             [655.515586997904, -28.486385973676, 433.871350322061],
             [[0.715297751602333, 0.606458811484983, 0.347212955583267],
              [0.365165254266631, -0.748000085322016, 0.554211340045152],
              [0.595821670996476, -0.269636018236581, -0.756500465327344]]),
            ([-120.0, 80.0, 150.0, -20.0, -150.0, 10.0, 160.0],
             [-273.566330502838, -584.824748384290, 437.162900646289],
             [[-0.081859970971454, 0.965112850854486, 0.248708926796124],
              [0.636083337299336, -0.141521016166235, 0.758531337515738],
              [0.767265881662082, 0.220292957442592, -0.602307296766779]]),
            ([10.0, -90.0, 90.0, -170.0, 100.0, 200.0, -150.0],
             [80.385522950601, 239.864175790035, 450.476836404233],
             [[0.061590755003082, -0.424490395695725, 0.903335199613210],
              [0.696806195166309, 0.666277776949361, 0.265584356318795],
              [-0.714610177142756, 0.613092022379597, 0.336824088833465]]),
        ];
        for (q, position, rows) in cases {
            assert_flange_is(&robot, &q, position, rows);
        }
    }

    /// The seventh joint's parameters move the seven-joint arm's SMR as the
    /// analytic Jacobian says (finite differences), and a six-joint arm's
    /// never: its seventh slots are outside its model.
    /// jobs/robots/gantry.toml (MDH, three prismatic joints) against a
    /// URDF-style chain written from the file's description, computed
    /// independently by fixtures/tools/gantry_fk.py (its output pasted here).
    #[test]
    // The script's output verbatim, digits and all.
    #[allow(clippy::excessive_precision, clippy::approx_constant)]
    fn gantry_file_matches_its_urdf_style_chain() {
        /// q (mm for joints 1–3, deg for 4–6), flange position (mm), rotation rows.
        type Case = ([f64; 6], [f64; 3], [[f64; 3]; 3]);
        let robot = crate::robot::test_support::gantry();
        assert_eq!(
            robot.prismatic_joints(),
            [true, true, true, false, false, false, false]
        );
        #[rustfmt::skip]
        let cases: [Case; 5] = [
            ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
             [0.0, 200.0, -890.0],
             [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]),
            ([1500.0, 1000.0, 600.0, 0.0, 0.0, 0.0],
             [1000.0, 1700.0, -1490.0],
             [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]),
            ([250.0, 1800.0, 1100.0, 90.0, 45.0, -30.0],
             [1800.0, 351.005050633883, -1948.994949366117],
             [[0.500000000000000, -0.866025403784439, 0.0],
              [-0.612372435695795, -0.353553390593274, -0.707106781186547],
              [0.612372435695794, 0.353553390593274, -0.707106781186548]]),
            ([2900.0, 120.0, 35.0, -200.0, -100.0, 300.0],
             [249.558320975765, 3147.155372436685, -760.689255126630],
             [[0.377786088309291, -0.029695587306942, 0.925416578398323],
              [-0.784102094042431, 0.521280576369176, 0.336824088833465],
              [-0.492403876506104, -0.852868531952443, 0.173648177666930]]),
            ([800.0, 640.0, 410.0, 30.0, 60.0, 90.0],
             [745.0, 939.378221735089, -1230.0],
             [[-0.5, -0.433012701892220, 0.75],
              [-0.866025403784439, 0.25, -0.433012701892219],
              [0.0, -0.866025403784439, -0.5]]),
        ];
        for (q, position, rows) in cases {
            assert_flange_is(&robot, &q, position, rows);
        }
    }

    /// A prismatic joint's load is the force along its axis of everything it
    /// carries, and its deflection `k·F` (mm) moves the tool along that axis:
    /// the vertical ram (joint 3, axis down) carries its own 80 kg, the wrist's
    /// 19.5 kg and the 10 kg payload; the horizontal bridge and carriage carry
    /// no gravity force. Hand-computed.
    #[test]
    fn a_prismatic_joint_carries_the_force_along_its_axis_and_deflects_along_it() {
        let robot = crate::robot::test_support::gantry();
        let mut p = ParamValues([0.0; PARAM_COUNT]);
        let k3_mm_per_n = 1e-3;
        p.set(ParamId::of_joint(JointParam::Compliance, 2), k3_mm_per_n);
        let q = crate::robot::joint_array(&[1000.0, 500.0, 300.0, 0.0, 0.0, 0.0]);
        let pull_n = 200.0;
        // In tool axes: the tool's z points down, so +z pulls the ram down.
        let wrench = Wrench::from_array([0.0, 0.0, pull_n, 0.0, 0.0, 0.0]);
        let prediction = robot.predict(&p, &q, &wrench);
        let carried_kg = 80.0 + 12.0 + 6.0 + 1.5 + 10.0;
        let force_n = carried_kg * 9.81 + pull_n;
        assert!((prediction.torques_nm[2] - force_n).abs() < 1e-9);
        assert!(prediction.torques_nm[0].abs() < 1e-9);
        assert!(prediction.torques_nm[1].abs() < 1e-9);
        assert!((prediction.deflections_deg[2] - k3_mm_per_n * force_n).abs() < 1e-12);
        let unloaded = robot.predict(&p, &q, &Wrench::zero());
        let drop_mm = unloaded.position_mm.z - prediction.position_mm.z;
        assert!((drop_mm - k3_mm_per_n * pull_n).abs() < 1e-9, "{drop_mm}");
    }

    #[test]
    fn a_seventh_joint_has_parameters_by_the_rule_of_the_42() {
        use crate::robot::params::JointParam;
        let names: Vec<&str> = [
            JointParam::Theta,
            JointParam::Alpha,
            JointParam::A,
            JointParam::D,
            JointParam::Compliance,
        ]
        .map(|kind| ParamId::of_joint(kind, 6).name())
        .to_vec();
        assert_eq!(names, ["dtheta7", "dalpha7", "da7", "dd7", "k7"]);
        for name in names {
            let id = ParamId::from_name(name).unwrap();
            assert_eq!(id.name(), name);
        }
        assert_eq!(ParamId::of_arm(6).count(), 42);
        assert_eq!(ParamId::of_arm(7).count(), 47);
        let panda = crate::robot::test_support::panda();
        let mut p = ParamValues::nominal(panda.spec());
        p.0[ParamId::of_joint(JointParam::Compliance, 6).index()] = 0.01;
        let mut rng = StdRng::seed_from_u64(7);
        let ids: Vec<ParamId> = ParamId::of_arm(7).collect();
        for _ in 0..20 {
            let row = ConfWrench::new(random_q(&panda, &mut rng), random_wrench(&mut rng));
            let prepared = panda.prepare(&p);
            let mut columns = vec![Vector3::zeros(); ids.len()];
            let base = prepared.jacobian_row(&row, &ids, &mut columns).position_mm;
            for (id, column) in ids.iter().zip(&columns) {
                let step = if id.is_compliance() { 1e-6 } else { 1e-5 };
                let mut moved = p;
                moved.0[id.index()] += step;
                let ahead = panda.prepare(&moved).predict_row(&row).position_mm;
                let numeric = (ahead - base) / step;
                assert!(
                    (numeric - column).norm() < 1e-4 * (1.0 + column.norm()),
                    "{id}: analytic {column:?}, numeric {numeric:?}"
                );
            }
        }
        let irb = irb1600();
        let truth = truth_params(&irb);
        let mut with_seventh = truth;
        for id in ParamId::of_arm(7).skip(42) {
            with_seventh.0[id.index()] = 0.5;
        }
        let row = ConfWrench::new(random_q(&irb, &mut rng), random_wrench(&mut rng));
        assert_eq!(
            irb.prepare(&truth).predict_row(&row),
            irb.prepare(&with_seventh).predict_row(&row)
        );
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
            let flange = robot.nominal_flange_in_base(&crate::robot::joint_array(&q));
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
        let home = robot.nominal_flange_in_base(&[0.0; 7]);
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
            let chain = robot.prepare(&p).chain(&q, &[0.0; 7]);
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
                .transform_point(&robot.prepare(&p).chain(&q, &[0.0; 7]).tool.origin_mm);
            assert_eq!(loaded.position_mm, kinematic);
            assert_eq!(loaded.deflections_deg, [0.0; MAX_JOINTS]);
        }
    }

    #[test]
    fn deflection_moves_the_tool_by_compliance_times_torque() {
        let robot = irb1600();
        let p = truth_params(&robot);
        let q = [10.0, 20.0, -30.0, 40.0, 50.0, 60.0];
        let w = Wrench::from_array([0.0, 0.0, 100.0, 0.0, 0.0, 5.0]);
        let prediction = robot.predict(&p, &crate::robot::joint_array(&q), &w);
        let q_deflected: [f64; 6] = std::array::from_fn(|i| q[i] + prediction.deflections_deg[i]);
        let mut rigid = p;
        for i in 0..6 {
            rigid.0[36 + i] = 0.0;
        }
        let moved = robot
            .predict(
                &rigid,
                &crate::robot::joint_array(&q_deflected),
                &Wrench::zero(),
            )
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
