//! The page as plain view structs, one per section, laid out by the templates
//! under `templates/report/` (one file per section, `page.html` includes them).
//!
//! Every number is formatted here with the helpers of [`super`], so the
//! templates hold markup and prose only. Askama escapes every string the
//! templates print; only the SVG charts, which plotters drew, go in unescaped.

use std::collections::BTreeMap;

use askama::Template;
use plotters::style::RGBColor;

use super::held_out::HeldOutView;
use super::ladder::LadderView;
use super::verdict::VerdictView;
use super::{
    EXCLUDED_LISTED, InputSource, MapPoint, PAPER_TABLE_III, PAPER_VALIDATION_ROWS, ParamRow,
    ReportData, SECTIONS, StatsRow, TraceRow, mm, ordered_models, p_value, param_value, plots,
    with_error,
};
use crate::robot::ParamId;
use crate::table::Provenance;
use plots::{Axes, HistogramSeries, LineSeries2, PosePoint};

/// The whole page.
#[derive(Template)]
#[template(path = "report/page.html")]
pub(super) struct Page<'a> {
    pub title: &'a str,
    /// The job that wrote the inputs, from the first provenance found.
    pub job: Option<&'a str>,
    pub validation_rows: i64,
    pub version: &'static str,
    pub verdict: VerdictView,
    pub contents: Vec<Heading>,
    pub errors: ErrorsSection,
    pub histograms: HistogramsSection,
    pub poses: PosesSection,
    pub accuracy: AccuracySection,
    pub iso9283: IsoSection,
    pub parameters: ParametersSection,
    pub observability: ObservabilitySection,
    pub convergence: ConvergenceSection,
    pub tests: TestsSection,
    pub provenance: ProvenanceSection<'a>,
}

/// A section's anchor and numbered heading.
pub(super) struct Heading {
    pub id: &'static str,
    pub number: usize,
    pub title: String,
}

impl Heading {
    /// Section `index` of [`SECTIONS`]; the paper's table or figure is named
    /// only when the job reproduces the paper.
    fn new(index: usize, compare_with_paper: bool) -> Heading {
        let section = SECTIONS[index];
        Heading {
            id: section.id,
            number: index + 1,
            title: section.title(compare_with_paper),
        }
    }
}

/// A chart (plotters' SVG, or why it could not be drawn) and its caption.
pub(super) struct Figure {
    pub chart: Result<String, String>,
    pub caption: String,
}

impl Figure {
    fn new(chart: Result<String, String>, caption: impl Into<String>) -> Figure {
        Figure {
            chart,
            caption: caption.into(),
        }
    }
}

/// Builds every section's view from the report's data.
pub(super) fn page(data: &ReportData) -> Page<'_> {
    let paper = data.compare_with_paper;
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
    // One heading per entry of SECTIONS, in page order: a section added there
    // and not here fails to compile.
    let [
        verdict,
        errors,
        histograms,
        poses,
        accuracy,
        iso9283,
        parameters,
        observability,
        convergence,
        tests,
        provenance,
    ] = std::array::from_fn(|index| Heading::new(index, paper));
    Page {
        title: &data.title,
        job: data.sources.iter().find_map(|s| match &s.provenance {
            Ok(Some(p)) => Some(p.job.as_str()),
            _ => None,
        }),
        validation_rows: data.stats.first().map_or(0, |s| s.n),
        version: env!("CARGO_PKG_VERSION"),
        verdict: super::verdict::view(&super::verdict::verdict(data), verdict),
        contents: (0..SECTIONS.len())
            .map(|index| Heading::new(index, paper))
            .collect(),
        errors: errors_section(data, errors),
        histograms: histograms_section(data, histograms, &models, &colors),
        poses: poses_section(data, poses),
        accuracy: accuracy_section(data, accuracy),
        iso9283: iso9283_section(data, iso9283),
        parameters: parameters_section(data, parameters),
        observability: observability_section(data, observability),
        convergence: convergence_section(data, convergence, &models, &colors),
        tests: tests_section(data, tests),
        provenance: provenance_section(data, provenance),
    }
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

