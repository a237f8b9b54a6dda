//! The report's held-out accuracy (issue #28): the `crossvalidate` stage's
//! pooled figures, random folds and grouped folds side by side, so the reader
//! sees how much of the validation accuracy survives away from the
//! calibration rows.

use super::{mm, ordered_models};
use std::collections::BTreeSet;

/// A row of `crossvalidate`'s `stats` table.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutRow {
    pub protocol: String,
    pub model: String,
    pub rows: i64,
    pub mean_mm: f64,
    pub p997_mm: f64,
    pub max_mm: f64,
}

/// The held-out table as `held_out.html` lays it out.
pub(super) struct HeldOutView {
    /// Random folds first: the figure the others are compared with.
    pub protocols: Vec<String>,
    pub rows: Vec<HeldOutModel>,
}

/// One model's figures, one cell per protocol (`None`: not crossvalidated so).
pub(super) struct HeldOutModel {
    pub model: String,
    pub cells: Vec<Option<HeldOutFigures>>,
}

pub(super) struct HeldOutFigures {
    pub mean: String,
    pub p99_7: String,
    pub max: String,
}

/// The part under the validation statistics; `None` without rows.
pub(super) fn view(rows: &[HeldOutRow]) -> Option<HeldOutView> {
    if rows.is_empty() {
        return None;
    }
    let mut protocols: Vec<&str> = rows
        .iter()
        .map(|r| r.protocol.as_str())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    protocols.sort_by_key(|p| (*p != "random", *p));
    let models = ordered_models(rows.iter().map(|r| r.model.as_str()));
    Some(HeldOutView {
        rows: models
            .into_iter()
            .map(|model| HeldOutModel {
                cells: protocols
                    .iter()
                    .map(|p| {
                        rows.iter()
                            .find(|r| r.model == model && r.protocol == *p)
                            .map(|r| HeldOutFigures {
                                mean: mm(r.mean_mm),
                                p99_7: mm(r.p997_mm),
                                max: mm(r.max_mm),
                            })
                    })
                    .collect(),
                model,
            })
            .collect(),
        protocols: protocols.into_iter().map(str::to_string).collect(),
    })
}

/// An elasto-geometric row of `protocol` with a mean of `mean_mm` (and a
/// p99.7 and maximum of 2× and 3× it), for the report's tests.
#[cfg(test)]
pub(crate) fn test_row(protocol: &str, mean_mm: f64) -> HeldOutRow {
    HeldOutRow {
        protocol: protocol.into(),
        model: "elastogeometric".into(),
        rows: 10,
        mean_mm,
        p997_mm: 2.0 * mean_mm,
        max_mm: 3.0 * mean_mm,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_folds_come_first_beside_the_grouped_ones() {
        let row = test_row;
        let view = view(&[row("configuration", 0.47), row("random", 0.43)]).expect("rows");
        assert_eq!(view.protocols, ["random", "configuration"]);
        let figures = view.rows[0].cells.iter().flatten();
        let means: Vec<&str> = figures.map(|f| f.mean.as_str()).collect();
        assert_eq!(means, ["0.430", "0.470"]);
        assert!(super::view(&[]).is_none());
    }
}
