//! The calibration report: one self-contained HTML page (inline CSS, inline SVG,
//! no scripts, nothing fetched) from plain data read by the `report` stage.
//!
//! Rendering is pure and deterministic: the same [`ReportData`] gives the same
//! bytes, so the runner's content-addressed cache holds. The only times in the
//! page are those recorded in the inputs' provenance.

pub mod held_out;
pub mod ladder;
pub mod plots;
pub mod verdict;

use std::collections::BTreeMap;
use std::fmt::Write as _;

use plotters::style::RGBColor;

use crate::robot::ParamId;
use crate::table::Provenance;
use plots::{Axes, HistogramSeries, LineSeries2, PosePoint};
pub use verdict::{CommandRow, Criterion, VerdictSettings};

/// One section of the report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Section {
    /// Anchor id.
    pub id: &'static str,
    pub heading: &'static str,
    /// The paper's table or figure it reproduces, appended to the heading only
    /// when the job reproduces the paper (`compare_with_paper`).
    pub paper: &'static str,
}

impl Section {
    /// The heading as the page shows it.
    pub fn title(&self, compare_with_paper: bool) -> String {
        if compare_with_paper && !self.paper.is_empty() {
            format!("{} ({})", self.heading, self.paper)
        } else {
            self.heading.to_string()
        }
    }
}

const fn section_of(id: &'static str, heading: &'static str, paper: &'static str) -> Section {
    Section { id, heading, paper }
}

/// The report's sections, in page order. The verdict comes first: it is what
/// the first screen answers ("is my calibration good?").
pub const SECTIONS: [Section; 11] = [
    section_of("verdict", "Verdict: is the calibration good?", ""),
    section_of(
        "errors",
        "Position errors on the validation rows",
        "Table III",
    ),
    section_of("histograms", "Error histograms", "Fig. 7"),
    section_of("poses", "Measurement poses", "Fig. 4"),
    section_of(
        "accuracy",
        "Accuracy map: predicted 95 % position uncertainty",
        "",
    ),
    section_of("iso9283", "ISO 9283 pose accuracy and repeatability", ""),
    section_of("parameters", "Identified parameters", ""),
    section_of("observability", "Observability of the DETMAX selection", ""),
    section_of("convergence", "Convergence of the identification", ""),
    section_of("tests", "Hypothesis tests", ""),
    section_of("provenance", "Provenance", ""),
];

/// One row of the paper's Table III: our model name, the paper's column, mean, std, max (mm).
pub struct PaperColumn {
    pub model: &'static str,
    pub column: &'static str,
    pub mean: f64,
    pub std: f64,
    pub max: f64,
}

/// The paper's Table III (825 validation rows).
pub const PAPER_TABLE_III: [PaperColumn; 3] = [
    PaperColumn {
        model: "nominal",
        column: "Nominal",
        mean: 2.486,
        std: 1.745,
        max: 5.954,
    },
    PaperColumn {
        model: "kinematic",
        column: "Kinematic calibration",
        mean: 0.943,
        std: 0.479,
        max: 2.571,
    },
    PaperColumn {
        model: "elastogeometric",
        column: "Elasto-geometrical calibration",
        mean: 0.264,
        std: 0.137,
        max: 0.960,
    },
];

/// Validation rows in the paper (875 candidates − 50 selected).
pub const PAPER_VALIDATION_ROWS: usize = 825;

/// How the DETMAX stage scales O1 (its `o1_scaling` fact), when the trace's
/// provenance does not say.
pub const DEFAULT_O1_SCALING: &str = "columns scaled to unit norm over all candidates, at nominal";

/// A row of the `stats` table.
#[derive(Debug, Clone, PartialEq)]
pub struct StatsRow {
    pub model: String,
    pub n: i64,
    pub mean: f64,
    pub std: f64,
    pub median: f64,
    pub rms: f64,
    pub p95: f64,
    pub max: f64,
}

/// A row of a `parameters` table.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamRow {
    pub model: String,
    pub name: String,
    pub unit: String,
    pub nominal: f64,
    pub value: f64,
    pub std_error: Option<f64>,
    pub status: String,
    /// Why it is `held`, `fixed` or `dependent` (spec §8); `None` where the
    /// table has no `reason` column or the cell is null.
    pub reason: Option<String>,
}

/// A row of the `tests` table.
#[derive(Debug, Clone, PartialEq)]
pub struct TestRow {
    pub model_a: String,
    pub model_b: String,
    pub test: String,
    pub statistic: f64,
    pub dof: Option<f64>,
    pub p_value: f64,
}

/// A row of the `poses` table: target point (base frame, mm) and tool angles (deg).
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    pub config_id: i64,
    pub target_mm: [f64; 3],
    /// alpha, beta, gamma: Rot(x)·Rot(y)·Rot(z) as the paper's eq. (4).
    pub tool_deg: [f64; 3],
}

impl Pose {
    /// The tool z axis (the SMR axis) in the base frame: third column of
    /// Rot(x, α)·Rot(y, β)·Rot(z, γ).
    pub fn tool_z(&self) -> [f64; 3] {
        let [a, b, _] = self.tool_deg.map(f64::to_radians);
        [b.sin(), -a.sin() * b.cos(), a.cos() * b.cos()]
    }
}

/// A row of the `observability` table.
#[derive(Debug, Clone, PartialEq)]
pub struct DetmaxStep {
    pub iteration: i64,
    pub added: Option<i64>,
    pub removed: Option<i64>,
    pub o1: f64,
}

/// A row of the `excluded_rows` table.
#[derive(Debug, Clone, PartialEq)]
pub struct ExcludedRow {
    pub cw_id: i64,
    /// `None`: a row check (every model).
    pub model: Option<String>,
    pub check: String,
    pub reason: String,
}

/// A row of an `accuracy_map` table (positions in the world frame, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct MapPoint {
    pub slice: i64,
    pub position_mm: [f64; 3],
    pub inside_box: bool,
    /// `None` where the point is not reachable.
    pub u95_mm: Option<f64>,
}

/// The accuracy map and the calibration positions it was built around.
#[derive(Debug, Clone, PartialEq)]
pub struct AccuracyMap {
    pub points: Vec<MapPoint>,
    /// World frame, mm; empty when the `calibration_positions` input is not bound.
    pub calibration_mm: Vec<[f64; 3]>,
}

/// A row of an `iso9283` table (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct IsoPoint {
    pub point: String,
    pub n: i64,
    pub ap_mm: f64,
    pub rp_mm: f64,
}

/// A row of an `iso9283_distances` table (mm).
#[derive(Debug, Clone, PartialEq)]
pub struct IsoDistance {
    pub from: String,
    pub to: String,
    pub n: i64,
    pub d_cmd_mm: f64,
    pub ad_mm: f64,
    pub rd_mm: f64,
}

/// One ISO 9283 test: its points and the distances between pairs of them.
#[derive(Debug, Clone, PartialEq)]
pub struct IsoTest {
    pub points: Vec<IsoPoint>,
    /// Empty when the distances input is not bound.
    pub distances: Vec<IsoDistance>,
}

/// Excluded rows listed one by one in the page; the rest are counted.
const EXCLUDED_LISTED: usize = 50;

/// A row of the `identification_trace` table.
#[derive(Debug, Clone, PartialEq)]
pub struct TraceRow {
    pub model: String,
    pub iteration: i64,
    pub rms_mm: f64,
    pub max_mm: f64,
    pub step_mm: f64,
}

/// Truth values of a simulated robot: one model of a parameters table.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    pub model: String,
    /// Parameter name → value.
    pub values: BTreeMap<String, f64>,
}

/// Where an input table came from.
#[derive(Debug, Clone, PartialEq)]
pub struct InputSource {
    /// The input slot (`stats`, `errors`, ...).
    pub input: String,
    /// The file, relative to the job's folder where possible.
    pub file: String,
    pub rows: usize,
    /// `table::content_hash` of the data.
    pub data_hash: String,
    /// The file's provenance: none when not written by egcal, or why it could not be read.
    pub provenance: Result<Option<Provenance>, String>,
}

/// Everything the report shows.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportData {
    pub title: String,
    /// What the first screen's verdict judges, and against what.
    pub verdict: VerdictSettings,
    /// Whether the job reproduces the paper (a simulated IRB 1600 campaign):
    /// only then are Table III, the figure numbers and the remarks on the
    /// truth's world frame shown. Real data are not the paper's robot.
    pub compare_with_paper: bool,
    /// The `commands` input (compensate), when bound: targets not `ok` are warnings.
    pub commands: Option<Vec<CommandRow>>,
    pub histogram_bins: usize,
    /// Which model of the truth table is the truth (a setting, shown in the page).
    pub truth_model: String,
    pub stats: Vec<StatsRow>,
    /// Error norms (mm) per model.
    pub errors: BTreeMap<String, Vec<f64>>,
    pub parameters: Vec<ParamRow>,
    pub tests: Option<Vec<TestRow>>,
    pub poses: Option<Vec<Pose>>,
    pub detmax_trace: Option<Vec<DetmaxStep>>,
    pub o1_scaling: String,
    pub identification_trace: Option<Vec<TraceRow>>,
    /// Rows the identification left out, when its `excluded_rows` is bound.
    pub excluded_rows: Option<Vec<ExcludedRow>>,
    /// Held-out figures per protocol and model, when `crossvalidation` is bound.
    pub held_out: Option<Vec<held_out::HeldOutRow>>,
    /// The model ladder of `crossvalidate`, when `ladder` is bound.
    pub ladder: Option<Vec<ladder::LadderRow>>,
    /// The predicted uncertainty over the workspace, when `accuracy_map` is bound.
    pub accuracy_map: Option<AccuracyMap>,
    /// The ISO 9283 test of the compensated commands, when `iso9283` is bound.
    pub iso9283: Option<IsoTest>,
    /// The same test run with the nominal commands, when `iso9283_baseline` is bound.
    pub iso9283_baseline: Option<IsoTest>,
    pub truth: Option<Truth>,
    pub sources: Vec<InputSource>,
}

/// HTML-escapes text for element content and quoted attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Canonical place of a model name (nominal, registered, kinematic,
/// elastogeometric), other names after them.
fn model_rank(model: &str) -> usize {
    ["nominal", "registered", "kinematic", "elastogeometric"]
        .iter()
        .position(|m| *m == model)
        .unwrap_or(4)
}

