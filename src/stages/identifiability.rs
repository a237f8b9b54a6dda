//! `identifiability`: which of the 42 parameters the candidate conf-wrench rows can
//! identify, by rank analysis of the scaled identification Jacobian at nominal
//! (paper §III.D; see `calibration::rank` for the method and tolerance).

use polars::prelude::Column;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use super::{Stage, StageContext, StageError, StageInfo, StageOutputs, TableSlot, commanded_rows};
use crate::calibration::{rank, stream};
use crate::robot::{ParamId, ParamValues};
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
    code_version: 4,
    inputs: &[TableSlot {
        name: "candidates",
        schema: schema::conf_wrenches,
        required: true,
        meaning: "conf-wrench rows",
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
        let (_, rows) = commanded_rows(ctx, ctx.input("candidates")?)?;
        let candidates: Vec<ParamId> = ParamId::of_robot(ctx.robot.spec())
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
        let mut names = Vec::new();
        let mut units = Vec::new();
        let mut identifiable = Vec::new();
        let mut combined = Vec::new();
        for id in &candidates {
            names.push(id.name());
            units.push(id.unit());
            let partners = analysis.dependent.iter().find(|(d, _)| d == id);
            identifiable.push(partners.is_none());
            combined.push(
                partners
                    .map(|(_, with)| with.iter().map(|p| p.name()).collect::<Vec<_>>().join(", ")),
            );
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
