//! A parameter set: which model it is, each parameter's value, standard error,
//! status and reason, and its targets. What a fit produces and every later stage
//! reads; `table::parameters` writes and reads it as the `parameters` table.

use std::fmt;
use std::str::FromStr;

use crate::robot::params::{PARAM_COUNT, ParamId, ParamKind, ParamValues, TOOL_TRANSLATION_NAMES};

/// Which calibration a parameter set comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ModelName {
    Nominal,
    /// Nominal robot with only the world frame and tool translation(s) fitted.
    Registered,
    Kinematic,
    Elastogeometric,
    /// An earlier calibration's robot with the world frame and tool
    /// translation(s) fitted anew (a moved tracker or re-mounted tool, spec §7).
    Reregistered,
    /// Elasto-geometric with a backlash per joint, signed by the approach
    /// direction (issue #29).
    EgBacklash,
    /// `eg_backlash` with transmission-error harmonics per joint at the chosen
    /// orders (issue #29).
    EgHarmonic,
    /// `eg_harmonic`'s parameters (or the elasto-geometric model's, identify's
    /// `residual_base`) plus a Gaussian-process model of what they leave, on
    /// joint angles and load (issue #29; the `residual_model` table).
    EgResidual,
}

impl ModelName {
    /// Every model, in the order a job lists them by default (not `reregistered`,
    /// which needs a start calibration).
    pub const ALL: [ModelName; 4] = [
        ModelName::Nominal,
        ModelName::Registered,
        ModelName::Kinematic,
        ModelName::Elastogeometric,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            ModelName::Nominal => "nominal",
            ModelName::Registered => "registered",
            ModelName::Kinematic => "kinematic",
            ModelName::Elastogeometric => "elastogeometric",
            ModelName::Reregistered => "reregistered",
            ModelName::EgBacklash => "eg_backlash",
            ModelName::EgHarmonic => "eg_harmonic",
            ModelName::EgResidual => "eg_residual",
        }
    }

    /// Every model a job may name.
    pub fn every() -> impl Iterator<Item = ModelName> + Clone {
        ModelName::ALL.into_iter().chain([
            ModelName::Reregistered,
            ModelName::EgBacklash,
            ModelName::EgHarmonic,
            ModelName::EgResidual,
        ])
    }

    /// The model's place on the ladder of `crossvalidate`'s choice (issue
    /// #29): each rung holds the terms of those below it.
    pub fn ladder_rank(self) -> usize {
        match self {
            ModelName::Nominal => 0,
            ModelName::Registered | ModelName::Reregistered => 1,
            ModelName::Kinematic => 2,
            ModelName::Elastogeometric => 3,
            ModelName::EgBacklash => 4,
            ModelName::EgHarmonic => 5,
            ModelName::EgResidual => 6,
        }
    }

    /// Whether the model has the joint-error terms beyond the paper's
    /// (backlash, harmonics).
    pub fn has_joint_terms(self) -> bool {
        matches!(
            self,
            ModelName::EgBacklash | ModelName::EgHarmonic | ModelName::EgResidual
        )
    }

    /// Whether the model carries a residual model beside its parameters.
    pub fn has_residual_model(self) -> bool {
        self == ModelName::EgResidual
    }
}

impl fmt::Display for ModelName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for ModelName {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let every = ModelName::every();
        every.clone().find(|m| m.as_str() == s).ok_or_else(|| {
            format!(
                "unknown model `{s}`, expected nominal, registered, kinematic, elastogeometric, reregistered, eg_backlash, eg_harmonic or eg_residual{}",
                crate::suggest::did_you_mean(s, every.map(|m| m.as_str()))
            )
        })
    }
}

/// How a parameter got its value in a set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamStatus {
    Identified,
    /// Not identifiable from the data (rank analysis); held at nominal.
    Dependent,
    /// Not part of this model (e.g. compliances in a kinematic calibration).
    Fixed,
    /// Identifiable in exact arithmetic but not determined by the data (standard
    /// error beyond its kind's bound, or near-dependent on others, spec §8);
    /// held at its nominal value by egcal rather than by the user.
    Held,
}

impl ParamStatus {
    pub fn as_str(self) -> &'static str {
        match self {
            ParamStatus::Identified => "identified",
            ParamStatus::Dependent => "dependent",
            ParamStatus::Fixed => "fixed",
            ParamStatus::Held => "held",
        }
    }

    /// The status a `parameters` table's `status` column names.
    pub fn parse(s: &str) -> Option<Self> {
        [
            ParamStatus::Identified,
            ParamStatus::Dependent,
            ParamStatus::Fixed,
            ParamStatus::Held,
        ]
        .into_iter()
        .find(|v| v.as_str() == s)
    }
}

