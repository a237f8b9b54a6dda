//! The report's first screen: "is my calibration good?"
//!
//! One model — the one in service — is judged on the validation rows: the mean,
//! the 99.7th percentile and the maximum of its error norms, computed here from
//! the `errors` input (not taken from `stats`, which has no p99.7). Vendors are
//! judged on the maximum and on "3σ"; the error norm is not normal, so the
//! distribution-free 99.7th percentile stands for 3σ. The verdict is PASS when
//! the figure the job's `criterion` names (default: the maximum, the stricter
//! one, since p99.7 ≤ max) is at most `tolerance_mm`, FAIL otherwise, and no
//! verdict at all without a tolerance: what is good enough depends on the
//! application, and a default would answer a question the job did not ask.
//!
//! Below it, the warnings that qualify a PASS: parameters the identification
//! held at nominal (with their reasons), fits that did not converge and were
//! accepted, rows the identification left out, and targets whose joint command
//! is not `ok` (for instance `outside_envelope`). They do not change PASS or
//! FAIL, which is about the measured figures only; they say how far to trust
//! those figures beyond the validation rows.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::{ReportData, escape, mm};

/// Which figure is compared with the tolerance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Criterion {
    /// The largest validation error: no row beyond the tolerance.
    Max,
    /// The 99.7th percentile (the "3σ" of a vendor's datasheet): one row in
    /// about 333 may lie beyond the tolerance.
    P99_7,
}

impl Criterion {
    /// The setting's spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Criterion::Max => "max",
            Criterion::P99_7 => "p99_7",
        }
    }

    fn label(self) -> &'static str {
        match self {
            Criterion::Max => "max",
            Criterion::P99_7 => "p99.7",
        }
    }
}

/// What the job asked the verdict for (the report stage's settings).
#[derive(Debug, Clone, PartialEq)]
pub struct VerdictSettings {
    /// The model in service; `None`: [`default_model`].
    pub model: Option<String>,
    /// `None`: figures without a verdict.
    pub tolerance_mm: Option<f64>,
    pub criterion: Criterion,
}

impl Default for VerdictSettings {
    fn default() -> Self {
        VerdictSettings {
            model: None,
            tolerance_mm: None,
            criterion: Criterion::Max,
        }
    }
}

/// A row of a `commands` table, as far as the report reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandRow {
    pub target_id: i64,
    /// `ok`, or why not (`unreachable`, `joint_limit`, `singular`,
    /// `not_converged`, `outside_envelope`, ...).
    pub status: String,
    /// Spec §8; `None` where the table has no such column or the cell is null.
    pub envelope_distance: Option<f64>,
    pub u95_mm: Option<f64>,
}

/// Models in the order a default prefers them as the one in service: the most
/// complete calibration first. `reregistered` (a calibration carried to new
/// frames) comes before `registered` (the nominal robot with its frames fitted).
const SERVICE_ORDER: [&str; 5] = [
    "elastogeometric",
    "kinematic",
    "reregistered",
    "registered",
    "nominal",
];

/// The model the verdict judges when the job does not name one: the first of
/// [`SERVICE_ORDER`] with validation errors, else the first model with any.
/// Not the model with the smallest error: which model is in service is a
/// decision made before looking at the validation rows.
pub fn default_model(errors: &BTreeMap<String, Vec<f64>>) -> Option<String> {
    let has = |m: &str| errors.get(m).is_some_and(|v| !v.is_empty());
    SERVICE_ORDER
        .iter()
        .find(|m| has(m))
        .map(|m| m.to_string())
        .or_else(|| {
            errors
                .iter()
                .find(|(_, v)| !v.is_empty())
                .map(|(m, _)| m.clone())
        })
}

