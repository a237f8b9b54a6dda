//! The report's held-out accuracy (issue #28): the `crossvalidate` stage's
//! pooled figures, random folds and grouped folds side by side, so the reader
//! sees how much of the validation accuracy survives away from the
//! calibration rows.

use std::collections::BTreeSet;
use std::fmt::Write;

use super::{escape, mm, ordered_models};

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

/// The part under the validation statistics; nothing without the input.
pub fn render(out: &mut String, rows: Option<&[HeldOutRow]>) {
    let Some(rows) = rows.filter(|r| !r.is_empty()) else {
        return;
    };
    // Random folds first: the figure the others are compared with.
    let mut protocols: Vec<&str> = rows
        .iter()
        .map(|r| r.protocol.as_str())
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    protocols.sort_by_key(|p| (*p != "random", *p));
    let models = ordered_models(rows.iter().map(|r| r.model.as_str()));
    out.push_str(
        "<h3 id=\"held-out\">Held-out accuracy</h3>\n<p>Each fold validated on a calibration \
         identified on the other folds (<code>crossvalidate</code>). Random folds validate near the \
         calibration rows; grouped folds leave whole regions, configurations, loads or times out, \
         as the robot meets them at work. Mean, 99.7th percentile and maximum error, mm.</p>\n\
         <div class=\"wide\"><table class=\"stats\">\n<thead>\n<tr><th>model</th>",
    );
    for p in &protocols {
        let _ = write!(out, "<th colspan=\"3\">{} folds</th>", escape(p));
    }
    out.push_str("</tr>\n<tr><th></th>");
    for _ in &protocols {
        out.push_str(
            "<th class=\"num\">mean</th><th class=\"num\">p99.7</th><th class=\"num\">max</th>",
        );
    }
    out.push_str("</tr>\n</thead>\n<tbody>\n");
    for model in &models {
        let _ = write!(out, "<tr><td>{}</td>", escape(model));
        for p in &protocols {
            match rows.iter().find(|r| &r.model == model && r.protocol == *p) {
                Some(r) => {
                    let _ = write!(
                        out,
                        "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>",
                        mm(r.mean_mm),
                        mm(r.p997_mm),
                        mm(r.max_mm)
                    );
                }
                None => out.push_str("<td></td><td></td><td></td>"),
            }
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</tbody>\n</table></div>\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_folds_come_first_beside_the_grouped_ones() {
        let row = |protocol: &str, mean_mm: f64| HeldOutRow {
            protocol: protocol.into(),
            model: "elastogeometric".into(),
            rows: 10,
            mean_mm,
            p997_mm: 2.0 * mean_mm,
            max_mm: 3.0 * mean_mm,
        };
        let mut out = String::new();
        render(
            &mut out,
            Some(&[row("configuration", 0.47), row("random", 0.43)]),
        );
        let random = out.find("random folds").unwrap();
        let grouped = out.find("configuration folds").unwrap();
        assert!(random < grouped, "{out}");
        assert!(out.contains("0.430") && out.contains("0.470"), "{out}");
        let mut empty = String::new();
        render(&mut empty, None);
        assert!(empty.is_empty());
    }
}