/// Section 2: the validation statistics, held-out accuracy and model ladder.
pub(super) struct ErrorsSection {
    pub heading: Heading,
    pub paper: bool,
    pub paper_validation_rows: usize,
    pub rows: Vec<StatsView>,
    /// Models whose meaning the page states (the template has the words).
    pub terms: Vec<String>,
    /// `Some` when the paper's job shows `nominal`, which is in the nominal
    /// world frame; inside, how far the truth's world frame is from it.
    pub nominal_in_paper_frame: Option<Option<(String, String)>>,
    pub registered_without_column: bool,
    pub elastogeometric_gain: Option<Gain>,
    pub held_out: Option<HeldOutView>,
    pub ladder: Option<LadderView>,
}

/// A row of the statistics table.
pub(super) struct StatsView {
    pub model: String,
    pub n: i64,
    pub mean: String,
    pub std: String,
    pub median: String,
    pub rms: String,
    pub p95: String,
    pub max: String,
    /// The paper's column of Table III for this model, if it has one.
    pub paper: Option<PaperView>,
}

pub(super) struct PaperView {
    pub column: &'static str,
    pub mean: String,
    pub std: String,
    pub max: String,
}

/// How much the elasto-geometric calibration divides the kinematic one's
/// mean and maximum errors (and the paper's, when compared).
pub(super) struct Gain {
    pub mean: String,
    pub max: String,
    pub paper: Option<(String, String)>,
}

/// Models whose meaning `errors.html` states, as the guide defines the terms (docs/report.md).
pub(super) const DEFINED_MODELS: [&str; 5] = [
    "nominal",
    "registered",
    "reregistered",
    "kinematic",
    "elastogeometric",
];

fn errors_section(data: &ReportData, heading: Heading) -> ErrorsSection {
    let paper = data.compare_with_paper;
    let stats: Vec<&StatsRow> = ordered_models(data.stats.iter().map(|s| s.model.as_str()))
        .iter()
        .filter_map(|m| data.stats.iter().find(|s| &s.model == m))
        .collect();
    let rows = stats
        .iter()
        .map(|s| StatsView {
            model: s.model.clone(),
            n: s.n,
            mean: mm(s.mean),
            std: mm(s.std),
            median: mm(s.median),
            rms: mm(s.rms),
            p95: mm(s.p95),
            max: mm(s.max),
            paper: PAPER_TABLE_III
                .iter()
                .find(|p| p.model == s.model)
                .map(|p| PaperView {
                    column: p.column,
                    mean: mm(p.mean),
                    std: mm(p.std),
                    max: mm(p.max),
                }),
        })
        .collect();
    let has = |m: &str| stats.iter().any(|s| s.model == m);
    let find = |m: &str| stats.iter().find(|s| s.model == m);
    let elastogeometric_gain = match (find("kinematic"), find("elastogeometric")) {
        (Some(k), Some(e)) if e.mean > 0.0 && e.max > 0.0 => Some(Gain {
            mean: format!("{:.1}", k.mean / e.mean),
            max: format!("{:.1}", k.max / e.max),
            paper: paper.then(|| {
                (
                    format!("{:.1}", PAPER_TABLE_III[1].mean / PAPER_TABLE_III[2].mean),
                    format!("{:.1}", PAPER_TABLE_III[1].max / PAPER_TABLE_III[2].max),
                )
            }),
        }),
        _ => None,
    };
    ErrorsSection {
        heading,
        paper,
        paper_validation_rows: PAPER_VALIDATION_ROWS,
        rows,
        terms: stats
            .iter()
            .filter(|s| DEFINED_MODELS.contains(&s.model.as_str()))
            .map(|s| s.model.clone())
            .collect(),
        nominal_in_paper_frame: (paper && has("nominal")).then(|| {
            super::world_offset(data).map(|(deg, mm)| (format!("{deg:.2}"), format!("{mm:.2}")))
        }),
        registered_without_column: paper && !has("nominal") && has("registered"),
        elastogeometric_gain,
        held_out: data.held_out.as_deref().and_then(super::held_out::view),
        ladder: data.ladder.as_deref().and_then(super::ladder::view),
    }
}

/// Section 3: the error histograms.
pub(super) struct HistogramsSection {
    pub heading: Heading,
    pub bins: usize,
    /// Kinematic and elasto-geometric on the same bins, when both have errors.
    pub overlay: Option<Figure>,
    /// One per model with errors; empty when the errors table has no rows.
    pub per_model: Vec<Figure>,
}