/// The model the verdict judges: the setting, or the default. An error (for
/// the stage to report) when the setting names a model without validation
/// errors, or when there are none at all.
pub fn model_in_service(
    errors: &BTreeMap<String, Vec<f64>>,
    setting: Option<&str>,
) -> Result<String, String> {
    let present = || {
        let names: Vec<&str> = errors
            .iter()
            .filter(|(_, v)| !v.is_empty())
            .map(|(m, _)| m.as_str())
            .collect();
        if names.is_empty() {
            "none".to_string()
        } else {
            names.join(", ")
        }
    };
    match setting {
        Some(m) if errors.get(m).is_some_and(|v| !v.is_empty()) => Ok(m.to_string()),
        Some(m) => Err(format!(
            "setting `model`: the errors table has no rows of model `{m}` (it has: {})",
            present()
        )),
        None => default_model(errors).ok_or_else(|| "the errors table has no rows".to_string()),
    }
}

/// The judged figures of one model's validation errors (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Figures {
    pub n: usize,
    pub mean: f64,
    pub p99_7: f64,
    pub max: f64,
}

impl Figures {
    /// `None` for no values (or a non-finite one, which the table checks exclude).
    pub fn of(values: &[f64]) -> Option<Figures> {
        let p99_7 = crate::stats::percentile(values, 0.997).ok()?;
        Some(Figures {
            n: values.len(),
            mean: values.iter().sum::<f64>() / values.len() as f64,
            p99_7,
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        })
    }

    fn judged(&self, criterion: Criterion) -> f64 {
        match criterion {
            Criterion::Max => self.max,
            Criterion::P99_7 => self.p99_7,
        }
    }
}

/// PASS, FAIL, or no verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Pass,
    Fail,
    /// The job set no `tolerance_mm`, or the model has no validation rows.
    NoVerdict,
}

/// A parameter held at nominal by the identification (status `held`).
#[derive(Debug, Clone, PartialEq)]
pub struct HeldParameter {
    pub model: String,
    pub name: String,
    pub reason: Option<String>,
}

/// What qualifies the verdict.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Warnings {
    /// Held parameters of the model in service.
    pub held: Vec<HeldParameter>,
    /// Held parameters of the other models (counted, not listed: they are in
    /// the parameters table).
    pub held_elsewhere: usize,
    /// `(model, text)` of each fit that did not converge and was accepted
    /// (`<model>_not_converged_accepted` in an input's provenance), any model.
    pub not_converged: Vec<(String, String)>,
    /// Rows the identification left out: `(row checks, robust exclusions of the
    /// model in service)`; `None` without an `excluded_rows` input.
    pub rows_left_out: Option<(usize, usize)>,
    /// Targets whose command is not `ok`; `None` without a `commands` input.
    pub targets_not_ok: Option<Vec<CommandRow>>,
    /// `ok` targets farther from the calibration rows than compensate's
    /// default envelope (a job that raised `max_envelope_distance_deg`).
    pub targets_beyond_default_envelope: Vec<CommandRow>,
    /// Rows of the `commands` input.
    pub targets: usize,
}

impl Warnings {
    /// How many warnings the list shows.
    pub fn count(&self) -> usize {
        usize::from(!self.held.is_empty())
            + self.not_converged.len()
            + usize::from(self.rows_left_out.is_some_and(|(c, r)| c + r > 0))
            + usize::from(self.targets_not_ok.as_ref().is_some_and(|t| !t.is_empty()))
            + usize::from(!self.targets_beyond_default_envelope.is_empty())
    }
}

/// The verdict on the model in service.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    pub model: String,
    /// Whether the job named the model (`model` setting) or the default chose it.
    pub model_from_setting: bool,
    /// `None` when the model has no validation errors (only when the page is
    /// rendered from data the stage did not check).
    pub figures: Option<Figures>,
    pub tolerance_mm: Option<f64>,
    pub criterion: Criterion,
    pub outcome: Outcome,
    pub warnings: Warnings,
}

/// Suffix of the fact identify writes for an accepted non-converged fit.
const NOT_CONVERGED_FACT: &str = "_not_converged_accepted";