/// The parameters of one model.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterSet {
    pub model: ModelName,
    pub values: ParamValues,
    pub std_errors: [Option<f64>; PARAM_COUNT],
    pub status: [ParamStatus; PARAM_COUNT],
    /// Why a parameter is `held`, `fixed` or `dependent` (spec §8), where known.
    pub reasons: [Option<String>; PARAM_COUNT],
    /// Target ids, sorted, when the set has several targets; empty (or one) for
    /// a one-target set, whose translation is `x_t, y_t, z_t`.
    pub targets: Vec<String>,
}

impl ParameterSet {
    /// All parameters at `values`, none identified, one target.
    pub fn fixed(model: ModelName, values: ParamValues) -> Self {
        ParameterSet {
            model,
            values,
            std_errors: [None; PARAM_COUNT],
            status: [ParamStatus::Fixed; PARAM_COUNT],
            reasons: std::array::from_fn(|_| None),
            targets: Vec::new(),
        }
    }

    /// The parameters this set has: the 42, one translation per further
    /// target, and a seventh joint's, the joint-error, track and positioner
    /// terms it uses (any not `fixed` at zero).
    pub fn ids(&self) -> impl Iterator<Item = ParamId> + use<> {
        let used: Vec<ParamId> = ParamId::of_arm(crate::robot::MAX_JOINTS)
            .skip(crate::robot::BASE_PARAM_COUNT)
            .chain(ParamId::joint_terms())
            .chain(ParamId::track_terms(crate::robot::track::MAX_TRACK_ORDER))
            .chain(ParamId::positioner_terms(
                crate::robot::positioner::MAX_POSITIONER_AXES,
            ))
            .filter(|id| {
                self.status[id.index()] != ParamStatus::Fixed || self.values.get(*id) != 0.0
            })
            .collect();
        ParamId::all_with_targets(6, self.targets.len()).chain(used)
    }

    /// The table name of `id` in this set (`x_t[nest2]` with several targets).
    pub fn name_of(&self, id: ParamId) -> String {
        param_name(id, &self.targets)
    }

    /// The target index of each of `rows` rows from their target ids (`None`:
    /// the table has no `target_id` column): 0 for every row of a one-target
    /// set. An error names a row's id the set does not have, or says that a
    /// several-target set needs the column: aiming every row with one target's
    /// tool would put the others' predictions centimetres off (spec §8).
    pub fn target_indices(
        &self,
        row_targets: Option<&[Option<String>]>,
        rows: usize,
    ) -> Result<Vec<usize>, String> {
        let Some(row_targets) = row_targets else {
            if self.targets.len() > 1 {
                return Err(format!(
                    "the {} parameters have one tool per target ({}) but the table has no `target_id` column saying which target each row measured",
                    self.model,
                    self.targets.join(", ")
                ));
            }
            return Ok(vec![0; rows]);
        };
        if self.targets.len() <= 1 {
            // A one-target set names its target only when it was fitted with one.
            if let Some(only) = self.targets.first()
                && let Some((row, id)) = row_targets
                    .iter()
                    .enumerate()
                    .find(|(_, id)| id.as_deref().is_some_and(|id| id != only))
            {
                return Err(format!(
                    "row {row}: target `{}` has no tool translation in the {} set (it has {only})",
                    id.as_deref().unwrap_or_default(),
                    self.model
                ));
            }
            return Ok(vec![0; row_targets.len()]);
        }
        row_targets
            .iter()
            .enumerate()
            .map(|(row, id)| {
                let id = id.as_deref().unwrap_or_default();
                self.targets.iter().position(|t| t == id).ok_or_else(|| {
                    format!(
                        "row {row}: target `{id}` has no tool translation in the {} set (it has {})",
                        self.model,
                        self.targets.join(", ")
                    )
                })
            })
            .collect()
    }
}

/// The table name of `id` in a set of `targets` (sorted ids): `x_t[nest2]`
/// for a tool translation when there are several, the spec's name otherwise.
pub fn param_name(id: ParamId, targets: &[String]) -> String {
    match id.kind() {
        ParamKind::ToolTranslation { target, axis } if targets.len() > 1 => {
            format!("{}[{}]", TOOL_TRANSLATION_NAMES[axis], targets[target])
        }
        _ => id.name().to_string(),
    }
}
