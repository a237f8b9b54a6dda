//! The report's model ladder (issue #29): `crossvalidate`'s climb from the
//! simplest model up on the grouped folds, each rung's held-out mean, 99.7th
//! percentile and maximum, the paired tests against the rung chosen so far,
//! and which model was chosen.

use std::fmt::Write;

use super::{escape, mm};

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

/// The part under the held-out accuracy; nothing without the input.
pub fn render(out: &mut String, rows: Option<&[LadderRow]>) {
    let Some(rows) = rows.filter(|r| !r.is_empty()) else {
        return;
    };
    let chosen = rows
        .iter()
        .find(|r| r.chosen)
        .map_or("none", |r| r.model.as_str());
    let _ = write!(
        out,
        "<h3 id=\"ladder\">Model ladder</h3>\n<p>From the simplest model up, on the {} folds: \
         a richer model is chosen only when its held-out errors, row by row on the same folds, \
         are lower by the minimum gain, both paired tests say so and its 99.7th percentile is \
         not worse beyond that share. Chosen: <strong>{}</strong>.</p>\n\
         <div class=\"wide\"><table class=\"stats\">\n<thead>\n<tr><th>model</th>\
         <th class=\"num\">mean</th><th class=\"num\">p99.7</th><th class=\"num\">max</th>\
         <th>against</th><th class=\"num\">paired t p</th><th class=\"num\">Wilcoxon p</th>\
         <th>decision</th></tr>\n</thead>\n<tbody>\n",
        escape(&rows[0].protocol),
        escape(chosen)
    );
    let p = |p: Option<f64>| p.map_or_else(String::new, |p| format!("{p:.1e}"));
    for r in rows {
        let _ = writeln!(
            out,
            "<tr{}><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            if r.chosen { " class=\"chosen\"" } else { "" },
            escape(&r.model),
            mm(r.mean_mm),
            mm(r.p997_mm),
            mm(r.max_mm),
            escape(r.compared_with.as_deref().unwrap_or("")),
            p(r.paired_t_p),
            p(r.wilcoxon_p),
            escape(&if r.chosen {
                format!("chosen: {}", r.reason)
            } else {
                r.reason.clone()
            })
        );
    }
    out.push_str("</tbody>\n</table></div>\n");
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
        let mut out = String::new();
        render(
            &mut out,
            Some(&[
                row("elastogeometric", 0.1, false),
                row("eg_backlash", 0.04, true),
            ]),
        );
        assert!(
            out.contains("Chosen: <strong>eg_backlash</strong>"),
            "{out}"
        );
        assert!(out.contains("0.040") && out.contains("1.0e-9"), "{out}");
        assert!(out.contains("configuration folds"), "{out}");
        let mut empty = String::new();
        render(&mut empty, None);
        assert!(empty.is_empty());
    }
}