/// The verdict of the page's data. Never fails: a model the errors lack gives
/// a verdict without figures (the stage refuses such a setting before).
pub fn verdict(data: &ReportData) -> Verdict {
    let settings = &data.verdict;
    let model = settings
        .model
        .clone()
        .or_else(|| default_model(&data.errors))
        .unwrap_or_else(|| "elastogeometric".to_string());
    let figures = data.errors.get(&model).and_then(|v| Figures::of(v));
    let outcome = match (settings.tolerance_mm, figures) {
        (Some(tolerance), Some(f)) if f.judged(settings.criterion) <= tolerance => Outcome::Pass,
        (Some(_), Some(_)) => Outcome::Fail,
        _ => Outcome::NoVerdict,
    };
    Verdict {
        warnings: warnings(data, &model),
        model,
        model_from_setting: settings.model.is_some(),
        figures,
        tolerance_mm: settings.tolerance_mm,
        criterion: settings.criterion,
        outcome,
    }
}

fn warnings(data: &ReportData, model: &str) -> Warnings {
    let held_rows = data.parameters.iter().filter(|p| p.status == "held");
    let (held, elsewhere): (Vec<_>, Vec<_>) = held_rows.partition(|p| p.model == model);
    // One fact per model, though several inputs may carry the same provenance.
    let mut not_converged: BTreeMap<String, String> = BTreeMap::new();
    for source in &data.sources {
        if let Ok(Some(provenance)) = &source.provenance {
            for (key, text) in &provenance.extra {
                if let Some(m) = key.strip_suffix(NOT_CONVERGED_FACT) {
                    not_converged
                        .entry(m.to_string())
                        .or_insert_with(|| text.clone());
                }
            }
        }
    }
    Warnings {
        held: held
            .into_iter()
            .map(|p| HeldParameter {
                model: p.model.clone(),
                name: p.name.clone(),
                reason: p.reason.clone(),
            })
            .collect(),
        held_elsewhere: elsewhere.len(),
        not_converged: not_converged.into_iter().collect(),
        rows_left_out: data.excluded_rows.as_ref().map(|rows| {
            let checks = rows.iter().filter(|r| r.model.is_none()).count();
            let robust = rows
                .iter()
                .filter(|r| r.model.as_deref() == Some(model))
                .count();
            (checks, robust)
        }),
        targets_not_ok: data
            .commands
            .as_ref()
            .map(|rows| rows.iter().filter(|r| r.status != "ok").cloned().collect()),
        targets_beyond_default_envelope: data
            .commands
            .iter()
            .flatten()
            .filter(|r| {
                r.status == "ok"
                    && r.envelope_distance.is_some_and(|d| {
                        d > crate::compensation::envelope::DEFAULT_MAX_DISTANCE_DEG
                    })
            })
            .cloned()
            .collect(),
        targets: data.commands.as_ref().map_or(0, Vec::len),
    }
}

/// Targets not `ok` listed one by one on the first screen; the rest are counted.
const TARGETS_LISTED: usize = 20;