/// Distinct model names: known ones in canonical order, then the others in order of appearance.
pub(crate) fn ordered_models<'a>(names: impl IntoIterator<Item = &'a str>) -> Vec<String> {
    let mut seen: Vec<String> = Vec::new();
    for name in names {
        if !seen.iter().any(|s| s == name) {
            seen.push(name.to_string());
        }
    }
    // Stable sort keeps the appearance order among unknown names.
    seen.sort_by_key(|m| model_rank(m));
    seen
}

fn model_color(model: &str, index: usize) -> RGBColor {
    const OTHERS: [RGBColor; 6] = [
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
        RGBColor(214, 39, 40),
    ];
    match model {
        "nominal" => RGBColor(127, 127, 127),
        "registered" => RGBColor(255, 127, 14),
        "kinematic" => RGBColor(31, 119, 180),
        "elastogeometric" => RGBColor(44, 160, 44),
        _ => OTHERS[index % OTHERS.len()],
    }
}

fn colors(models: &[String]) -> BTreeMap<String, RGBColor> {
    models
        .iter()
        .enumerate()
        .map(|(i, m)| (m.clone(), model_color(m, i)))
        .collect()
}

pub(crate) fn mm(value: f64) -> String {
    format!("{value:.3}")
}

/// Two significant digits (standard errors).
fn sig2(value: f64) -> String {
    if value == 0.0 {
        return "0".into();
    }
    if value.abs() < 1e-6 {
        return format!("{value:.1e}");
    }
    let digits = (1 - value.abs().log10().floor() as i32).max(0) as usize;
    format!("{value:.digits$}")
}

/// A parameter value without a standard error: as the spec prints them (3
/// decimals), compliances (deg/(N·m), ~1e-4) with 5.
fn param_value(value: f64, unit: &str) -> String {
    if unit.contains('N') {
        format!("{value:.5}")
    } else {
        format!("{value:.3}")
    }
}

/// A value with its standard error: the value to the last digit of the
/// two-significant-digit standard error.
fn with_error(value: f64, se: Option<f64>, unit: &str) -> String {
    match se.filter(|s| *s > 0.0 && s.is_finite()) {
        Some(s) => {
            let digits = (1 - s.log10().floor() as i32).clamp(0, 12) as usize;
            format!("{value:.digits$} ± {}", sig2(s))
        }
        None => param_value(value, unit),
    }
}

fn p_value(p: f64) -> String {
    if p == 0.0 {
        // Below the smallest double: the test's tail underflowed.
        "&lt; 1e-300".into()
    } else if p < 1e-3 {
        format!("{p:.2e}")
    } else {
        format!("{p:.4}")
    }
}

fn note(out: &mut String, text: &str) {
    let _ = writeln!(out, "<p class=\"note\">{}</p>", escape(text));
}

/// Places a chart, or a note saying why it is missing.
fn figure(out: &mut String, chart: Result<String, String>, caption: &str) {
    match chart {
        Ok(svg) => {
            let _ = writeln!(
                out,
                "<figure>\n{svg}<figcaption>{}</figcaption>\n</figure>",
                escape(caption)
            );
        }
        Err(e) => note(out, &format!("The chart could not be drawn: {e}.")),
    }
}

