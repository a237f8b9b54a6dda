//! The calibration report: one self-contained HTML page (inline CSS, inline SVG,
//! no scripts, nothing fetched) from plain data read by the `report` stage.
//!
//! Rendering is pure and deterministic: the same [`ReportData`] gives the same
//! bytes, so the runner's content-addressed cache holds. The only times in the
//! page are those recorded in the inputs' provenance.

pub mod held_out;
pub mod ladder;
mod page;
pub mod plots;
pub mod verdict;

use std::collections::BTreeMap;

use askama::Template;

use crate::table::Provenance;
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

/// HTML-escapes text for element content and quoted attribute values, where
/// markup is written without a template (the charts' SVG labels, the fleet page).
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
        "< 1e-300".into()
    } else if p < 1e-3 {
        format!("{p:.2e}")
    } else {
        format!("{p:.4}")
    }
}

/// The page could not be rendered (a template's formatting failed).
#[derive(Debug, thiserror::Error)]
#[error("the report page could not be rendered: {0}")]
pub struct RenderError(#[from] askama::Error);

/// Renders the whole page: the view of each section (see `page.rs`) laid out
/// by the templates under `templates/report/`.
pub fn render(data: &ReportData) -> Result<String, RenderError> {
    Ok(page::page(data).render()?)
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
        let html = render(&sample()).expect("render");
        assert!(html.starts_with("<!DOCTYPE html>"));
        for s in SECTIONS {
            assert!(
                html.contains(&format!("<section id=\"{}\">", s.id)),
                "{}",
                s.id
            );
            assert!(html.contains(&s.title(true)), "{}", s.heading);
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
        let html = render(&sample()).expect("render");
        assert!(!html.contains("odd<model>"), "raw model name in the page");
        assert!(html.contains("odd&#60;model&#62;&#38;"));
        assert!(html.contains("<title>Synthetic &#60;report&#62;</title>"));
        assert!(!html.contains("<report>"));
    }

    #[test]
    fn rendering_twice_gives_identical_bytes() {
        let data = sample();
        assert_eq!(
            render(&data).expect("render"),
            render(&data).expect("render")
        );
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
        let html = render(&data).expect("render");
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
            render(&data)
                .expect("render")
                .contains("this truth's world frame is off by up to 0.60° and 1.50 mm")
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
        let html = render(&sample()).expect("render");
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
        let html = render(&data).expect("render");
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
        let html = render(&data).expect("render");
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
        let html = render(&data).expect("render");
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
        let html = render(&data).expect("render");
        let block = verdict_block(&html);
        assert!(
            block.contains("<h3 id=\"warnings\">Warnings (4)</h3>"),
            "{block}"
        );
        assert!(block.contains(
            "1 parameter of <strong>elastogeometric</strong> held at nominal: the data did not determine it"
        ));
        assert!(block.contains(
            "<li><code>dtheta5</code>: near-dependent on da6 (corr +1.000) &#38; &#60;more&#62;</li>"
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
        assert!(html.contains(
            "<tr><td>kinematic</td><td>da4</td><td>std error 0.7 mm &#62; 0.5</td></tr>"
        ));
        assert!(html.contains("<td class=\"held\" title=\"std error 0.7 mm &#62; 0.5\">held</td>"));
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
        let html = render(&data).expect("render");
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
        let html = render(&data).expect("render");
        let block = verdict_block(&html);
        assert!(block.contains(
            "2 of 3 targets have an <code>ok</code> command more than 40° (compensate's default envelope) from the nearest calibration row, up to 96.0°"
        ));
        data.commands = Some(vec![row(1, 12.0)]);
        let html = render(&data).expect("render");
        let block = verdict_block(&html);
        assert!(!block.contains("default envelope"));
    }

    #[test]
    fn real_data_get_no_paper_comparison() {
        let mut data = sample();
        data.compare_with_paper = false;
        data.truth = None;
        let html = render(&data).expect("render");
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
        let html = render(&data).expect("render");
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
    fn held_out_figures_and_the_ladder_follow_the_statistics() {
        let mut data = sample();
        let held_out = held_out::test_row;
        data.held_out = Some(vec![
            held_out("configuration", 0.47),
            held_out("random", 0.43),
        ]);
        let rung = |model: &str, chosen: bool| ladder::LadderRow {
            protocol: "configuration".into(),
            model: model.into(),
            mean_mm: 0.1,
            p997_mm: 0.2,
            max_mm: 0.3,
            compared_with: chosen.then(|| "elastogeometric".into()),
            paired_t_p: Some(1e-9),
            wilcoxon_p: None,
            chosen,
            reason: "held-out mean <lower>".into(),
        };
        data.ladder = Some(vec![
            rung("elastogeometric", false),
            rung("eg_backlash", true),
        ]);
        let html = render(&data).expect("render");
        let at = |text: &str| html.find(text).unwrap_or_else(|| panic!("{text}"));
        assert!(at("<h3 id=\"held-out\">") < at("<h3 id=\"ladder\">"));
        assert!(at("random folds") < at("configuration folds"));
        assert!(at("<section id=\"errors\">") < at("random folds"));
        assert!(at("configuration folds") < at("<section id=\"histograms\">"));
        assert!(html.contains(
            "<tr><td>elastogeometric</td><td class=\"num\">0.430</td><td class=\"num\">0.860</td>\
             <td class=\"num\">1.290</td><td class=\"num\">0.470</td>"
        ));
        assert!(html.contains("Chosen: <strong>eg_backlash</strong>"));
        assert!(html.contains(
            "<tr class=\"chosen\"><td>eg_backlash</td><td class=\"num\">0.100</td><td class=\"num\">0.200</td>\
             <td class=\"num\">0.300</td><td>elastogeometric</td><td class=\"num\">1.0e-9</td><td class=\"num\"></td>\
             <td>chosen: held-out mean &#60;lower&#62;</td></tr>"
        ));
    }

    /// `errors.html` has the words for each model page.rs lists as defined.
    #[test]
    fn every_defined_model_has_its_meaning() {
        let mut data = sample();
        data.stats = page::DEFINED_MODELS
            .iter()
            .map(|m| stats_row(m, 1.0))
            .collect();
        let html = render(&data).expect("render");
        for model in page::DEFINED_MODELS {
            let term = format!("<li><strong>{model}</strong>: ");
            let at = html.find(&term).unwrap_or_else(|| panic!("{model}")) + term.len();
            assert!(
                html[at..].len() > 20 && !html[at..].starts_with(".</li>"),
                "{model}"
            );
        }
    }

    #[test]
    fn models_in_canonical_order_then_appearance() {
        let order = ordered_models(["zeta", "kinematic", "alpha", "nominal", "kinematic"]);
        assert_eq!(order, ["nominal", "kinematic", "zeta", "alpha"]);
    }
}