/// The verdict block: outcome, figures, tolerance, then the warnings.
pub fn render(out: &mut String, v: &Verdict) {
    let (class, word) = match v.outcome {
        Outcome::Pass => ("pass", "PASS"),
        Outcome::Fail => ("fail", "FAIL"),
        Outcome::NoVerdict => ("none", "NO VERDICT"),
    };
    let chosen = if v.model_from_setting {
        "the report's setting <code>model</code>"
    } else {
        "the most complete calibration validated; setting <code>model</code> names another"
    };
    let _ = writeln!(
        out,
        "<div class=\"verdict {class}\">\n<p class=\"outcome\"><span class=\"badge\">{word}</span> \
         Model in service: <strong>{}</strong> ({chosen}).</p>",
        escape(&v.model)
    );
    let Some(f) = v.figures else {
        let _ = writeln!(
            out,
            "<p>The errors table has no validation rows of model <code>{}</code>, so there is nothing to judge.</p>\n</div>",
            escape(&v.model)
        );
        render_warnings(out, &v.warnings);
        return;
    };
    let judged = f.judged(v.criterion);
    let sentence = match (v.outcome, v.tolerance_mm) {
        (Outcome::Pass, Some(t)) => format!(
            "Its {} validation error, {} mm, is within the tolerance of {} mm.",
            v.criterion.label(),
            mm(judged),
            mm(t)
        ),
        (Outcome::Fail, Some(t)) => format!(
            "Its {} validation error, {} mm, exceeds the tolerance of {} mm.",
            v.criterion.label(),
            mm(judged),
            mm(t)
        ),
        _ => "No tolerance is set, so there is no PASS or FAIL: set the report's <code>tolerance_mm</code> \
              (and <code>criterion</code>, <code>max</code> or <code>p99_7</code>) to the accuracy the \
              application needs."
            .to_string(),
    };
    let _ = writeln!(out, "<p>{sentence}</p>");
    let mark = |c: Criterion| {
        if v.tolerance_mm.is_some() && c == v.criterion {
            " class=\"num judged\""
        } else {
            " class=\"num\""
        }
    };
    let _ = writeln!(
        out,
        "<table class=\"figures\">\n<thead><tr><th class=\"num\">validation rows</th><th class=\"num\">mean (mm)</th>\
         <th{}>p99.7 (mm)</th><th{}>max (mm)</th><th class=\"num\">tolerance (mm)</th><th>criterion</th></tr></thead>\n\
         <tbody><tr><td class=\"num\">{}</td><td class=\"num\">{}</td><td{}>{}</td><td{}>{}</td><td class=\"num\">{}</td><td>{}</td></tr></tbody>\n</table>",
        mark(Criterion::P99_7),
        mark(Criterion::Max),
        f.n,
        mm(f.mean),
        mark(Criterion::P99_7),
        mm(f.p99_7),
        mark(Criterion::Max),
        mm(f.max),
        v.tolerance_mm.map_or_else(|| "not set".to_string(), mm),
        if v.tolerance_mm.is_some() {
            v.criterion.as_str()
        } else {
            "—"
        },
    );
    let _ = write!(
        out,
        "<p class=\"note\">Error norm ‖predicted − measured‖ of each validation row (rows the calibration did not use). \
         p99.7: the 99.7th percentile (linear interpolation), the distribution-free counterpart of a datasheet's \"3σ\""
    );
    if f.n < 333 {
        out.push_str("; with fewer than 333 rows it lies between the two largest errors");
    }
    out.push_str(".</p>\n</div>\n");
    render_warnings(out, &v.warnings);
}