fn histograms_section(
    data: &ReportData,
    heading: Heading,
    models: &[String],
    colors: &BTreeMap<String, RGBColor>,
) -> HistogramsSection {
    let bins = data.histogram_bins.max(1);
    let with_errors: Vec<&String> = models
        .iter()
        .filter(|m| data.errors.get(*m).is_some_and(|v| !v.is_empty()))
        .collect();
    let overlay = match (
        data.errors.get("kinematic"),
        data.errors.get("elastogeometric"),
    ) {
        (Some(k), Some(e)) if !k.is_empty() && !e.is_empty() => {
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
            Some(Figure::new(
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
            ))
        }
        _ => None,
    };
    let per_model = with_errors
        .iter()
        .map(|model| {
            let values = &data.errors[*model];
            let series = [HistogramSeries {
                name: model,
                color: colors[*model],
                values,
            }];
            let title = format!("{model} ({} rows)", values.len());
            Figure::new(
                plots::histogram(&title, &series, bins, (560, 320)),
                format!("Model {model}."),
            )
        })
        .collect();
    HistogramsSection {
        heading,
        bins,
        overlay,
        per_model,
    }
}

/// Section 4: the measurement poses.
pub(super) struct PosesSection {
    pub heading: Heading,
    /// `None` without a poses input.
    pub view: Option<PosesView>,
}

pub(super) struct PosesView {
    pub count: usize,
    pub figure: Figure,
}

fn poses_section(data: &ReportData, heading: Heading) -> PosesSection {
    let view = data.poses.as_ref().filter(|p| !p.is_empty()).map(|poses| {
        let points: Vec<PosePoint> = poses
            .iter()
            .map(|p| PosePoint {
                position: p.target_mm,
                axis: p.tool_z(),
            })
            .collect();
        PosesView {
            count: poses.len(),
            figure: Figure::new(
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
            ),
        }
    });
    PosesSection { heading, view }
}

/// Section 5: the accuracy map.
pub(super) struct AccuracySection {
    pub heading: Heading,
    /// `None` without an accuracy_map input.
    pub map: Option<MapView>,
}

pub(super) struct MapView {
    pub points: usize,
    pub unreachable: usize,
    pub median_inside: String,
    pub median_margin: String,
    /// One heat map per slice.
    pub slices: Vec<Figure>,
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
fn accuracy_section(data: &ReportData, heading: Heading) -> AccuracySection {
    let map = data
        .accuracy_map
        .as_ref()
        .filter(|m| !m.points.is_empty())
        .map(|map| {
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
            let median_where = |inside: bool| {
                let mut values: Vec<f64> = map
                    .points
                    .iter()
                    .filter(|p| p.inside_box == inside)
                    .filter_map(|p| p.u95_mm)
                    .collect();
                median(&mut values).map_or_else(
                    || "no reachable point".to_string(),
                    |m| format!("{} mm", mm(m)),
                )
            };
            let (median_inside, median_margin) = (median_where(true), median_where(false));
            let calibration_box = map.calibration_mm.iter().fold(
                None,
                |acc: Option<([f64; 3], [f64; 3])>, p| {
                    Some(match acc {
                        None => (*p, *p),
                        Some((lo, hi)) => (
                            std::array::from_fn(|i| lo[i].min(p[i])),
                            std::array::from_fn(|i| hi[i].max(p[i])),
                        ),
                    })
                },
            );
            // Calibration positions within half a slice spacing of a slice's height.
            let mut heights: Vec<f64> = map.points.iter().map(|p| p.position_mm[2]).collect();
            heights.sort_by(f64::total_cmp);
            heights.dedup();
            let band = heights
                .windows(2)
                .map(|w| w[1] - w[0])
                .fold(f64::INFINITY, f64::min)
                / 2.0;
            let slice_figures = slices
                .iter()
                .map(|slice| {
                    let points: Vec<&MapPoint> =
                        map.points.iter().filter(|p| p.slice == *slice).collect();
                    let z = points.first().map_or(0.0, |p| p.position_mm[2]);
                    let spacing = |axis: usize| {
                        let mut levels: Vec<f64> =
                            points.iter().map(|p| p.position_mm[axis]).collect();
                        levels.sort_by(f64::total_cmp);
                        levels.dedup();
                        let step = levels
                            .windows(2)
                            .map(|w| w[1] - w[0])
                            .fold(f64::INFINITY, f64::min);
                        if step.is_finite() { step } else { 1.0 }
                    };
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
                            cell_mm: (spacing(0), spacing(1)),
                            overlay: &overlay,
                            outline,
                        },
                        &cells,
                        (620, 520),
                    );
                    Figure::new(
                        chart,
                        format!(
                            "Slice {} (z = {z:.0} mm): u95 per grid point, one colour scale for all slices; red \
                             dots: the {} calibration positions within {:.0} mm of this height.",
                            slice + 1,
                            overlay.len(),
                            if band.is_finite() { band } else { 0.0 },
                        ),
                    )
                })
                .collect();
            MapView {
                points: map.points.len(),
                unreachable: map.points.len() - reachable.len(),
                median_inside,
                median_margin,
                slices: slice_figures,
            }
        });
    AccuracySection { heading, map }
}

