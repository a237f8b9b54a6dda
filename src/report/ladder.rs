//! The report's model ladder (issue #29): `crossvalidate`'s climb from the
//! simplest model up on the grouped folds, each rung's held-out mean, 99.7th
//! percentile and maximum, the paired tests against the rung chosen so far,
//! and which model was chosen.

use super::mm;

/// A row of `crossvalidate`'s `ladder` table.
#[derive(Debug, Clone, PartialEq)]
pub struct LadderRow {
    pub protocol: String,
    pub model: String,
    pub mean_mm: f64,
    pub p997_mm: f64,
    pub max_mm: f64,
    pub compared_with: Option<String>,
    pub paired_t_p: Option<f64>,
    pub wilcoxon_p: Option<f64>,
    pub chosen: bool,
    pub reason: String,
}

/// The ladder as `ladder.html` lays it out.
pub(super) struct LadderView {
    /// The folds the ladder climbed on.
    pub protocol: String,
    /// The model chosen, or `none`.
    pub chosen: String,
    pub rungs: Vec<RungView>,
}

pub(super) struct RungView {
    pub model: String,
    pub mean: String,
    pub p99_7: String,
    pub max: String,
    /// The rung compared with; empty for the first.
    pub compared_with: String,
    /// Empty where not tested.
    pub paired_t_p: String,
    pub wilcoxon_p: String,
    pub chosen: bool,
    pub reason: String,
}

/// The part under the held-out accuracy; `None` without rows.
pub(super) fn view(rows: &[LadderRow]) -> Option<LadderView> {
    let first = rows.first()?;
    let p = |p: Option<f64>| p.map_or_else(String::new, |p| format!("{p:.1e}"));
    Some(LadderView {
        protocol: first.protocol.clone(),
        chosen: rows
            .iter()
            .find(|r| r.chosen)
            .map_or("none", |r| r.model.as_str())
            .to_string(),
        rungs: rows
            .iter()
            .map(|r| RungView {
                model: r.model.clone(),
                mean: mm(r.mean_mm),
                p99_7: mm(r.p997_mm),
                max: mm(r.max_mm),
                compared_with: r.compared_with.clone().unwrap_or_default(),
                paired_t_p: p(r.paired_t_p),
                wilcoxon_p: p(r.wilcoxon_p),
                chosen: r.chosen,
                reason: r.reason.clone(),
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rung_and_the_choice_are_shown() {
        let row = |model: &str, mean_mm: f64, chosen: bool| LadderRow {
            protocol: "configuration".into(),
            model: model.into(),
            mean_mm,
            p997_mm: 2.0 * mean_mm,
            max_mm: 3.0 * mean_mm,
            compared_with: (model != "elastogeometric").then(|| "elastogeometric".into()),
            paired_t_p: Some(1e-9),
            wilcoxon_p: Some(2e-9),
            chosen,
            reason: "held-out mean".into(),
        };
        let view = view(&[
            row("elastogeometric", 0.1, false),
            row("eg_backlash", 0.04, true),
        ])
        .expect("rows");
        assert_eq!(view.chosen, "eg_backlash");
        assert_eq!(view.protocol, "configuration");
        assert_eq!(view.rungs[1].mean, "0.040");
        assert_eq!(view.rungs[0].paired_t_p, "1.0e-9");
        assert!(super::view(&[]).is_none());
    }
}