fn render_warnings(out: &mut String, w: &Warnings) {
    let count = w.count();
    let _ = writeln!(
        out,
        "<h3 id=\"warnings\">Warnings ({count})</h3>\n<p>They do not change PASS or FAIL, which is about the measured \
         rows; they say where the calibration is less certain than those rows suggest.</p>"
    );
    let mut items: Vec<String> = Vec::new();
    if !w.held.is_empty() {
        let list: Vec<String> = w
            .held
            .iter()
            .map(|h| {
                format!(
                    "<li><code>{}</code>: {}</li>",
                    escape(&h.name),
                    h.reason
                        .as_deref()
                        .map_or_else(|| "no reason recorded".to_string(), escape)
                )
            })
            .collect();
        items.push(format!(
            "{} parameter{} of <strong>{}</strong> held at nominal: the data did not determine {} \
             (<a href=\"#parameters\">parameters</a>).<ul>{}</ul>",
            w.held.len(),
            if w.held.len() == 1 { "" } else { "s" },
            escape(&w.held[0].model),
            if w.held.len() == 1 { "it" } else { "them" },
            list.join("")
        ));
    }
    for (model, text) in &w.not_converged {
        // identify's text starts with the model's name, said already.
        let text = text
            .strip_prefix(model.as_str())
            .and_then(|t| t.strip_prefix(": "))
            .unwrap_or(text);
        items.push(format!(
            "<strong>{}</strong>: the fit did not converge and was used anyway ({}); its parameters may fall short \
             of the best the data allow (<a href=\"#convergence\">convergence</a>).",
            escape(model),
            escape(text)
        ));
    }
    if let Some((checks, robust)) = w.rows_left_out
        && checks + robust > 0
    {
        items.push(format!(
            "Rows left out of the calibration: {checks} by the row checks (every model), {robust} by the robust fit \
             of this model (<a href=\"#excluded-rows\">rows left out</a>)."
        ));
    }
    if let Some(targets) = w.targets_not_ok.as_ref().filter(|t| !t.is_empty()) {
        let mut by_status: BTreeMap<&str, usize> = BTreeMap::new();
        for t in targets {
            *by_status.entry(t.status.as_str()).or_default() += 1;
        }
        let counts: Vec<String> = by_status
            .iter()
            .map(|(s, n)| format!("{n} {}", escape(s)))
            .collect();
        let mut item = format!(
            "{} of {} targets have a command whose status is not <code>ok</code> ({}): the validation figures above do \
             not vouch for them.",
            targets.len(),
            w.targets,
            counts.join(", ")
        );
        let with = |f: fn(&CommandRow) -> Option<f64>| targets.iter().any(|t| f(t).is_some());
        let (distance, u95) = (with(|t| t.envelope_distance), with(|t| t.u95_mm));
        item.push_str(
            "<table class=\"targets\">\n<thead><tr><th class=\"num\">target_id</th><th>status</th>",
        );
        if distance {
            item.push_str("<th class=\"num\">envelope_distance</th>");
        }
        if u95 {
            item.push_str("<th class=\"num\">u95 (mm)</th>");
        }
        item.push_str("</tr></thead>\n<tbody>\n");
        let cell = |v: Option<f64>| v.map_or_else(|| "—".to_string(), |v| format!("{v:.3}"));
        for t in targets.iter().take(TARGETS_LISTED) {
            let _ = write!(
                item,
                "<tr><td class=\"num\">{}</td><td>{}</td>",
                t.target_id,
                escape(&t.status)
            );
            if distance {
                let _ = write!(item, "<td class=\"num\">{}</td>", cell(t.envelope_distance));
            }
            if u95 {
                let _ = write!(item, "<td class=\"num\">{}</td>", cell(t.u95_mm));
            }
            item.push_str("</tr>\n");
        }
        item.push_str("</tbody>\n</table>");
        if targets.len() > TARGETS_LISTED {
            let _ = write!(
                item,
                "… and {} more (the commands table has them all).",
                targets.len() - TARGETS_LISTED
            );
        }
        items.push(item);
    }
    if !w.targets_beyond_default_envelope.is_empty() {
        let farthest = w
            .targets_beyond_default_envelope
            .iter()
            .filter_map(|t| t.envelope_distance)
            .fold(0.0, f64::max);
        items.push(format!(
            "{} of {} targets have an <code>ok</code> command more than {}° (compensate's default envelope) from the \
             nearest calibration row, up to {farthest:.1}°: the job raised <code>max_envelope_distance_deg</code>, but \
             no row was measured there, so the validation figures above do not vouch for them.",
            w.targets_beyond_default_envelope.len(),
            w.targets,
            crate::compensation::envelope::DEFAULT_MAX_DISTANCE_DEG
        ));
    }
    if items.is_empty() {
        out.push_str("<p class=\"clear\">None.</p>\n");
    } else {
        out.push_str("<ul class=\"warnings\">\n");
        for item in items {
            let _ = writeln!(out, "<li>{item}</li>");
        }
        out.push_str("</ul>\n");
    }
    // What was looked at, so "none" is not read as "all checked".
    let mut unchecked = Vec::new();
    if w.rows_left_out.is_none() {
        unchecked.push("rows left out (no <code>excluded_rows</code> input)");
    }
    if w.targets_not_ok.is_none() {
        unchecked.push("targets (no <code>commands</code> input)");
    }
    if w.held_elsewhere > 0 {
        let _ = writeln!(
            out,
            "<p class=\"note\">Other models hold {} parameter{} (see the parameters table).</p>",
            w.held_elsewhere,
            if w.held_elsewhere == 1 { "" } else { "s" }
        );
    }
    if !unchecked.is_empty() {
        let _ = writeln!(
            out,
            "<p class=\"note\">Not checked: {}.</p>",
            unchecked.join("; ")
        );
    }
}