/// Section 6: ISO 9283.
pub(super) struct IsoSection {
    pub heading: Heading,
    /// `None` without an iso9283 input.
    pub test: Option<IsoView>,
}

pub(super) struct IsoView {
    /// The nominal commands' test is beside the compensated one.
    pub with_baseline: bool,
    pub points: Vec<IsoPointView>,
    pub distances: Vec<IsoDistanceView>,
}

/// A test point; the baseline's figures are a dash where it lacks the point.
pub(super) struct IsoPointView {
    pub point: String,
    pub n: i64,
    pub accuracy: String,
    pub repeatability: String,
    pub baseline_accuracy: String,
    pub baseline_repeatability: String,
}

pub(super) struct IsoDistanceView {
    pub from: String,
    pub to: String,
    pub n: i64,
    pub commanded: String,
    pub accuracy: String,
    pub repeatability: String,
    pub baseline_accuracy: String,
    pub baseline_repeatability: String,
}

/// A cell of a value the baseline may lack: the value, or a dash.
fn optional_mm(value: Option<f64>) -> String {
    value.map_or_else(|| "—".to_string(), mm)
}

/// The ISO 9283 statistics per point and per pair of points, the compensated
/// commands beside the nominal ones when both tests are bound, so the gain of
/// compensation reads off one table.
fn iso9283_section(data: &ReportData, heading: Heading) -> IsoSection {
    let baseline = data.iso9283_baseline.as_ref();
    let test = data.iso9283.as_ref().map(|test| IsoView {
        with_baseline: baseline.is_some(),
        points: test
            .points
            .iter()
            .map(|p| {
                let base = baseline.and_then(|b| b.points.iter().find(|q| q.point == p.point));
                IsoPointView {
                    point: p.point.clone(),
                    n: p.n,
                    accuracy: mm(p.ap_mm),
                    repeatability: mm(p.rp_mm),
                    baseline_accuracy: optional_mm(base.map(|b| b.ap_mm)),
                    baseline_repeatability: optional_mm(base.map(|b| b.rp_mm)),
                }
            })
            .collect(),
        distances: test
            .distances
            .iter()
            .map(|d| {
                let base = baseline.and_then(|b| {
                    b.distances
                        .iter()
                        .find(|e| e.from == d.from && e.to == d.to)
                });
                IsoDistanceView {
                    from: d.from.clone(),
                    to: d.to.clone(),
                    n: d.n,
                    commanded: mm(d.d_cmd_mm),
                    accuracy: mm(d.ad_mm),
                    repeatability: mm(d.rd_mm),
                    baseline_accuracy: optional_mm(base.map(|b| b.ad_mm)),
                    baseline_repeatability: optional_mm(base.map(|b| b.rd_mm)),
                }
            })
            .collect(),
    });
    IsoSection { heading, test }
}

/// Section 7: the identified parameters.
pub(super) struct ParametersSection {
    pub heading: Heading,
    /// The truth table's model, when a truth is bound.
    pub truth_model: Option<String>,
    /// The model compared with the truth by z, when it has a column.
    pub z_model: Option<String>,
    /// Every model, with its status counts.
    pub models: Vec<ModelSummary>,
    /// Models with a column (not every parameter at nominal).
    pub columns: Vec<String>,
    pub rows: Vec<ParamView>,
    pub held: Vec<HeldView>,
}

pub(super) struct ModelSummary {
    pub name: String,
    /// `(status, count)` in status order.
    pub status_counts: Vec<(String, usize)>,
    /// Every parameter fixed at nominal: listed, not tabulated.
    pub at_nominal: bool,
    pub z_against_truth: Option<ZSummary>,
}

pub(super) struct ZSummary {
    pub count: usize,
    pub rms: String,
    pub largest: String,
}

