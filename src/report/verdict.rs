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

use super::page::Heading;
use super::{ReportData, mm};

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

/// The verdict block as `verdict.html` lays it out.
pub(super) struct VerdictView {
    pub heading: Heading,
    /// CSS class of the block: `pass`, `fail` or `none`.
    pub class: &'static str,
    pub word: &'static str,
    pub model: String,
    pub model_from_setting: bool,
    /// `None`: the model has no validation rows.
    pub figures: Option<FiguresView>,
    pub warnings: WarningsView,
}

/// The judged figures, formatted.
pub(super) struct FiguresView {
    /// `None` without a tolerance.
    pub judgement: Option<Judgement>,
    pub rows: usize,
    pub mean: String,
    pub p99_7: String,
    pub max: String,
    /// CSS classes of the two judged columns: the one the criterion names is bold.
    pub p99_7_class: &'static str,
    pub max_class: &'static str,
    pub tolerance: String,
    pub criterion: &'static str,
    /// Fewer than 333 rows: p99.7 lies between the two largest errors.
    pub few_rows: bool,
}

/// The figure compared with the tolerance, and how it compares.
pub(super) struct Judgement {
    pub criterion: &'static str,
    pub value: String,
    pub tolerance: String,
    pub exceeds: bool,
}

/// The warnings, formatted; `count` is the number of items listed.
pub(super) struct WarningsView {
    pub count: usize,
    pub held: Option<HeldWarning>,
    pub not_converged: Vec<(String, String)>,
    /// `(row checks, robust exclusions)`, when any row was left out.
    pub rows_left_out: Option<(usize, usize)>,
    pub targets_not_ok: Option<TargetsWarning>,
    pub beyond_default_envelope: Option<EnvelopeWarning>,
    /// Rows of the `commands` input.
    pub targets: usize,
    pub held_elsewhere: usize,
    /// No `excluded_rows` input: said, so "none" is not read as "all checked".
    pub rows_unchecked: bool,
    /// No `commands` input.
    pub targets_unchecked: bool,
}

/// Held parameters of the model in service: `(name, reason)`.
pub(super) struct HeldWarning {
    pub model: String,
    pub parameters: Vec<(String, String)>,
}

/// Targets whose command is not `ok`.
pub(super) struct TargetsWarning {
    pub count: usize,
    /// `(status, count)` in status order.
    pub by_status: Vec<(String, usize)>,
    pub with_distance: bool,
    pub with_u95: bool,
    /// The first [`TARGETS_LISTED`].
    pub rows: Vec<TargetView>,
    /// Targets not listed.
    pub more: usize,
}

pub(super) struct TargetView {
    pub id: i64,
    pub status: String,
    pub distance: String,
    pub u95: String,
}

/// `ok` targets beyond compensate's default envelope.
pub(super) struct EnvelopeWarning {
    pub count: usize,
    pub limit_deg: String,
    pub farthest_deg: String,
}

/// The verdict's view: outcome, figures, tolerance, then the warnings.
pub(super) fn view(v: &Verdict, heading: Heading) -> VerdictView {
    let (class, word) = match v.outcome {
        Outcome::Pass => ("pass", "PASS"),
        Outcome::Fail => ("fail", "FAIL"),
        Outcome::NoVerdict => ("none", "NO VERDICT"),
    };
    let class_of = |c: Criterion| {
        if v.tolerance_mm.is_some() && c == v.criterion {
            "num judged"
        } else {
            "num"
        }
    };
    let figures = v.figures.map(|f| FiguresView {
        judgement: match (v.outcome, v.tolerance_mm) {
            (Outcome::Pass | Outcome::Fail, Some(t)) => Some(Judgement {
                criterion: v.criterion.label(),
                value: mm(f.judged(v.criterion)),
                tolerance: mm(t),
                exceeds: v.outcome == Outcome::Fail,
            }),
            _ => None,
        },
        rows: f.n,
        mean: mm(f.mean),
        p99_7: mm(f.p99_7),
        max: mm(f.max),
        p99_7_class: class_of(Criterion::P99_7),
        max_class: class_of(Criterion::Max),
        tolerance: v.tolerance_mm.map_or_else(|| "not set".to_string(), mm),
        criterion: if v.tolerance_mm.is_some() {
            v.criterion.as_str()
        } else {
            "—"
        },
        few_rows: f.n < 333,
    });
    VerdictView {
        heading,
        class,
        word,
        model: v.model.clone(),
        model_from_setting: v.model_from_setting,
        figures,
        warnings: warnings_view(&v.warnings),
    }
}

fn warnings_view(w: &Warnings) -> WarningsView {
    let held = w.held.first().map(|first| HeldWarning {
        model: first.model.clone(),
        parameters: w
            .held
            .iter()
            .map(|h| {
                (
                    h.name.clone(),
                    h.reason
                        .clone()
                        .unwrap_or_else(|| "no reason recorded".to_string()),
                )
            })
            .collect(),
    });
    let not_converged = w
        .not_converged
        .iter()
        .map(|(model, text)| {
            // identify's text starts with the model's name, said already.
            let text = text
                .strip_prefix(model.as_str())
                .and_then(|t| t.strip_prefix(": "))
                .unwrap_or(text);
            (model.clone(), text.to_string())
        })
        .collect();
    let targets_not_ok = w
        .targets_not_ok
        .as_ref()
        .filter(|t| !t.is_empty())
        .map(|targets| {
            let mut by_status: BTreeMap<&str, usize> = BTreeMap::new();
            for t in targets {
                *by_status.entry(t.status.as_str()).or_default() += 1;
            }
            let cell = |v: Option<f64>| v.map_or_else(|| "—".to_string(), |v| format!("{v:.3}"));
            TargetsWarning {
                count: targets.len(),
                by_status: by_status
                    .into_iter()
                    .map(|(s, n)| (s.to_string(), n))
                    .collect(),
                with_distance: targets.iter().any(|t| t.envelope_distance.is_some()),
                with_u95: targets.iter().any(|t| t.u95_mm.is_some()),
                rows: targets
                    .iter()
                    .take(TARGETS_LISTED)
                    .map(|t| TargetView {
                        id: t.target_id,
                        status: t.status.clone(),
                        distance: cell(t.envelope_distance),
                        u95: cell(t.u95_mm),
                    })
                    .collect(),
                more: targets.len().saturating_sub(TARGETS_LISTED),
            }
        });
    let beyond = &w.targets_beyond_default_envelope;
    WarningsView {
        count: w.count(),
        held,
        not_converged,
        rows_left_out: w.rows_left_out.filter(|(c, r)| c + r > 0),
        targets_not_ok,
        beyond_default_envelope: (!beyond.is_empty()).then(|| EnvelopeWarning {
            count: beyond.len(),
            limit_deg: crate::compensation::envelope::DEFAULT_MAX_DISTANCE_DEG.to_string(),
            farthest_deg: format!(
                "{:.1}",
                beyond
                    .iter()
                    .filter_map(|t| t.envelope_distance)
                    .fold(0.0, f64::max)
            ),
        }),
        targets: w.targets,
        held_elsewhere: w.held_elsewhere,
        rows_unchecked: w.rows_left_out.is_none(),
        targets_unchecked: w.targets_not_ok.is_none(),
    }
}
