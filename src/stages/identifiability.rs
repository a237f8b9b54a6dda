//! `identifiability`: which of the 42 parameters the candidate conf-wrench rows can
//! identify, by rank analysis of the scaled identification Jacobian at nominal
//! (paper §III.D; see `calibration::rank` for the method and tolerance).
//! Candidates with several targets (the arm's SMR and a positioner's nests,
//! by `target_id`) add each further target's translation, named `x_t[ID]`.

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::target_slots::{aim_candidates, cell_parameters};
use super::{Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot, commanded_rows};
use crate::calibration::{rank, stream};
use crate::robot::ParamValues;
use crate::table::parameters::param_name;
use crate::table::{frame, schema};

pub struct IdentifiabilityStage;

/// Settings of `identifiability`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct IdentifiabilitySettings {
    /// A column is dependent when its part orthogonal to the kept columns is below
    /// this (columns scaled to unit norm); also the SVD rank threshold relative to σ_max.
    #[schemars(extend("exclusiveMinimum" = 0.0, "exclusiveMaximum" = 1.0))]
    pub rank_tolerance: f64,
    /// Analyse the kinematic model only (compliances excluded).
    pub kinematic_only: bool,
}

impl Default for IdentifiabilitySettings {
    fn default() -> Self {
        IdentifiabilitySettings {
            rank_tolerance: 1e-6,
            kinematic_only: false,
        }
    }
}

static INFO: StageInfo = StageInfo {
    kind: "identifiability",
    uses_cable_robot: false,
    updates_input: None,
    summary: "Rank analysis: which parameters the candidate rows can identify, and what dependent ones combine with",
    code_version: 5,
    inputs: &[TableSlot {
        name: "candidates",
        schema: schema::conf_wrenches,
        required: true,
        meaning: "conf-wrench rows; with `target_id`, each row's SMR (the arm's or a positioner's nest)",
    }],
    outputs: &[TableSlot {
        name: "identifiability",
        schema: schema::identifiability,
        required: true,
        meaning: "name, unit, identifiable, combined_with",
    }],
};

impl Stage for IdentifiabilityStage {
    type Settings = IdentifiabilitySettings;

    fn info(&self) -> &'static StageInfo {
        &INFO
    }

    fn run(
        &self,
        ctx: &StageContext,
        settings: &IdentifiabilitySettings,
    ) -> Result<StageOutputs, StageError> {
        let input = ctx.input("candidates")?;
        let (_, mut rows) = commanded_rows(ctx, input)?;
        let targets = aim_candidates(input, &mut rows)?;
        let candidates: Vec<_> = cell_parameters(ctx.robot.spec(), targets.count())
            .into_iter()
            .filter(|p| !(settings.kinematic_only && p.is_compliance()))
            .collect();
        let nominal = ParamValues::nominal(ctx.robot.spec());
        let analysis = rank::analyse(
            ctx.robot,
            &nominal,
            &rows,
            &candidates,
            settings.rank_tolerance,
            stream::CHUNK_ROWS,
        );
        let prismatic = ctx.robot.prismatic_joints();
        let mut names = Vec::new();
        let mut units = Vec::new();
        let mut identifiable = Vec::new();
        let mut combined = Vec::new();
        for id in &candidates {
            names.push(param_name(*id, &targets.ids));
            units.push(id.unit_on(&prismatic));
            let partners = analysis.dependent.iter().find(|(d, _)| d == id);
            identifiable.push(partners.is_none());
            combined.push(partners.map(|(_, with)| {
                with.iter()
                    .map(|p| param_name(*p, &targets.ids))
                    .collect::<Vec<_>>()
                    .join(", ")
            }));
        }
        let mut outputs = StageOutputs::default();
        outputs.tables.insert(
            "identifiability".into(),
            frame(vec![
                Column::new("name".into(), names),
                Column::new("unit".into(), units),
                Column::new("identifiable".into(), identifiable),
                Column::new("combined_with".into(), combined),
            ]),
        );
        // Condition number of the identifiable part: σ_max over the smallest kept σ.
        let largest = analysis.singular_values.first().copied().unwrap_or(0.0);
        let smallest_kept = analysis
            .singular_values
            .get(analysis.svd_rank.saturating_sub(1))
            .copied()
            .unwrap_or(0.0);
        outputs
            .facts
            .insert("candidates".into(), candidates.len().to_string());
        outputs.facts.insert(
            "identifiable".into(),
            analysis.independent.len().to_string(),
        );
        outputs
            .facts
            .insert("dependent".into(), analysis.dependent.len().to_string());
        outputs
            .facts
            .insert("svd_rank".into(), analysis.svd_rank.to_string());
        outputs
            .facts
            .insert("rank_tolerance".into(), settings.rank_tolerance.to_string());
        outputs.facts.insert(
            "condition_number".into(),
            format!("{:.3e}", largest / smallest_kept.max(f64::MIN_POSITIVE)),
        );
        if analysis.svd_rank != analysis.independent.len() {
            ctx.progress.note(&format!(
                "warning: sequential rank {} differs from SVD rank {} at tolerance {}",
                analysis.independent.len(),
                analysis.svd_rank,
                settings.rank_tolerance
            ));
        }
        Ok(outputs)
    }
}