/// A parameter's row: one cell per column model (`None`: the model lacks it).
pub(super) struct ParamView {
    pub name: String,
    pub unit: String,
    pub nominal: String,
    pub cells: Vec<Option<ParamCell>>,
    /// `None` without a truth column.
    pub truth: Option<String>,
    /// `None` without a z column; `Some(None)` where z is undefined.
    pub z: Option<Option<ZCell>>,
}

pub(super) struct ParamCell {
    pub value: String,
    pub status: String,
    /// The status as a CSS class; empty for a status the style does not know.
    pub class: &'static str,
    /// Why it is held, fixed or dependent, as a tooltip.
    pub reason: Option<String>,
}

pub(super) struct ZCell {
    pub value: String,
    /// |z| > 3.
    pub flagged: bool,
}

pub(super) struct HeldView {
    pub model: String,
    pub name: String,
    pub reason: String,
}

fn status_class(status: &str) -> &'static str {
    match status {
        "identified" => "identified",
        "dependent" => "dependent",
        "fixed" => "fixed",
        "held" => "held",
        _ => "",
    }
}

fn parameters_section(data: &ReportData, heading: Heading) -> ParametersSection {
    let all_models = ordered_models(data.parameters.iter().map(|p| p.model.as_str()));
    // A model with every parameter fixed at nominal (the `nominal` set) would
    // repeat the nominal column: listed, not tabulated.
    let at_nominal = |model: &str| {
        data.parameters
            .iter()
            .filter(|p| p.model == model)
            .all(|p| p.status == "fixed" && p.value == p.nominal)
    };
    let columns: Vec<String> = all_models
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
    let by_model_and_name: BTreeMap<(&str, &str), &ParamRow> = data
        .parameters
        .iter()
        .map(|p| ((p.model.as_str(), p.name.as_str()), p))
        .collect();
    let z_model = truth
        .map(|t| t.model.as_str())
        .filter(|m| columns.iter().any(|x| x == m));
    let z_of = |p: &ParamRow| -> Option<f64> {
        let truth = truth?.values.get(&p.name)?;
        Some((p.value - truth) / p.std_error.filter(|s| *s > 0.0)?)
    };

    let models = all_models
        .iter()
        .map(|model| {
            let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
            for p in data.parameters.iter().filter(|p| &p.model == model) {
                *counts.entry(p.status.as_str()).or_default() += 1;
            }
            let z_against_truth = (z_model == Some(model.as_str()))
                .then(|| {
                    let z: Vec<f64> = data
                        .parameters
                        .iter()
                        .filter(|p| &p.model == model && p.status == "identified")
                        .filter_map(z_of)
                        .collect();
                    (!z.is_empty()).then(|| ZSummary {
                        count: z.len(),
                        rms: format!(
                            "{:.2}",
                            (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt()
                        ),
                        largest: format!("{:.2}", z.iter().fold(0.0f64, |a, v| a.max(v.abs()))),
                    })
                })
                .flatten();
            ModelSummary {
                name: model.clone(),
                status_counts: counts
                    .into_iter()
                    .map(|(s, n)| (s.to_string(), n))
                    .collect(),
                at_nominal: at_nominal(model),
                z_against_truth,
            }
        })
        .collect();

    let rows = names
        .iter()
        .map(|name| {
            let first = data.parameters.iter().find(|p| &p.name == name);
            let unit = first.map_or_else(
                || {
                    ParamId::from_name(name)
                        .map_or("", |id| id.unit())
                        .to_string()
                },
                |p| p.unit.clone(),
            );
            ParamView {
                name: name.to_string(),
                nominal: first.map_or("—".into(), |p| param_value(p.nominal, &unit)),
                cells: columns
                    .iter()
                    .map(|model| {
                        by_model_and_name
                            .get(&(model.as_str(), *name))
                            .map(|p| ParamCell {
                                value: with_error(p.value, p.std_error, &unit),
                                status: p.status.clone(),
                                class: status_class(&p.status),
                                reason: p.reason.clone(),
                            })
                    })
                    .collect(),
                truth: truth.map(|t| {
                    t.values
                        .get(*name)
                        .map_or("—".into(), |v| param_value(*v, &unit))
                }),
                z: z_model.map(|m| {
                    by_model_and_name
                        .get(&(m, *name))
                        .filter(|p| p.status == "identified")
                        .and_then(|p| z_of(p))
                        .map(|z| ZCell {
                            value: format!("{z:+.2}"),
                            flagged: z.abs() > 3.0,
                        })
                }),
                unit,
            }
        })
        .collect();
    let held = all_models
        .iter()
        .flat_map(|m| {
            data.parameters
                .iter()
                .filter(move |p| &p.model == m && p.status == "held")
        })
        .map(|p| HeldView {
            model: p.model.clone(),
            name: p.name.clone(),
            reason: p
                .reason
                .clone()
                .unwrap_or_else(|| "no reason recorded".to_string()),
        })
        .collect();
    ParametersSection {
        heading,
        truth_model: truth.map(|t| t.model.clone()),
        z_model: z_model.map(str::to_string),
        models,
        columns,
        rows,
        held,
    }
}

/// Section 8: DETMAX's observability trace.
pub(super) struct ObservabilitySection {
    pub heading: Heading,
    pub o1_scaling: String,
    /// `None` without an observability input.
    pub trace: Option<DetmaxView>,
}

pub(super) struct DetmaxView {
    pub start: String,
    pub last: String,
    pub exchanges: usize,
    pub figure: Figure,
}

fn observability_section(data: &ReportData, heading: Heading) -> ObservabilitySection {
    let trace = data
        .detmax_trace
        .as_ref()
        .and_then(|t| Some((t, t.first()?)))
        .map(|(trace, first)| {
            let start = trace.iter().find(|s| s.iteration == 0).unwrap_or(first);
            let last = trace.iter().max_by_key(|s| s.iteration).unwrap_or(first);
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
            DetmaxView {
                start: plots::short(start.o1),
                last: plots::short(last.o1),
                exchanges: trace
                    .iter()
                    .filter(|s| s.added.is_some() || s.removed.is_some())
                    .count(),
                figure: Figure::new(
                    plots::line_chart(&axes, &series, (1000, 380)),
                    format!("O1 ({}).", data.o1_scaling),
                ),
            }
        });
    ObservabilitySection {
        heading,
        o1_scaling: data.o1_scaling.clone(),
        trace,
    }
}

/// Section 9: the identification's convergence and the rows it left out.
pub(super) struct ConvergenceSection {
    pub heading: Heading,
    /// `None` without an identification_trace input.
    pub trace: Option<ConvergenceView>,
    /// `None` without an excluded_rows input.
    pub excluded: Option<ExcludedView>,
}

pub(super) struct ConvergenceView {
    pub figure: Figure,
    pub models: Vec<ConvergenceRow>,
}

pub(super) struct ConvergenceRow {
    pub name: String,
    pub iterations: usize,
    pub first_rms: String,
    pub last_rms: String,
    pub last_max: String,
    pub last_step: String,
}

pub(super) struct ExcludedView {
    pub row_checks: usize,
    pub robust: usize,
    /// The first [`EXCLUDED_LISTED`] rows.
    pub rows: Vec<ExcludedRowView>,
    /// Rows not listed.
    pub more: usize,
}

pub(super) struct ExcludedRowView {
    pub cw_id: i64,
    pub model: String,
    pub check: String,
    pub reason: String,
}

fn convergence_section(
    data: &ReportData,
    heading: Heading,
    models: &[String],
    colors: &BTreeMap<String, RGBColor>,
) -> ConvergenceSection {
    let trace = data
        .identification_trace
        .as_ref()
        .filter(|t| !t.is_empty())
        .map(|trace| {
            // Each traced model's rows in iteration order (never empty).
            let traced: Vec<(&String, Vec<&TraceRow>)> = models
                .iter()
                .map(|m| {
                    let mut rows: Vec<&TraceRow> = trace.iter().filter(|t| &t.model == m).collect();
                    rows.sort_by_key(|t| t.iteration);
                    (m, rows)
                })
                .filter(|(_, rows)| !rows.is_empty())
                .collect();
            let series: Vec<LineSeries2> = traced
                .iter()
                .map(|(m, rows)| LineSeries2 {
                    name: m.as_str(),
                    color: colors[m.as_str()],
                    points: rows.iter().map(|t| (t.iteration, t.rms_mm)).collect(),
                })
                .collect();
            let axes = Axes {
                title: "Identification convergence",
                x: "iteration",
                y: "residual rms (mm)",
            };
            ConvergenceView {
                figure: Figure::new(
                    plots::log_line_chart(&axes, &series, (1000, 400)),
                    "rms_mm per iteration, per model.",
                ),
                models: traced
                    .iter()
                    .filter_map(|(m, rows)| {
                        let (first, last) = (rows.first()?, rows.last()?);
                        Some(ConvergenceRow {
                            name: m.to_string(),
                            iterations: rows.len(),
                            first_rms: plots::short(first.rms_mm),
                            last_rms: plots::short(last.rms_mm),
                            last_max: plots::short(last.max_mm),
                            last_step: plots::short(last.step_mm),
                        })
                    })
                    .collect(),
            }
        });
    let excluded = data.excluded_rows.as_ref().map(|rows| {
        let row_checks = rows.iter().filter(|r| r.model.is_none()).count();
        ExcludedView {
            row_checks,
            robust: rows.len() - row_checks,
            rows: rows
                .iter()
                .take(EXCLUDED_LISTED)
                .map(|r| ExcludedRowView {
                    cw_id: r.cw_id,
                    model: r.model.clone().unwrap_or_else(|| "all".to_string()),
                    check: r.check.clone(),
                    reason: r.reason.clone(),
                })
                .collect(),
            more: rows.len().saturating_sub(EXCLUDED_LISTED),
        }
    });
    ConvergenceSection {
        heading,
        trace,
        excluded,
    }
}

/// Section 10: the hypothesis tests.
pub(super) struct TestsSection {
    pub heading: Heading,
    pub paper: bool,
    /// `None` without a tests input.
    pub rows: Option<Vec<TestView>>,
}

pub(super) struct TestView {
    pub model_a: String,
    pub model_b: String,
    pub test: String,
    pub statistic: String,
    pub dof: String,
    pub p_value: String,
    /// p < 0.05, shown in bold.
    pub significant: bool,
}

fn tests_section(data: &ReportData, heading: Heading) -> TestsSection {
    TestsSection {
        heading,
        paper: data.compare_with_paper,
        rows: data.tests.as_ref().map(|tests| {
            tests
                .iter()
                .map(|t| TestView {
                    model_a: t.model_a.clone(),
                    model_b: t.model_b.clone(),
                    test: t.test.clone(),
                    statistic: format!("{:.4}", t.statistic),
                    dof: t.dof.map_or("—".into(), |d| format!("{d:.1}")),
                    p_value: p_value(t.p_value),
                    significant: t.p_value < 0.05,
                })
                .collect()
        }),
    }
}

/// Section 11: where each input came from, and the report's settings.
pub(super) struct ProvenanceSection<'a> {
    pub heading: Heading,
    pub histogram_bins: usize,
    pub truth_model: &'a str,
    pub model: Option<&'a str>,
    pub tolerance_mm: String,
    pub criterion: &'static str,
    pub compare_with_paper: bool,
    pub groups: Vec<ProvenanceGroup<'a>>,
}