const STYLE: &str = r#"
:root { --ink: #1d2330; --muted: #5b6474; --rule: #d5dae3; --band: #f4f6f9; --accent: #1f5aa6; }
* { box-sizing: border-box; }
body { margin: 0; color: var(--ink); background: #fff;
  font: 15px/1.5 "DejaVu Sans", "Helvetica Neue", Arial, sans-serif; }
main { max-width: 1240px; margin: 0 auto; padding: 24px 24px 48px; }
header { border-bottom: 3px solid var(--accent); margin-bottom: 18px; padding-bottom: 8px; }
h1 { font-size: 26px; margin: 0 0 4px; }
h2 { font-size: 20px; margin: 34px 0 10px; padding-bottom: 4px; border-bottom: 1px solid var(--rule); }
h3 { font-size: 16px; margin: 20px 0 6px; }
p { margin: 8px 0; max-width: 92ch; }
.meta { color: var(--muted); margin: 0; }
nav ol { columns: 2; margin: 8px 0 0; padding-left: 22px; }
nav a, a { color: var(--accent); }
table { border-collapse: collapse; margin: 10px 0 14px; font-size: 13px; }
th, td { border: 1px solid var(--rule); padding: 3px 7px; vertical-align: top; }
th { background: #e9edf3; text-align: left; font-weight: 600; }
tbody tr:nth-child(even) { background: var(--band); }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.paper, th.paper { background: #fbf6ea; }
td.none { color: var(--muted); text-align: center; }
td.mono, code { font-family: "DejaVu Sans Mono", Menlo, Consolas, monospace; font-size: 12px; }
td.mono { word-break: break-all; }
.identified { color: #19692c; }
.dependent { color: #9a6400; font-style: italic; }
.held { color: #b54708; font-weight: 600; }
div.verdict { border: 1px solid var(--rule); border-left: 10px solid #8a94a6; border-radius: 4px;
  padding: 8px 16px; margin: 10px 0 14px; background: var(--band); }
div.verdict.pass { border-left-color: #2e7d32; background: #edf7ee; }
div.verdict.fail { border-left-color: #b42318; background: #fdeeed; }
.outcome { font-size: 16px; margin: 4px 0 8px; }
.badge { display: inline-block; font-size: 24px; font-weight: 800; letter-spacing: 0.05em; color: #fff;
  background: #5b6474; padding: 2px 14px; border-radius: 4px; margin-right: 10px; vertical-align: middle; }
.pass .badge { background: #2e7d32; }
.fail .badge { background: #b42318; }
td.judged, th.judged { font-weight: 700; }
.fail td.judged { color: #b42318; }
ul.warnings > li { margin: 6px 0; }
ul.warnings li::marker { color: #b54708; }
.fixed { color: var(--muted); }
.flag { color: #b42318; font-weight: 600; }
.significant { font-weight: 700; }
.note { color: var(--muted); font-style: italic; }
figure { margin: 12px 0 18px; }
figcaption { color: var(--muted); font-size: 13px; margin-top: 4px; }
svg.chart { display: block; max-width: 100%; height: auto; border: 1px solid var(--rule); }
.grid { display: grid; grid-template-columns: repeat(auto-fit, minmax(460px, 1fr)); gap: 8px 18px; }
.grid figure { margin: 6px 0; }
.wide { overflow-x: auto; }
dl.prov { display: grid; grid-template-columns: max-content 1fr; gap: 2px 14px; margin: 6px 0 10px; font-size: 13px; }
dl.prov dt { color: var(--muted); }
dl.prov dd { margin: 0; word-break: break-all; }
footer { margin-top: 40px; color: var(--muted); font-size: 12px; border-top: 1px solid var(--rule); padding-top: 8px; }
"#;

/// Renders the whole page.
pub fn render(data: &ReportData) -> String {
    let mut out = String::with_capacity(256 * 1024);
    let title = escape(&data.title);
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <title>{title}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<main>\n<header>\n<h1>{title}</h1>\n"
    );
    let job = data.sources.iter().find_map(|s| {
        s.provenance
            .as_ref()
            .ok()
            .and_then(|p| p.as_ref())
            .map(|p| p.job.clone())
    });
    let stats_rows = data.stats.first().map_or(0, |s| s.n);
    let _ = writeln!(
        out,
        "<p class=\"meta\">{}Validation rows: {stats_rows}. Generated by egcal {}; this page needs no network and no scripts.</p>",
        job.map_or(String::new(), |j| format!(
            "Job <strong>{}</strong>. ",
            escape(&j)
        )),
        env!("CARGO_PKG_VERSION"),
    );
    out.push_str("</header>\n");
    let paper = data.compare_with_paper;
    // The verdict before the table of contents: the first screen answers "is
    // my calibration good?".
    section(&mut out, 0, paper);
    verdict::render(&mut out, &verdict::verdict(data));
    out.push_str("</section>\n<nav><ol>\n");
    for s in &SECTIONS {
        let _ = writeln!(
            out,
            "<li><a href=\"#{}\">{}</a></li>",
            s.id,
            escape(&s.title(paper))
        );
    }
    out.push_str("</ol></nav>\n");

    let models = ordered_models(
        data.stats
            .iter()
            .map(|s| s.model.as_str())
            .chain(data.errors.keys().map(String::as_str))
            .chain(data.parameters.iter().map(|p| p.model.as_str()))
            .chain(
                data.identification_trace
                    .iter()
                    .flatten()
                    .map(|t| t.model.as_str()),
            ),
    );
    let colors = colors(&models);

    section(&mut out, 1, paper);
    stats_section(&mut out, data);
    held_out::render(&mut out, data.held_out.as_deref());
    ladder::render(&mut out, data.ladder.as_deref());
    section(&mut out, 2, paper);
    histogram_section(&mut out, data, &models, &colors);
    section(&mut out, 3, paper);
    poses_section(&mut out, data);
    section(&mut out, 4, paper);
    accuracy_map_section(&mut out, data);
    section(&mut out, 5, paper);
    iso9283_section(&mut out, data);
    section(&mut out, 6, paper);
    parameters_section(&mut out, data);
    section(&mut out, 7, paper);
    detmax_section(&mut out, data);
    section(&mut out, 8, paper);
    convergence_section(&mut out, data, &models, &colors);
    excluded_rows_part(&mut out, data);
    section(&mut out, 9, paper);
    tests_section(&mut out, data);
    section(&mut out, 10, paper);
    provenance_section(&mut out, data);

    let _ = writeln!(
        out,
        "<footer>{title} — egcal {}. Self-contained HTML: inline CSS and SVG, no scripts.</footer>\n</main>\n</body>\n</html>",
        env!("CARGO_PKG_VERSION")
    );
    out
}

/// Opens section `index`, closing the one before it (the verdict's is closed
/// where the table of contents follows it).
fn section(out: &mut String, index: usize, compare_with_paper: bool) {
    let s = SECTIONS[index];
    if index > 1 {
        out.push_str("</section>\n");
    }
    let _ = writeln!(
        out,
        "<section id=\"{}\">\n<h2>{}. {}</h2>",
        s.id,
        index + 1,
        escape(&s.title(compare_with_paper))
    );
}

/// How far the truth's world frame is from nominal: largest angle (deg) and
/// largest translation (mm) difference, when the truth and the nominal values are known.
fn world_offset(data: &ReportData) -> Option<(f64, f64)> {
    let truth = data.truth.as_ref()?;
    let difference = |name: &str| {
        let nominal = data.parameters.iter().find(|p| p.name == name)?.nominal;
        Some((truth.values.get(name)? - nominal).abs())
    };
    let largest = |names: [&str; 3]| {
        names
            .iter()
            .map(|n| difference(n))
            .try_fold(0.0f64, |a, d| Some(a.max(d?)))
    };
    Some((
        largest(["alpha_w", "beta_w", "gamma_w"])?,
        largest(["x_w", "y_w", "z_w"])?,
    ))
}

/// What a model name means, as the guide defines the terms (docs/report.md); `None` for a
/// name egcal does not write.
fn model_meaning(model: &str) -> Option<&'static str> {
    Some(match model {
        "nominal" => "the robot file's model in the robot file's frames; nothing fitted",
        "registered" => {
            "the nominal robot with the world frame and the tool translation fitted: the fair \"before calibration\" figure"
        }
        "reregistered" => {
            "an existing calibration (the identify stage's input <code>start</code>) with only the world frame and the \
             tool translation refitted on these measurements"
        }
        "kinematic" => {
            "geometric calibration: the frames and the identifiable geometric parameters fitted, joint compliances at zero"
        }
        "elastogeometric" => {
            "elasto-geometric calibration: the geometric parameters and the joint compliances fitted"
        }
        _ => return None,
    })
}

fn stats_section(out: &mut String, data: &ReportData) {
    let paper = data.compare_with_paper;
    let stats: Vec<&StatsRow> = {
        let order = ordered_models(data.stats.iter().map(|s| s.model.as_str()));
        order
            .iter()
            .filter_map(|m| data.stats.iter().find(|s| &s.model == m))
            .collect()
    };
    if paper {
        let _ = writeln!(
            out,
            "<p>Statistics of the error norm ‖predicted − measured‖ per model on the validation rows, \
             beside the paper's Table III ({PAPER_VALIDATION_ROWS} validation rows; the paper gives mean, std and max only). All values in mm.</p>"
        );
        out.push_str(
            "<div class=\"wide\"><table class=\"stats\">\n<thead>\n<tr><th colspan=\"8\">This run</th>\
             <th class=\"paper\" colspan=\"4\">Paper, Table III</th></tr>\n",
        );
    } else {
        out.push_str(
            "<p>Statistics of the error norm ‖predicted − measured‖ per model on the validation rows (the rows the \
             calibration did not use). All values in mm.</p>\n<div class=\"wide\"><table class=\"stats\">\n<thead>\n",
        );
    }
    out.push_str(
        "<tr><th>model</th><th class=\"num\">n</th>\
         <th class=\"num\">mean</th><th class=\"num\">std</th><th class=\"num\">median</th><th class=\"num\">rms</th>\
         <th class=\"num\">p95</th><th class=\"num\">max</th>",
    );
    if paper {
        out.push_str(
            "<th class=\"paper\">column</th><th class=\"num paper\">mean</th>\
             <th class=\"num paper\">std</th><th class=\"num paper\">max</th>",
        );
    }
    out.push_str("</tr>\n</thead>\n<tbody>\n");
    for s in &stats {
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>\
             <td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>",
            escape(&s.model),
            s.n,
            mm(s.mean),
            mm(s.std),
            mm(s.median),
            mm(s.rms),
            mm(s.p95),
            mm(s.max)
        );
        if !paper {
            out.push_str("</tr>\n");
            continue;
        }
        match PAPER_TABLE_III.iter().find(|p| p.model == s.model) {
            Some(p) => {
                let _ = writeln!(
                    out,
                    "<td class=\"paper\">{}</td><td class=\"num paper\">{}</td><td class=\"num paper\">{}</td><td class=\"num paper\">{}</td></tr>",
                    escape(p.column),
                    mm(p.mean),
                    mm(p.std),
                    mm(p.max)
                );
            }
            None => out.push_str(
                "<td class=\"none paper\" colspan=\"4\">no counterpart in the paper</td></tr>\n",
            ),
        }
    }
    out.push_str("</tbody>\n</table></div>\n");
    let terms: Vec<String> = stats
        .iter()
        .filter_map(|s| {
            model_meaning(&s.model).map(|meaning| {
                format!("<li><strong>{}</strong>: {meaning}.</li>", escape(&s.model))
            })
        })
        .collect();
    if !terms.is_empty() {
        let _ = writeln!(out, "<ul class=\"terms\">\n{}\n</ul>", terms.join("\n"));
    }
    if paper {
        if stats.iter().any(|s| s.model == "nominal") {
            let offset = world_offset(data)
                .map(|(deg, mm)| {
                    format!("; this truth's world frame is off by up to {deg:.2}° and {mm:.2} mm")
                })
                .unwrap_or_default();
            let _ = writeln!(
                out,
                "<p>Here <strong>nominal</strong> is in the nominal world frame, so its error includes the \
                 world-frame error of the truth (spec §4{offset}): a fraction of a degree of world rotation is tens of \
                 millimetres at the tracker's distance. Hence <strong>registered</strong>, which has no column in the \
                 paper.</p>"
            );
        } else if stats.iter().any(|s| s.model == "registered") {
            out.push_str("<p><strong>registered</strong> has no column in the paper.</p>\n");
        }
    }
    let find = |m: &str| stats.iter().find(|s| s.model == m);
    if let (Some(k), Some(e)) = (find("kinematic"), find("elastogeometric"))
        && e.mean > 0.0
        && e.max > 0.0
    {
        let _ = write!(
            out,
            "<p>Elasto-geometric calibration divides the mean error of the kinematic calibration by {:.1} and its \
             maximum by {:.1}",
            k.mean / e.mean,
            k.max / e.max,
        );
        if paper {
            let _ = write!(
                out,
                " (paper: {:.1} and {:.1})",
                PAPER_TABLE_III[1].mean / PAPER_TABLE_III[2].mean,
                PAPER_TABLE_III[1].max / PAPER_TABLE_III[2].max
            );
        }
        out.push_str(".</p>\n");
    }
}

fn histogram_section(
    out: &mut String,
    data: &ReportData,
    models: &[String],
    colors: &BTreeMap<String, RGBColor>,
) {
    let bins = data.histogram_bins.max(1);
    let _ = writeln!(
        out,
        "<p>Counts of validation rows by error norm, {bins} equal bins from 0 to the largest error of the chart.</p>"
    );
    let with_errors: Vec<&String> = models
        .iter()
        .filter(|m| data.errors.get(*m).is_some_and(|v| !v.is_empty()))
        .collect();
    if with_errors.is_empty() {
        note(out, "The errors table has no rows.");
        return;
    }
    if let (Some(k), Some(e)) = (
        data.errors.get("kinematic"),
        data.errors.get("elastogeometric"),
    ) && !k.is_empty()
        && !e.is_empty()
    {
        let series = [
            HistogramSeries {
                name: "kinematic",
                color: colors["kinematic"],
                values: k,
            },
            HistogramSeries {
                name: "elastogeometric",
                color: colors["elastogeometric"],
                values: e,
            },
        ];
        figure(
            out,
            plots::histogram(
                "Position errors after kinematic and elasto-geometric calibration",
                &series,
                bins,
                (1000, 420),
            ),
            if data.compare_with_paper {
                "Overlaid on the same bins, as the paper's Fig. 7."
            } else {
                "Overlaid on the same bins."
            },
        );
    }
    out.push_str("<div class=\"grid\">\n");
    for model in with_errors {
        let values = &data.errors[model];
        let series = [HistogramSeries {
            name: model,
            color: colors[model],
            values,
        }];
        let title = format!("{model} ({} rows)", values.len());
        figure(
            out,
            plots::histogram(&title, &series, bins, (560, 320)),
            &format!("Model {model}."),
        );
    }
    out.push_str("</div>\n");
}

fn poses_section(out: &mut String, data: &ReportData) {
    let Some(poses) = data.poses.as_ref().filter(|p| !p.is_empty()) else {
        note(
            out,
            "No poses input is bound to this report stage, so the 3-D view of the poses is left out.",
        );
        return;
    };
    let points: Vec<PosePoint> = poses
        .iter()
        .map(|p| PosePoint {
            position: p.target_mm,
            axis: p.tool_z(),
        })
        .collect();
    let _ = writeln!(
        out,
        "<p>The {} target points of the SMR in the robot's base frame (equal scales on the three axes, base z \
         vertical), each with a short tick along the tool z axis, the direction the SMR faces (towards the tracker).</p>",
        poses.len()
    );
    figure(
        out,
        plots::poses_3d(
            &format!("{} poses, base frame", poses.len()),
            &points,
            (1000, 720),
        ),
        if data.compare_with_paper {
            "Target points and tool z axes, as the paper's Fig. 4."
        } else {
            "Target points and tool z axes."
        },
    );
}

/// The median of `values` (sorted in place); `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(values[n / 2]),
        _ => Some((values[n / 2 - 1] + values[n / 2]) / 2.0),
    }
}

/// One heat map per slice of the accuracy map, on a colour scale shared by
/// all slices, with the calibration positions of that slice's height band and
/// the box they span drawn over it.
fn accuracy_map_section(out: &mut String, data: &ReportData) {
    let Some(map) = data.accuracy_map.as_ref().filter(|m| !m.points.is_empty()) else {
        note(
            out,
            "No accuracy_map input is bound to this report stage, so the map of the predicted uncertainty is left out.",
        );
        return;
    };
    let mut slices: Vec<i64> = map.points.iter().map(|p| p.slice).collect();
    slices.sort_unstable();
    slices.dedup();
    let reachable: Vec<f64> = map.points.iter().filter_map(|p| p.u95_mm).collect();
    let value_range = reachable
        .iter()
        .fold((f64::INFINITY, 0.0_f64), |(lo, hi), v| {
            (lo.min(*v), hi.max(*v))
        });
    let value_range = if value_range.0.is_finite() {
        value_range
    } else {
        (0.0, 1.0)
    };
    let mut inside: Vec<f64> = map
        .points
        .iter()
        .filter(|p| p.inside_box)
        .filter_map(|p| p.u95_mm)
        .collect();
    let mut margin: Vec<f64> = map
        .points
        .iter()
        .filter(|p| !p.inside_box)
        .filter_map(|p| p.u95_mm)
        .collect();
    let summary = |values: &mut Vec<f64>| {
        median(values).map_or_else(
            || "no reachable point".to_string(),
            |m| format!("{} mm", mm(m)),
        )
    };
    let _ = writeln!(
        out,
        "<p>The radius u95 of the 95 % uncertainty of the predicted tool position (sqrt(χ²₃(0.95)·λ<sub>max</sub>) of \
         J·Σ·Jᵀ, the parameters' covariance propagated to the position, no measurement noise, no external wrench) \
         over a grid of {} points in {} horizontal slices of the world (tracker) frame. The grid spans the box of the \
         calibration rows' tool positions (white outline) and a margin around it, where the calibration extrapolates; \
         each point keeps the tool orientation of the nearest calibration pose. Grey cells: no configuration within \
         the joint limits ({} of {}). Median u95 inside the box: {}; in the margin: {}.</p>",
        map.points.len(),
        slices.len(),
        map.points.len() - reachable.len(),
        map.points.len(),
        summary(&mut inside),
        summary(&mut margin),
    );
    let box_of = |points: &mut dyn Iterator<Item = [f64; 3]>| {
        points.fold(None, |acc: Option<([f64; 3], [f64; 3])>, p| {
            Some(match acc {
                None => (p, p),
                Some((lo, hi)) => (
                    std::array::from_fn(|i| lo[i].min(p[i])),
                    std::array::from_fn(|i| hi[i].max(p[i])),
                ),
            })
        })
    };
    let calibration_box = box_of(&mut map.calibration_mm.iter().copied());
    out.push_str("<div class=\"grid\">\n");
    for slice in &slices {
        let points: Vec<&MapPoint> = map.points.iter().filter(|p| p.slice == *slice).collect();
        let z = points.first().map_or(0.0, |p| p.position_mm[2]);
        let spacing = |axis: usize| {
            let mut levels: Vec<f64> = points.iter().map(|p| p.position_mm[axis]).collect();
            levels.sort_by(f64::total_cmp);
            levels.dedup();
            levels
                .windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min)
        };
        let cell_mm = (spacing(0), spacing(1));
        let cell_mm = (
            if cell_mm.0.is_finite() {
                cell_mm.0
            } else {
                1.0
            },
            if cell_mm.1.is_finite() {
                cell_mm.1
            } else {
                1.0
            },
        );
        // Calibration positions within half a slice spacing of this slice's height.
        let mut heights: Vec<f64> = map.points.iter().map(|p| p.position_mm[2]).collect();
        heights.sort_by(f64::total_cmp);
        heights.dedup();
        let band = heights
            .windows(2)
            .map(|w| w[1] - w[0])
            .fold(f64::INFINITY, f64::min)
            / 2.0;
        let overlay: Vec<(f64, f64)> = map
            .calibration_mm
            .iter()
            .filter(|p| !band.is_finite() || (p[2] - z).abs() <= band)
            .map(|p| (p[0], p[1]))
            .collect();
        let outline = calibration_box
            .filter(|(lo, hi)| z >= lo[2] && z <= hi[2])
            .map(|(lo, hi)| ((lo[0], lo[1]), (hi[0], hi[1])));
        let cells: Vec<plots::HeatCell> = points
            .iter()
            .map(|p| plots::HeatCell {
                x: p.position_mm[0],
                y: p.position_mm[1],
                value: p.u95_mm,
            })
            .collect();
        let title = format!("u95 at z = {z:.0} mm");
        let chart = plots::heat_map(
            &plots::HeatMap {
                title: &title,
                x: "x (mm, world)",
                y: "y (mm, world)",
                value: "u95 (mm)",
                value_range,
                cell_mm,
                overlay: &overlay,
                outline,
            },
            &cells,
            (620, 520),
        );
        figure(
            out,
            chart,
            &format!(
                "Slice {} (z = {z:.0} mm): u95 per grid point, one colour scale for all slices; red dots: the {} \
                 calibration positions within {:.0} mm of this height.",
                slice + 1,
                overlay.len(),
                if band.is_finite() { band } else { 0.0 },
            ),
        );
    }
    out.push_str("</div>\n");
}

/// A cell of a value the baseline may lack: the value, or a dash.
fn optional_mm(value: Option<f64>) -> String {
    value.map_or_else(|| "—".to_string(), mm)
}

/// The ISO 9283 statistics per point and per pair of points, the compensated
/// commands beside the nominal ones when both tests are bound, so the gain of
/// compensation reads off one table.
fn iso9283_section(out: &mut String, data: &ReportData) {
    let Some(test) = data.iso9283.as_ref() else {
        note(
            out,
            "No iso9283 input is bound to this report stage, so the ISO 9283 statistics are left out.",
        );
        return;
    };
    let baseline = data.iso9283_baseline.as_ref();
    out.push_str(
        "<p>ISO 9283 pose accuracy AP (distance of the barycentre of the attained positions from the commanded one) \
         and repeatability RP (mean distance from the barycentre plus three standard deviations) per test point, \
         positions only, in the tracker frame",
    );
    out.push_str(if baseline.is_some() {
        "; <em>compensated</em>: the calibrated commands, <em>nominal</em>: the same targets commanded with the \
         robot file's model (the baseline test).</p>\n"
    } else {
        ".</p>\n"
    });
    let header = if baseline.is_some() {
        "<th class=\"num\">AP compensated (mm)</th><th class=\"num\">AP nominal (mm)</th>\
         <th class=\"num\">RP compensated (mm)</th><th class=\"num\">RP nominal (mm)</th>"
    } else {
        "<th class=\"num\">AP (mm)</th><th class=\"num\">RP (mm)</th>"
    };
    let _ = writeln!(
        out,
        "<table class=\"iso9283\">\n<thead><tr><th>point</th><th class=\"num\">n</th>{header}</tr></thead>\n<tbody>"
    );
    for p in &test.points {
        let base = baseline.and_then(|b| b.points.iter().find(|q| q.point == p.point));
        let values = match baseline {
            Some(_) => format!(
                "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>",
                mm(p.ap_mm),
                optional_mm(base.map(|b| b.ap_mm)),
                mm(p.rp_mm),
                optional_mm(base.map(|b| b.rp_mm)),
            ),
            None => format!(
                "<td class=\"num\">{}</td><td class=\"num\">{}</td>",
                mm(p.ap_mm),
                mm(p.rp_mm)
            ),
        };
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td class=\"num\">{}</td>{values}</tr>",
            escape(&p.point),
            p.n
        );
    }
    out.push_str("</tbody>\n</table>\n");
    if test.distances.is_empty() {
        return;
    }
    out.push_str(
        "<p>Distance accuracy AD (|mean attained distance − commanded distance|) and repeatability RD (three \
         standard deviations of the attained distance) between pairs of points.</p>\n",
    );
    let header = if baseline.is_some() {
        "<th class=\"num\">AD compensated (mm)</th><th class=\"num\">AD nominal (mm)</th>\
         <th class=\"num\">RD compensated (mm)</th><th class=\"num\">RD nominal (mm)</th>"
    } else {
        "<th class=\"num\">AD (mm)</th><th class=\"num\">RD (mm)</th>"
    };
    let _ = writeln!(
        out,
        "<table class=\"iso9283_distances\">\n<thead><tr><th>from</th><th>to</th><th class=\"num\">n</th>\
         <th class=\"num\">commanded (mm)</th>{header}</tr></thead>\n<tbody>"
    );
    for d in &test.distances {
        let base = baseline.and_then(|b| {
            b.distances
                .iter()
                .find(|e| e.from == d.from && e.to == d.to)
        });
        let values = match baseline {
            Some(_) => format!(
                "<td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>",
                mm(d.ad_mm),
                optional_mm(base.map(|b| b.ad_mm)),
                mm(d.rd_mm),
                optional_mm(base.map(|b| b.rd_mm)),
            ),
            None => format!(
                "<td class=\"num\">{}</td><td class=\"num\">{}</td>",
                mm(d.ad_mm),
                mm(d.rd_mm)
            ),
        };
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td>{values}</tr>",
            escape(&d.from),
            escape(&d.to),
            d.n,
            mm(d.d_cmd_mm)
        );
    }
    out.push_str("</tbody>\n</table>\n");
}

fn parameters_section(out: &mut String, data: &ReportData) {
    let all_models = ordered_models(data.parameters.iter().map(|p| p.model.as_str()));
    // A model with every parameter fixed at nominal (the `nominal` set) would
    // repeat the nominal column: listed, not tabulated.
    let at_nominal = |model: &str| {
        data.parameters
            .iter()
            .filter(|p| p.model == model)
            .all(|p| p.status == "fixed" && p.value == p.nominal)
    };
    let models: Vec<String> = all_models
        .iter()
        .filter(|m| !at_nominal(m))
        .cloned()
        .collect();
    let truth = data.truth.as_ref();
    // Names in the spec's order, then any others in order of appearance.
    let mut present: Vec<&str> = Vec::new();
    for name in data.parameters.iter().map(|p| p.name.as_str()).chain(
        truth
            .iter()
            .flat_map(|t| t.values.keys().map(String::as_str)),
    ) {
        if !present.contains(&name) {
            present.push(name);
        }
    }
    // The spec's order (a seventh joint's after the 42), a track's terms
    // after the arm's, then a positioner's.
    let mut names: Vec<&str> = ParamId::of_arm(crate::robot::MAX_JOINTS)
        .chain(ParamId::track_terms(crate::robot::track::MAX_TRACK_ORDER))
        .chain(ParamId::positioner_terms(
            crate::robot::positioner::MAX_POSITIONER_AXES,
        ))
        .map(|id| id.name())
        .filter(|n| present.contains(n))
        .collect();
    names.extend(present.iter().filter(|n| ParamId::from_name(n).is_none()));
    let rows: BTreeMap<(&str, &str), &ParamRow> = data
        .parameters
        .iter()
        .map(|p| ((p.model.as_str(), p.name.as_str()), p))
        .collect();
    let z_model = truth
        .map(|t| t.model.as_str())
        .filter(|m| models.iter().any(|x| x == m));

    out.push_str(
        "<p>One column per model with its value ± standard error, and its status: <span class=\"identified\">identified</span>, \
         <span class=\"dependent\">dependent</span> (not identifiable from these measurements, kept at nominal), \
         <span class=\"held\">held</span> (identifiable in principle but not determined by the data, kept at \
         nominal by egcal; the reasons are listed below the table) or <span class=\"fixed\">fixed</span> (not part \
         of the model, or fixed by the job).",
    );
    match truth {
        Some(t) => {
            let _ = write!(
                out,
                " The truth column is model <code>{}</code> of the truth table (the simulated robot).",
                escape(&t.model)
            );
            if let Some(m) = z_model {
                let _ = write!(
                    out,
                    " z = (value − truth) / standard error for <code>{}</code>; |z| &gt; 3 is flagged.",
                    escape(m)
                );
            }
        }
        None => out.push_str(" No truth input is bound, so there is no truth column."),
    }
    out.push_str("</p>\n<ul>\n");
    for model in &all_models {
        let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
        for p in data.parameters.iter().filter(|p| &p.model == model) {
            *counts.entry(p.status.as_str()).or_default() += 1;
        }
        let text: Vec<String> = counts
            .iter()
            .map(|(s, n)| format!("{n} {}", escape(s)))
            .collect();
        let _ = write!(
            out,
            "<li><strong>{}</strong>: {}",
            escape(model),
            text.join(", ")
        );
        if at_nominal(model) {
            out.push_str(", all at nominal (not repeated in the table)");
        }
        if let (Some(t), Some(m)) = (truth, z_model)
            && m == model
        {
            let z: Vec<f64> = data
                .parameters
                .iter()
                .filter(|p| &p.model == model && p.status == "identified")
                .filter_map(|p| {
                    Some((p.value - t.values.get(&p.name)?) / p.std_error.filter(|s| *s > 0.0)?)
                })
                .collect();
            if !z.is_empty() {
                let rms = (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt();
                let worst = z.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                let _ = write!(
                    out,
                    "; against the truth over {} identified parameters: rms z {rms:.2}, largest |z| {worst:.2} \
                     (rms z near 1 when the standard errors are honest)",
                    z.len()
                );
            }
        }
        out.push_str("</li>\n");
    }
    out.push_str("</ul>\n<div class=\"wide\"><table class=\"parameters\">\n<thead>\n<tr><th>name</th><th>unit</th><th class=\"num\">nominal</th>");
    for model in &models {
        let _ = write!(
            out,
            "<th class=\"num\">{}</th><th>status</th>",
            escape(model)
        );
    }
    if truth.is_some() {
        out.push_str("<th class=\"num\">truth</th>");
    }
    if let Some(m) = z_model {
        let _ = write!(out, "<th class=\"num\">z ({})</th>", escape(m));
    }
    out.push_str("</tr>\n</thead>\n<tbody>\n");
    for name in &names {
        let first = data.parameters.iter().find(|p| &p.name == name);
        let unit = first.map_or_else(
            || {
                ParamId::from_name(name)
                    .map_or("", |id| id.unit())
                    .to_string()
            },
            |p| p.unit.clone(),
        );
        let nominal = first.map(|p| p.nominal);
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td class=\"num\">{}</td>",
            escape(name),
            escape(&unit),
            nominal.map_or("—".into(), |v| param_value(v, &unit))
        );
        for model in &models {
            match rows.get(&(model.as_str(), *name)) {
                Some(p) => {
                    let class = match p.status.as_str() {
                        "identified" | "dependent" | "fixed" | "held" => p.status.as_str(),
                        _ => "",
                    };
                    // The reason as a tooltip; held ones are listed below the table too.
                    let title = p
                        .reason
                        .as_deref()
                        .map_or_else(String::new, |r| format!(" title=\"{}\"", escape(r)));
                    let _ = write!(
                        out,
                        "<td class=\"num {class}\">{}</td><td class=\"{class}\"{title}>{}</td>",
                        with_error(p.value, p.std_error, &unit),
                        escape(&p.status)
                    );
                }
                None => out.push_str("<td class=\"none\">—</td><td class=\"none\">—</td>"),
            }
        }
        if let Some(t) = truth {
            let _ = write!(
                out,
                "<td class=\"num\">{}</td>",
                t.values
                    .get(*name)
                    .map_or("—".into(), |v| param_value(*v, &unit))
            );
        }
        if let (Some(t), Some(m)) = (truth, z_model) {
            let z = rows
                .get(&(m, *name))
                .filter(|p| p.status == "identified")
                .and_then(|p| {
                    Some((p.value - t.values.get(*name)?) / p.std_error.filter(|s| *s > 0.0)?)
                });
            match z {
                Some(z) if z.abs() > 3.0 => {
                    let _ = write!(out, "<td class=\"num flag\">{z:+.2}</td>");
                }
                Some(z) => {
                    let _ = write!(out, "<td class=\"num\">{z:+.2}</td>");
                }
                None => out.push_str("<td class=\"none\">—</td>"),
            }
        }
        out.push_str("</tr>\n");
    }
    out.push_str("</tbody>\n</table></div>\n");
    let held: Vec<&ParamRow> = all_models
        .iter()
        .flat_map(|m| {
            data.parameters
                .iter()
                .filter(move |p| &p.model == m && p.status == "held")
        })
        .collect();
    if !held.is_empty() {
        out.push_str("<h3 id=\"held\">Held parameters</h3>\n<table class=\"held\">\n<thead><tr><th>model</th><th>name</th><th>reason</th></tr></thead>\n<tbody>\n");
        for p in held {
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
                escape(&p.model),
                escape(&p.name),
                p.reason
                    .as_deref()
                    .map_or_else(|| "no reason recorded".to_string(), escape)
            );
        }
        out.push_str("</tbody>\n</table>\n");
    }
}

fn detmax_section(out: &mut String, data: &ReportData) {
    let Some(trace) = data.detmax_trace.as_ref().filter(|t| !t.is_empty()) else {
        note(
            out,
            "No observability input is bound to this report stage, so the observability trace is left out.",
        );
        return;
    };
    let start = trace.iter().find(|s| s.iteration == 0).unwrap_or(&trace[0]);
    let last = trace
        .iter()
        .max_by_key(|s| s.iteration)
        .unwrap_or(&trace[0]);
    let exchanges = trace
        .iter()
        .filter(|s| s.added.is_some() || s.removed.is_some())
        .count();
    let _ = writeln!(
        out,
        "<p>Observability index O1 = (σ<sub>1</sub>·…·σ<sub>m</sub>)<sup>1/m</sup>/√n of the selected rows after each \
         DETMAX exchange (iteration 0 is the random start), spec §5. O1 scaling: {}. O1 went from {} at the random \
         start to {} after {exchanges} exchange{}.</p>",
        escape(&data.o1_scaling),
        plots::short(start.o1),
        plots::short(last.o1),
        if exchanges == 1 { "" } else { "s" }
    );
    let series = [LineSeries2 {
        name: "O1",
        color: RGBColor(31, 90, 170),
        points: trace.iter().map(|s| (s.iteration, s.o1)).collect(),
    }];
    let axes = Axes {
        title: "O1 per DETMAX exchange",
        x: "exchange",
        y: "O1",
    };
    figure(
        out,
        plots::line_chart(&axes, &series, (1000, 380)),
        &format!("O1 ({}).", data.o1_scaling),
    );
}

fn convergence_section(
    out: &mut String,
    data: &ReportData,
    models: &[String],
    colors: &BTreeMap<String, RGBColor>,
) {
    let Some(trace) = data.identification_trace.as_ref().filter(|t| !t.is_empty()) else {
        note(
            out,
            "No identification_trace input is bound to this report stage, so the convergence trace is left out.",
        );
        return;
    };
    out.push_str(
        "<p>Residual RMS per coordinate before each step of the fit (Levenberg–Marquardt by default, or undamped \
         Gauss–Newton), per identified model (log scale).</p>\n",
    );
    let traced: Vec<&String> = models
        .iter()
        .filter(|m| trace.iter().any(|t| &t.model == *m))
        .collect();
    let series: Vec<LineSeries2> = traced
        .iter()
        .map(|m| {
            let mut rows: Vec<&TraceRow> = trace.iter().filter(|t| &t.model == *m).collect();
            rows.sort_by_key(|t| t.iteration);
            LineSeries2 {
                name: m.as_str(),
                color: colors[m.as_str()],
                points: rows.iter().map(|t| (t.iteration, t.rms_mm)).collect(),
            }
        })
        .collect();
    let axes = Axes {
        title: "Identification convergence",
        x: "iteration",
        y: "residual rms (mm)",
    };
    figure(
        out,
        plots::log_line_chart(&axes, &series, (1000, 400)),
        "rms_mm per iteration, per model.",
    );
    out.push_str(
        "<table>\n<thead><tr><th>model</th><th class=\"num\">iterations</th><th class=\"num\">first rms (mm)</th>\
         <th class=\"num\">last rms (mm)</th><th class=\"num\">last max (mm)</th><th class=\"num\">last step (mm)</th></tr></thead>\n<tbody>\n",
    );
    for m in traced {
        let mut rows: Vec<&TraceRow> = trace.iter().filter(|t| &t.model == m).collect();
        rows.sort_by_key(|t| t.iteration);
        let (first, last) = (rows[0], rows[rows.len() - 1]);
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>",
            escape(m),
            rows.len(),
            plots::short(first.rms_mm),
            plots::short(last.rms_mm),
            plots::short(last.max_mm),
            plots::short(last.step_mm)
        );
    }
    out.push_str("</tbody>\n</table>\n");
}

/// The rows the identification did not use and why (row checks, robust fit).
fn excluded_rows_part(out: &mut String, data: &ReportData) {
    out.push_str("<h3 id=\"excluded-rows\">Rows left out</h3>\n");
    let Some(rows) = data.excluded_rows.as_ref() else {
        note(
            out,
            "No excluded_rows input is bound to this report stage, so the rows the identification left out are not listed.",
        );
        return;
    };
    if rows.is_empty() {
        out.push_str("<p>Every calibration row was used: none failed the row checks and the robust fit excluded none.</p>\n");
        return;
    }
    let checks = rows.iter().filter(|r| r.model.is_none()).count();
    let _ = writeln!(
        out,
        "<p>{checks} rows failed the row checks (joint limits, absurd values) and were left out of every model; \
         {} exclusions by the robust fit (rows beyond its threshold, per model).</p>",
        rows.len() - checks
    );
    out.push_str("<table class=\"excluded\">\n<thead><tr><th class=\"num\">cw_id</th><th>model</th><th>check</th><th>reason</th></tr></thead>\n<tbody>\n");
    for row in rows.iter().take(EXCLUDED_LISTED) {
        let _ = writeln!(
            out,
            "<tr><td class=\"num\">{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            row.cw_id,
            escape(row.model.as_deref().unwrap_or("all")),
            escape(&row.check),
            escape(&row.reason)
        );
    }
    out.push_str("</tbody>\n</table>\n");
    if rows.len() > EXCLUDED_LISTED {
        let _ = writeln!(
            out,
            "<p>… and {} more (the excluded_rows table has them all).</p>",
            rows.len() - EXCLUDED_LISTED
        );
    }
}

fn tests_section(out: &mut String, data: &ReportData) {
    let Some(tests) = data.tests.as_ref() else {
        note(out, "No tests input is bound to this report stage.");
        return;
    };
    out.push_str(if data.compare_with_paper {
        "<p>Two-sided tests of equal error norms between each pair of models on the same validation rows. The paper \
         used Student's t between kinematic and elasto-geometrical calibration (p &lt; 0.05); error norms are not \
         normal, so the Wilcoxon signed-rank test is given too. p &lt; 0.05 in bold.</p>\n"
    } else {
        "<p>Two-sided tests of equal error norms between each pair of models on the same validation rows: t tests \
         and, since error norms are not normal, the Wilcoxon signed-rank test. p &lt; 0.05 in bold.</p>\n"
    });
    if tests.is_empty() {
        note(out, "The tests table has no rows.");
        return;
    }
    out.push_str(
        "<table class=\"tests\">\n<thead><tr><th>model_a</th><th>model_b</th><th>test</th><th class=\"num\">statistic</th>\
         <th class=\"num\">dof</th><th class=\"num\">p_value</th></tr></thead>\n<tbody>\n",
    );
    for t in tests {
        let class = if t.p_value < 0.05 {
            "num significant"
        } else {
            "num"
        };
        let _ = writeln!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td class=\"num\">{:.4}</td><td class=\"num\">{}</td><td class=\"{class}\">{}</td></tr>",
            escape(&t.model_a),
            escape(&t.model_b),
            escape(&t.test),
            t.statistic,
            t.dof.map_or("—".into(), |d| format!("{d:.1}")),
            p_value(t.p_value)
        );
    }
    out.push_str("</tbody>\n</table>\n");
}

fn provenance_section(out: &mut String, data: &ReportData) {
    let _ = writeln!(
        out,
        "<p>Where each input table came from, as recorded in its Parquet footer when this page was rendered. The \
         report is cached by the content of its inputs: an upstream re-run that reproduces identical tables does not \
         re-render it. Report settings: histogram_bins = {}, truth_model = <code>{}</code>, model = {}, tolerance_mm = {}, \
         criterion = <code>{}</code>, compare_with_paper = {}.</p>",
        data.histogram_bins,
        escape(&data.truth_model),
        data.verdict.model.as_deref().map_or_else(
            || "not set".to_string(),
            |m| format!("<code>{}</code>", escape(m))
        ),
        data.verdict
            .tolerance_mm
            .map_or_else(|| "not set".to_string(), |t| t.to_string()),
        data.verdict.criterion.as_str(),
        data.compare_with_paper
    );
    // Inputs written by the same stage run share one provenance: shown once.
    let mut groups: Vec<Vec<&InputSource>> = Vec::new();
    for source in &data.sources {
        let same = groups.iter_mut().find(|g| {
            matches!((&g[0].provenance, &source.provenance), (Ok(Some(a)), Ok(Some(b))) if a == b)
        });
        match same {
            Some(group) => group.push(source),
            None => groups.push(vec![source]),
        }
    }
    for group in groups {
        let names: Vec<String> = group.iter().map(|s| escape(&s.input)).collect();
        let from = match &group[0].provenance {
            Ok(Some(p)) => format!(" — from stage {}", escape(&p.stage_id)),
            _ => String::new(),
        };
        let _ = writeln!(
            out,
            "<h3>{}{from}</h3>\n<dl class=\"prov\">",
            names.join(", ")
        );
        let mut item = |key: &str, value: String| {
            let _ = writeln!(out, "<dt>{}</dt><dd>{value}</dd>", escape(key));
        };
        for source in &group {
            item(
                &source.input,
                format!(
                    "<code>{}</code>, {} rows, data hash <code>{}</code>",
                    escape(&source.file),
                    source.rows,
                    escape(&source.data_hash)
                ),
            );
        }
        match &group[0].provenance {
            Ok(Some(p)) => {
                item("job", escape(&p.job));
                item("stage id", escape(&p.stage_id));
                item("stage kind", escape(&p.stage_kind));
                item(
                    "cache key",
                    format!("<code>{}</code>", escape(&p.cache_key)),
                );
                let hashes: Vec<String> = p
                    .input_hashes
                    .iter()
                    .map(|(k, v)| format!("{}: <code>{}</code>", escape(k), escape(v)))
                    .collect();
                item(
                    "input hashes",
                    if hashes.is_empty() {
                        "none".into()
                    } else {
                        hashes.join("<br>")
                    },
                );
                item("tool version", escape(&p.tool_version));
                item("created at", escape(&p.created_at));
                if !p.extra.is_empty() {
                    let facts: Vec<String> = p
                        .extra
                        .iter()
                        .map(|(k, v)| format!("{} = {}", escape(k), escape(v)))
                        .collect();
                    item("facts", facts.join("<br>"));
                }
            }
            Ok(None) => item(
                "provenance",
                "<span class=\"note\">none recorded (not written by egcal)</span>".into(),
            ),
            Err(e) => item(
                "provenance",
                format!(
                    "<span class=\"note\">could not be read: {}</span>",
                    escape(e)
                ),
            ),
        }
        out.push_str("</dl>\n");
    }
    out.push_str("</section>\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats_row(model: &str, scale: f64) -> StatsRow {
        StatsRow {
            model: model.into(),
            n: 6,
            mean: 1.0 * scale,
            std: 0.5 * scale,
            median: 0.9 * scale,
            rms: 1.1 * scale,
            p95: 1.9 * scale,
            max: 2.0 * scale,
        }
    }

    fn param(
        model: &str,
        name: &str,
        unit: &str,
        value: f64,
        se: Option<f64>,
        status: &str,
    ) -> ParamRow {
        ParamRow {
            model: model.into(),
            name: name.into(),
            unit: unit.into(),
            nominal: 1.0,
            value,
            std_error: se,
            status: status.into(),
            reason: None,
        }
    }

    /// Small synthetic data with every optional input, and a model name with markup in it.
    fn sample() -> ReportData {
        let odd = "odd<model>&";
        let models = ["nominal", "registered", "kinematic", "elastogeometric", odd];
        let scales = [10.0, 2.0, 1.0, 0.2, 0.5];
        let stats = models
            .iter()
            .zip(scales)
            .map(|(m, s)| stats_row(m, s))
            .collect();
        let errors = models
            .iter()
            .zip(scales)
            .map(|(m, s)| {
                (
                    m.to_string(),
                    (0..6).map(|k| s * (0.5 + 0.3 * k as f64)).collect(),
                )
            })
            .collect();
        // The nominal set as identify writes it: everything fixed at nominal.
        let mut parameters = vec![
            param("nominal", "x_w", "mm", 1.0, None, "fixed"),
            param("nominal", "k2", "deg/(N·m)", 1.0, None, "fixed"),
            param("nominal", "dd3", "mm", 1.0, None, "fixed"),
        ];
        for m in ["kinematic", "elastogeometric"] {
            parameters.push(param(m, "x_w", "mm", 1.2, Some(0.01), "identified"));
            parameters.push(param(
                m,
                "k2",
                "deg/(N·m)",
                0.00019,
                Some(0.00001),
                "identified",
            ));
            parameters.push(param(m, "dd3", "mm", 1.0, None, "dependent"));
        }
        let truth = Truth {
            model: "elastogeometric".into(),
            values: [
                ("x_w".to_string(), 1.19),
                ("k2".to_string(), 0.00023),
                ("dd3".to_string(), 1.0),
            ]
            .into(),
        };
        let provenance = Provenance {
            job: "synthetic".into(),
            stage_id: "validate".into(),
            stage_kind: "validate".into(),
            cache_key: "abc123".into(),
            input_hashes: [("measurements".to_string(), "feed".to_string())].into(),
            tool_version: "0.1.0".into(),
            created_at: "2026-01-01T00:00:00Z".into(),
            extra: [("validation_rows".to_string(), "6".to_string())].into(),
        };
        ReportData {
            title: "Synthetic <report>".into(),
            verdict: VerdictSettings {
                model: None,
                tolerance_mm: Some(0.5),
                criterion: Criterion::Max,
            },
            compare_with_paper: true,
            commands: None,
            histogram_bins: 8,
            truth_model: "elastogeometric".into(),
            stats,
            errors,
            parameters,
            tests: Some(vec![TestRow {
                model_a: "kinematic".into(),
                model_b: "elastogeometric".into(),
                test: "student_t".into(),
                statistic: 4.2,
                dof: Some(10.0),
                p_value: 0.0018,
            }]),
            poses: Some(
                (0..8)
                    .map(|k| Pose {
                        config_id: k,
                        target_mm: [
                            800.0 + 100.0 * (k & 1) as f64,
                            100.0 * (k >> 1 & 1) as f64,
                            900.0 + 50.0 * (k >> 2) as f64,
                        ],
                        tool_deg: [180.0 - 10.0 * k as f64, 20.0, 0.0],
                    })
                    .collect(),
            ),
            detmax_trace: Some(vec![
                DetmaxStep {
                    iteration: 0,
                    added: None,
                    removed: None,
                    o1: 0.01,
                },
                DetmaxStep {
                    iteration: 1,
                    added: Some(3),
                    removed: Some(4),
                    o1: 0.02,
                },
                DetmaxStep {
                    iteration: 2,
                    added: Some(5),
                    removed: Some(1),
                    o1: 0.025,
                },
            ]),
            o1_scaling: DEFAULT_O1_SCALING.into(),
            held_out: None,
            ladder: None,
            excluded_rows: Some(vec![ExcludedRow {
                cw_id: 17,
                model: None,
                check: "row_check".into(),
                reason: "q2_deg = 130 is outside the joint limits [-90, 120] of the robot file"
                    .into(),
            }]),
            identification_trace: Some(
                ["registered", "kinematic", "elastogeometric"]
                    .iter()
                    .flat_map(|m| {
                        (1..=4).map(move |i| TraceRow {
                            model: m.to_string(),
                            iteration: i,
                            rms_mm: 10.0 / (i * i) as f64,
                            max_mm: 20.0 / i as f64,
                            step_mm: 1.0 / i as f64,
                        })
                    })
                    .collect(),
            ),
            accuracy_map: Some(AccuracyMap {
                // Two slices of 3 × 3 points; u95 grows away from the centre, one
                // corner unreachable.
                points: (0..2)
                    .flat_map(|slice| {
                        (0..9).map(move |k| {
                            let (x, y) = ((k % 3) as f64 * 100.0, (k / 3) as f64 * 100.0);
                            MapPoint {
                                slice,
                                position_mm: [x, y, 500.0 + 200.0 * slice as f64],
                                inside_box: k == 4 && slice == 0,
                                u95_mm: (k != 8).then(|| {
                                    0.05 + 0.001 * ((x - 100.0).abs() + (y - 100.0).abs())
                                }),
                            }
                        })
                    })
                    .collect(),
                calibration_mm: vec![[90.0, 110.0, 510.0], [110.0, 90.0, 490.0]],
            }),
            iso9283: Some(IsoTest {
                points: vec![IsoPoint {
                    point: "P1".into(),
                    n: 30,
                    ap_mm: 0.061,
                    rp_mm: 0.084,
                }],
                distances: vec![IsoDistance {
                    from: "P2".into(),
                    to: "P4".into(),
                    n: 30,
                    d_cmd_mm: 692.82,
                    ad_mm: 0.012,
                    rd_mm: 0.09,
                }],
            }),
            iso9283_baseline: Some(IsoTest {
                points: vec![IsoPoint {
                    point: "P1".into(),
                    n: 30,
                    ap_mm: 2.5,
                    rp_mm: 0.085,
                }],
                distances: Vec::new(),
            }),
            truth: Some(truth),
            sources: vec![
                InputSource {
                    input: "stats".into(),
                    file: "out/validate/stats.parquet".into(),
                    rows: 5,
                    data_hash: "beef".into(),
                    provenance: Ok(Some(provenance)),
                },
                InputSource {
                    input: "truth".into(),
                    file: "truth/t.parquet".into(),
                    rows: 3,
                    data_hash: "cafe".into(),
                    provenance: Ok(None),
                },
                InputSource {
                    input: "poses".into(),
                    file: "gone.parquet".into(),
                    rows: 8,
                    data_hash: "f00d".into(),
                    provenance: Err("gone.parquet: cannot open".into()),
                },
            ],
        }
    }

    #[test]
    fn report_has_every_section_table_and_chart() {
        let html = render(&sample());
        assert!(html.starts_with("<!DOCTYPE html>"));
        for s in SECTIONS {
            assert!(
                html.contains(&format!("<section id=\"{}\">", s.id)),
                "{}",
                s.id
            );
            assert!(html.contains(&escape(&s.title(true))), "{}", s.heading);
        }
        assert!(html.contains("(Table III)") && html.contains("(Fig. 7)"));
        // Stats rows with the paper beside them.
        assert!(
            html.contains("<td>kinematic</td><td class=\"num\">6</td><td class=\"num\">1.000</td>"),
            "stats row"
        );
        assert!(html.contains("<td class=\"paper\">Elasto-geometrical calibration</td><td class=\"num paper\">0.264</td>"));
        assert!(html.contains("no counterpart in the paper"));
        // Overlay + 5 per-model histograms + poses + 2 map slices + O1 + convergence.
        assert_eq!(html.matches("<svg").count(), 11);
        assert_eq!(html.matches("</svg>").count(), 11);
        // The accuracy map: what is drawn, the medians inside the box and in the margin.
        assert!(html.contains("Median u95 inside the box: 0.050 mm; in the margin: 0.150 mm."));
        assert!(html.contains("(2 of 18)"), "unreachable points counted");
        assert!(
            html.contains("red dots: the 2 calibration positions within 100 mm of this height")
        );
        assert_eq!(
            html.matches("<section").count(),
            html.matches("</section>").count()
        );
        // Parameters with truth and z; tests; provenance in its three states.
        assert!(html.contains("<th class=\"num\">z (elastogeometric)</th>"));
        assert!(
            html.contains("<td class=\"num\">0.00023</td>"),
            "truth of k2"
        );
        // Values to the last digit of their standard error; z of x_w is (1.2 − 1.19)/0.01.
        assert!(html.contains("<td class=\"num identified\">1.200 ± 0.010</td>"));
        assert!(html.contains("<td class=\"num identified\">0.000190 ± 0.000010</td>"));
        assert!(html.contains("<td class=\"num\">+1.00</td>"), "z of x_w");
        assert!(
            html.contains("<td class=\"num flag\">-4.00</td>"),
            "z of k2 flagged"
        );
        // The nominal set is listed, not tabulated.
        assert!(html.contains("all at nominal (not repeated in the table)"));
        assert!(!html.contains("<th class=\"num\">nominal</th><th>status</th>"));
        assert!(html.contains("<th class=\"num\">kinematic</th><th>status</th>"));
        assert!(html.contains("<td>student_t</td>"));
        assert!(html.contains("abc123") && html.contains("2026-01-01T00:00:00Z"));
        assert!(html.contains("none recorded (not written by egcal)"));
        assert!(html.contains("could not be read: gone.parquet: cannot open"));
        assert!(html.contains(DEFAULT_O1_SCALING));
        // No scripts, nothing fetched: the only URL is the SVG namespace.
        for fetch in ["<script", "<link", " src=", "url(", "@import", "https://"] {
            assert!(!html.contains(fetch), "{fetch}");
        }
        assert_eq!(
            html.matches("http://").count(),
            html.matches("xmlns=\"http://www.w3.org/2000/svg\"").count()
        );
    }

    #[test]
    fn markup_in_names_is_escaped() {
        let html = render(&sample());
        assert!(!html.contains("odd<model>"), "raw model name in the page");
        assert!(html.contains("odd&lt;model&gt;&amp;"));
        assert!(html.contains("<title>Synthetic &lt;report&gt;</title>"));
        assert!(!html.contains("<report>"));
    }

    #[test]
    fn rendering_twice_gives_identical_bytes() {
        let data = sample();
        assert_eq!(render(&data), render(&data));
    }

    #[test]
    fn missing_optional_inputs_leave_notes() {
        let mut data = sample();
        data.tests = None;
        data.poses = None;
        data.detmax_trace = None;
        data.identification_trace = None;
        data.truth = None;
        data.accuracy_map = None;
        data.iso9283 = None;
        let html = render(&data);
        for s in SECTIONS {
            assert!(
                html.contains(&format!("<section id=\"{}\">", s.id)),
                "{}",
                s.id
            );
        }
        assert!(html.contains("No poses input is bound"));
        assert!(html.contains("No observability input is bound"));
        assert!(html.contains("No identification_trace input is bound"));
        assert!(html.contains("No tests input is bound"));
        assert!(html.contains("No truth input is bound"));
        assert!(html.contains("No accuracy_map input is bound"));
        assert!(html.contains("No iso9283 input is bound"));
        // Overlay + 5 per-model histograms only.
        assert_eq!(html.matches("<svg").count(), 6);
    }

    #[test]
    fn tool_z_axis_follows_eq_4() {
        let pose = |a: f64, b: f64| Pose {
            config_id: 0,
            target_mm: [0.0; 3],
            tool_deg: [a, b, 30.0],
        };
        let close = |u: [f64; 3], v: [f64; 3]| (0..3).all(|i| (u[i] - v[i]).abs() < 1e-12);
        assert!(close(pose(0.0, 0.0).tool_z(), [0.0, 0.0, 1.0]));
        assert!(close(pose(0.0, 90.0).tool_z(), [1.0, 0.0, 0.0]));
        assert!(close(pose(90.0, 0.0).tool_z(), [0.0, -1.0, 0.0]));
        assert!(close(pose(180.0, 0.0).tool_z(), [0.0, 0.0, -1.0]));
    }

    #[test]
    fn the_world_offset_of_the_truth_is_stated() {
        let mut data = sample();
        assert_eq!(world_offset(&data), None);
        let truth = data.truth.as_mut().unwrap();
        for (name, unit, value) in [
            ("x_w", "mm", 2.5),
            ("y_w", "mm", 1.0),
            ("z_w", "mm", 0.0),
            ("alpha_w", "deg", 1.0),
            ("beta_w", "deg", 0.4),
            ("gamma_w", "deg", 1.0),
        ] {
            truth.values.insert(name.to_string(), value);
            data.parameters
                .push(param("kinematic", name, unit, 0.0, None, "identified"));
        }
        // Nominal values are 1.0 in the sample.
        assert_eq!(world_offset(&data), Some((0.6, 1.5)));
        assert!(
            render(&data).contains("this truth's world frame is off by up to 0.60° and 1.50 mm")
        );
    }

    /// The page's verdict block (from its section to the table of contents).
    fn verdict_block(html: &str) -> &str {
        let start = html
            .find("<section id=\"verdict\">")
            .expect("verdict section");
        let end = html[start..].find("<nav>").expect("nav after the verdict") + start;
        &html[start..end]
    }

    #[test]
    fn the_first_screen_passes_the_model_in_service_within_tolerance() {
        let html = render(&sample());
        // The verdict comes before the table of contents and every other section.
        assert!(html.find("id=\"verdict\"") < html.find("<nav>"));
        assert!(html.find("<nav>") < html.find("<section id=\"errors\">"));
        let block = verdict_block(&html);
        // Elasto-geometric errors 0.10, 0.16, …, 0.40 mm: mean 0.25, p99.7 0.3991, max 0.40.
        assert!(block.contains("<div class=\"verdict pass\">"), "{block}");
        assert!(block.contains("<span class=\"badge\">PASS</span>"));
        assert!(block.contains("Model in service: <strong>elastogeometric</strong>"));
        assert!(block.contains(
            "<td class=\"num\">6</td><td class=\"num\">0.250</td><td class=\"num\">0.399</td>\
             <td class=\"num judged\">0.400</td><td class=\"num\">0.500</td><td>max</td>"
        ));
        assert!(
            block.contains(
                "Its max validation error, 0.400 mm, is within the tolerance of 0.500 mm."
            )
        );
        assert!(
            block.contains("<h3 id=\"warnings\">Warnings (1)</h3>"),
            "{block}"
        );
        // The sample's one row check: a warning with its count.
        assert!(block.contains("Rows left out of the calibration: 1 by the row checks (every model), 0 by the robust fit"));
        assert!(block.contains("Not checked: targets (no <code>commands</code> input)."));
    }

    #[test]
    fn the_first_screen_fails_beyond_tolerance_and_on_the_named_criterion() {
        let mut data = sample();
        data.verdict.tolerance_mm = Some(0.3);
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(block.contains("<div class=\"verdict fail\">"));
        assert!(block.contains("<span class=\"badge\">FAIL</span>"));
        assert!(
            block
                .contains("Its max validation error, 0.400 mm, exceeds the tolerance of 0.300 mm.")
        );
        // p99.7 of the kinematic errors (0.5, 0.8, …, 2.0): 1.9955; max 2.0.
        data.verdict = VerdictSettings {
            model: Some("kinematic".into()),
            tolerance_mm: Some(1.999),
            criterion: Criterion::P99_7,
        };
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(
            block.contains("<span class=\"badge\">PASS</span>"),
            "{block}"
        );
        assert!(block.contains(
            "Its p99.7 validation error, 1.996 mm, is within the tolerance of 1.999 mm."
        ));
        assert!(block.contains("the report's setting <code>model</code>"));
        assert!(block.contains("<td class=\"num judged\">1.996</td><td class=\"num\">2.000</td>"));
    }

    #[test]
    fn without_a_tolerance_there_are_figures_and_no_verdict() {
        let mut data = sample();
        data.verdict.tolerance_mm = None;
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(block.contains("<span class=\"badge\">NO VERDICT</span>"));
        assert!(!block.contains("badge\">PASS") && !block.contains("badge\">FAIL"));
        assert!(block.contains("set the report's <code>tolerance_mm</code>"));
        assert!(
            block.contains("<td class=\"num\">0.400</td><td class=\"num\">not set</td><td>—</td>")
        );
    }

    #[test]
    fn held_parameters_non_convergence_and_targets_are_warnings() {
        let mut data = sample();
        let mut held = param("elastogeometric", "dtheta5", "deg", 1.0, None, "held");
        held.reason = Some("near-dependent on da6 (corr +1.000) & <more>".into());
        data.parameters.push(held);
        let mut elsewhere = param("kinematic", "da4", "mm", 1.0, None, "held");
        elsewhere.reason = Some("std error 0.7 mm > 0.5".into());
        data.parameters.push(elsewhere);
        // identify's fact, in the provenance of its outputs (twice: deduplicated).
        let mut provenance = match &data.sources[0].provenance {
            Ok(Some(p)) => p.clone(),
            _ => unreachable!("the sample's first source has a provenance"),
        };
        provenance.extra.insert(
            "elastogeometric_not_converged_accepted".into(),
            "elastogeometric: not converged after 200 steps, accepted (`accept_not_converged = true`)".into(),
        );
        for input in ["parameters", "identification_trace"] {
            data.sources.push(InputSource {
                input: input.into(),
                file: format!("out/identify/{input}.parquet"),
                rows: 1,
                data_hash: "0".into(),
                provenance: Ok(Some(provenance.clone())),
            });
        }
        data.commands = Some(vec![
            CommandRow {
                target_id: 1,
                status: "ok".into(),
                envelope_distance: Some(0.1),
                u95_mm: Some(0.05),
            },
            CommandRow {
                target_id: 2,
                status: "outside_envelope".into(),
                envelope_distance: Some(2.5),
                u95_mm: Some(0.8),
            },
            CommandRow {
                target_id: 3,
                status: "unreachable".into(),
                envelope_distance: None,
                u95_mm: None,
            },
        ]);
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(
            block.contains("<h3 id=\"warnings\">Warnings (4)</h3>"),
            "{block}"
        );
        assert!(block.contains(
            "1 parameter of <strong>elastogeometric</strong> held at nominal: the data did not determine it"
        ));
        assert!(block.contains(
            "<li><code>dtheta5</code>: near-dependent on da6 (corr +1.000) &amp; &lt;more&gt;</li>"
        ));
        assert!(
            !block.contains("<code>da4</code>"),
            "another model's held parameter is counted, not listed"
        );
        assert!(block.contains("Other models hold 1 parameter"));
        assert_eq!(block.matches("did not converge").count(), 1);
        assert!(block.contains(
            "<strong>elastogeometric</strong>: the fit did not converge and was used anyway (not converged after 200 \
             steps, accepted (`accept_not_converged = true`))"
        ));
        assert!(block.contains(
            "2 of 3 targets have a command whose status is not <code>ok</code> (1 outside_envelope, 1 unreachable)"
        ));
        assert!(block.contains(
            "<tr><td class=\"num\">2</td><td>outside_envelope</td><td class=\"num\">2.500</td><td class=\"num\">0.800</td></tr>"
        ));
        assert!(block.contains("<tr><td class=\"num\">3</td><td>unreachable</td><td class=\"num\">—</td><td class=\"num\">—</td></tr>"));
        assert!(!block.contains("Not checked"));
        // Warnings qualify the verdict; they do not change it.
        assert!(block.contains("<span class=\"badge\">PASS</span>"));
        // The parameters section lists every held parameter with its reason.
        assert!(
            html.contains(
                "<tr><td>kinematic</td><td>da4</td><td>std error 0.7 mm &gt; 0.5</td></tr>"
            )
        );
        assert!(html.contains("<td class=\"held\" title=\"std error 0.7 mm &gt; 0.5\">held</td>"));
    }

    #[test]
    fn commands_without_the_envelope_columns_still_warn() {
        let mut data = sample();
        data.commands = Some(vec![CommandRow {
            target_id: 7,
            status: "joint_limit".into(),
            envelope_distance: None,
            u95_mm: None,
        }]);
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(block.contains(
            "1 of 1 targets have a command whose status is not <code>ok</code> (1 joint_limit)"
        ));
        assert!(
            block.contains(
                "<thead><tr><th class=\"num\">target_id</th><th>status</th></tr></thead>"
            )
        );
        assert!(!block.contains("envelope_distance"));
    }

    /// `ok` commands beyond compensate's default envelope (a job that raised
    /// `max_envelope_distance_deg`) are a warning; those within it are not.
    #[test]
    fn ok_commands_beyond_the_default_envelope_warn() {
        let mut data = sample();
        let row = |target_id, distance| CommandRow {
            target_id,
            status: "ok".into(),
            envelope_distance: Some(distance),
            u95_mm: Some(0.1),
        };
        data.commands = Some(vec![row(1, 12.0), row(2, 55.5), row(3, 96.0)]);
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(block.contains(
            "2 of 3 targets have an <code>ok</code> command more than 40° (compensate's default envelope) from the nearest calibration row, up to 96.0°"
        ));
        data.commands = Some(vec![row(1, 12.0)]);
        let html = render(&data);
        let block = verdict_block(&html);
        assert!(!block.contains("default envelope"));
    }

    #[test]
    fn real_data_get_no_paper_comparison() {
        let mut data = sample();
        data.compare_with_paper = false;
        data.truth = None;
        let html = render(&data);
        for paper in [
            "Table III",
            "Fig. 7",
            "Fig. 4",
            "paper:",
            "no counterpart in the paper",
            "Elasto-geometrical calibration",
            "world-frame error",
            "class=\"paper\"",
            "The paper used",
        ] {
            assert!(!html.contains(paper), "{paper}");
        }
        // The terms, as the guide defines them (docs/report.md).
        assert!(html.contains(
            "<li><strong>registered</strong>: the nominal robot with the world frame and the tool translation fitted"
        ));
        assert!(
            html.contains("maximum by 5.0.</p>"),
            "ratio without the paper's"
        );
        assert!(html.contains("Position errors on the validation rows</h2>"));
        // The paper job keeps it all.
        data.compare_with_paper = true;
        let html = render(&data);
        assert!(html.contains("Position errors on the validation rows (Table III)</h2>"));
        assert!(html.contains("(paper: 3.6 and 2.7)"));
        assert!(html.contains("world-frame error of the truth"));
    }

    #[test]
    fn the_default_model_in_service_is_the_most_complete_calibration() {
        let errors = |models: &[&str]| -> BTreeMap<String, Vec<f64>> {
            models.iter().map(|m| (m.to_string(), vec![1.0])).collect()
        };
        use verdict::{default_model, model_in_service};
        assert_eq!(
            default_model(&errors(&["registered", "kinematic", "elastogeometric"])).as_deref(),
            Some("elastogeometric")
        );
        assert_eq!(
            default_model(&errors(&["registered", "reregistered"])).as_deref(),
            Some("reregistered")
        );
        assert_eq!(default_model(&errors(&["mine"])).as_deref(), Some("mine"));
        assert_eq!(default_model(&errors(&[])), None);
        assert_eq!(
            model_in_service(&errors(&["kinematic"]), Some("elastogeometric")),
            Err("setting `model`: the errors table has no rows of model `elastogeometric` (it has: kinematic)".into())
        );
        assert_eq!(
            model_in_service(&errors(&["kinematic"]), Some("kinematic")).as_deref(),
            Ok("kinematic")
        );
    }

    #[test]
    fn models_in_canonical_order_then_appearance() {
        let order = ordered_models(["zeta", "kinematic", "alpha", "nominal", "kinematic"]);
        assert_eq!(order, ["nominal", "kinematic", "zeta", "alpha"]);
    }
}