/// Inputs written by the same stage run: they share one provenance.
pub(super) struct ProvenanceGroup<'a> {
    pub sources: Vec<&'a InputSource>,
    pub stage_id: Option<&'a str>,
    pub provenance: Result<Option<&'a Provenance>, &'a str>,
}

fn provenance_section(data: &ReportData, heading: Heading) -> ProvenanceSection<'_> {
    let mut groups: Vec<ProvenanceGroup> = Vec::new();
    for source in &data.sources {
        let same = groups.iter_mut().find(|g| {
            matches!((&g.provenance, &source.provenance), (Ok(Some(a)), Ok(Some(b))) if *a == b)
        });
        match same {
            Some(group) => group.sources.push(source),
            None => {
                let provenance = match &source.provenance {
                    Ok(p) => Ok(p.as_ref()),
                    Err(e) => Err(e.as_str()),
                };
                groups.push(ProvenanceGroup {
                    sources: vec![source],
                    stage_id: provenance
                        .ok()
                        .flatten()
                        .map(|p: &Provenance| p.stage_id.as_str()),
                    provenance,
                });
            }
        }
    }
    ProvenanceSection {
        heading,
        histogram_bins: data.histogram_bins,
        truth_model: &data.truth_model,
        model: data.verdict.model.as_deref(),
        tolerance_mm: data
            .verdict
            .tolerance_mm
            .map_or_else(|| "not set".to_string(), |t| t.to_string()),
        criterion: data.verdict.criterion.as_str(),
        compare_with_paper: data.compare_with_paper,
        groups,
    }
}
