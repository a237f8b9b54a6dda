//! The report's charts, drawn with plotters into SVG strings.
//!
//! Every function takes plain numbers and returns a complete `<svg>` element (or a
//! message saying why it could not be drawn). The output depends on the inputs
//! only: no clock, no randomness, no hash-map order.
//!
//! plotters' `ab_glyph` backend measures text with a registered font; the font
//! (DejaVu Sans, `assets/fonts/`) is embedded in the binary and registered once
//! under the family name `sans-serif`. The SVG names that family, so the viewer
//! draws the text with its own sans-serif font.

use std::error::Error;
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

/// DejaVu Sans; licence in `assets/fonts/LICENSE`.
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// The family every chart uses.
const FAMILY: &str = "sans-serif";

type DrawResult = Result<(), Box<dyn Error>>;

/// Registers the embedded font with plotters, once per process.
fn ensure_font() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FAMILY, plotters::style::FontStyle::Normal, FONT).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded font could not be registered".into())
    }
}

/// Renders one chart of `size` pixels into an SVG string.
fn render<F>(size: (u32, u32), label: &str, draw: F) -> Result<String, String>
where
    F: FnOnce(&DrawingArea<SVGBackend, Shift>) -> DrawResult,
{
    ensure_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        draw(&root).map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    // Accessible name, and a class the page's CSS scales by.
    let attributes = format!(
        "<svg class=\"chart\" role=\"img\" aria-label=\"{}\" ",
        super::escape(label)
    );
    Ok(svg.replacen("<svg ", &attributes, 1))
}

fn font(size: u32) -> TextStyle<'static> {
    (FAMILY, size).into_font().into()
}

/// Short tick label: three significant digits, no trailing zeros.
pub fn short(value: f64) -> String {
    if value == 0.0 || !value.is_finite() {
        return if value.is_finite() {
            "0".into()
        } else {
            value.to_string()
        };
    }
    let digits = (2 - value.abs().log10().floor() as i32).clamp(0, 12) as usize;
    let text = format!("{value:.digits$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// Bin edges and counts of `values` over [lo, hi] in `bins` equal bins.
pub fn bin_counts(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<u32> {
    let bins = bins.max(1);
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0u32; bins];
    for &v in values {
        if !v.is_finite() || width <= 0.0 {
            continue;
        }
        let k = (((v - lo) / width).floor().max(0.0) as usize).min(bins - 1);
        counts[k] += 1;
    }
    counts
}

/// The range a histogram of `values` spans: from 0 (errors are norms) to the
/// largest value, widened when every value is the same.
pub fn histogram_range(values: &[f64]) -> (f64, f64) {
    let finite = values.iter().copied().filter(|v| v.is_finite());
    let (min, max) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    if !min.is_finite() {
        return (0.0, 1.0);
    }
    let lo = min.min(0.0);
    let hi = if max > lo {
        max
    } else {
        lo + max.abs().max(1.0)
    };
    (lo, hi)
}

/// One histogram series: a name, its colour and its values.
pub struct HistogramSeries<'a> {
    pub name: &'a str,
    pub color: RGBColor,
    pub values: &'a [f64],
}

/// Histogram of error norms, several series overlaid on the same bins (Fig. 7).
pub fn histogram(
    title: &str,
    series: &[HistogramSeries],
    bins: usize,
    size: (u32, u32),
) -> Result<String, String> {
    let all: Vec<f64> = series
        .iter()
        .flat_map(|s| s.values.iter().copied())
        .collect();
    let (lo, hi) = histogram_range(&all);
    let bins = bins.max(1);
    let width = (hi - lo) / bins as f64;
    let counts: Vec<Vec<u32>> = series
        .iter()
        .map(|s| bin_counts(s.values, lo, hi, bins))
        .collect();
    let top = counts.iter().flatten().copied().max().unwrap_or(0).max(1);
    let overlaid = series.len() > 1;
    render(size, title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, font(17))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(52)
            .build_cartesian_2d(lo..hi, 0f64..(f64::from(top) * 1.12))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .max_light_lines(2)
            .light_line_style(BLACK.mix(0.05))
            .bold_line_style(BLACK.mix(0.12))
            .x_desc("position error (mm)")
            .y_desc("validation rows")
            .axis_desc_style(font(14))
            .label_style(font(12))
            .x_label_formatter(&|v| short(*v))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        for (s, counts) in series.iter().zip(&counts) {
            let fill = if overlaid {
                s.color.mix(0.45)
            } else {
                s.color.mix(0.75)
            };
            let color = s.color;
            chart
                .draw_series(
                    counts
                        .iter()
                        .enumerate()
                        .filter(|(_, c)| **c > 0)
                        .map(|(k, c)| {
                            let x0 = lo + width * k as f64;
                            Rectangle::new([(x0, 0.0), (x0 + width, f64::from(*c))], fill.filled())
                        }),
                )?
                .label(s.name)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 14, y + 6)], color.mix(0.6).filled())
                });
            chart.draw_series(counts.iter().enumerate().filter(|(_, c)| **c > 0).map(
                |(k, c)| {
                    let x0 = lo + width * k as f64;
                    Rectangle::new(
                        [(x0, 0.0), (x0 + width, f64::from(*c))],
                        color.stroke_width(1),
                    )
                },
            ))?;
        }
        if overlaid {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.9))
                .border_style(BLACK.mix(0.4))
                .label_font(font(13))
                .draw()?;
        }
        Ok(())
    })
}

/// One line of a line chart: (iteration, value) points.
pub struct LineSeries2<'a> {
    pub name: &'a str,
    pub color: RGBColor,
    pub points: Vec<(i64, f64)>,
}

/// Axis texts of a line chart.
pub struct Axes<'a> {
    pub title: &'a str,
    pub x: &'a str,
    pub y: &'a str,
}

/// The x range of integer points, widened when it is a single value.
fn x_extent(series: &[LineSeries2]) -> (i64, i64) {
    let xs = series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let (lo, hi) = xs.fold((i64::MAX, i64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        (0, 1)
    } else if hi > lo {
        (lo, hi)
    } else {
        (lo - 1, lo + 1)
    }
}

/// Line chart with markers on a linear y axis (the DETMAX O1 trace).
pub fn line_chart(axes: &Axes, series: &[LineSeries2], size: (u32, u32)) -> Result<String, String> {
    let (x_lo, x_hi) = x_extent(series);
    let ys = series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
    let (y_min, y_max) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    let (y_lo, y_hi) = if !y_min.is_finite() {
        (0.0, 1.0)
    } else if y_max > y_min {
        let pad = (y_max - y_min) * 0.08;
        (y_min - pad, y_max + pad)
    } else {
        let pad = y_min.abs().max(1e-12) * 0.05;
        (y_min - pad, y_max + pad)
    };
    render(size, axes.title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(axes.title, font(17))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(70)
            .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)?;
        chart
            .configure_mesh()
            .max_light_lines(2)
            .light_line_style(BLACK.mix(0.05))
            .bold_line_style(BLACK.mix(0.12))
            .x_desc(axes.x)
            .y_desc(axes.y)
            .axis_desc_style(font(14))
            .label_style(font(12))
            .x_label_formatter(&|v| v.to_string())
            .y_label_formatter(&|v| short(*v))
            .draw()?;
        draw_lines(&mut chart, series)?;
        Ok(())
    })
}

/// Line chart with markers on a logarithmic y axis (identification convergence).
pub fn log_line_chart(
    axes: &Axes,
    series: &[LineSeries2],
    size: (u32, u32),
) -> Result<String, String> {
    let (x_lo, x_hi) = x_extent(series);
    let ys = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.1))
        .filter(|v| *v > 0.0 && v.is_finite());
    let (y_min, y_max) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    let (y_lo, y_hi) = if y_min.is_finite() {
        (y_min / 1.6, y_max * 1.6)
    } else {
        (0.1, 10.0)
    };
    // Values a log axis cannot show are drawn at its floor.
    let floor = |v: f64| if v > 0.0 && v.is_finite() { v } else { y_lo };
    let clamped: Vec<LineSeries2> = series
        .iter()
        .map(|s| LineSeries2 {
            name: s.name,
            color: s.color,
            points: s.points.iter().map(|&(x, y)| (x, floor(y))).collect(),
        })
        .collect();
    render(size, axes.title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(axes.title, font(17))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(70)
            .build_cartesian_2d(x_lo..x_hi, (y_lo..y_hi).log_scale())?;
        chart
            .configure_mesh()
            .max_light_lines(2)
            .light_line_style(BLACK.mix(0.05))
            .bold_line_style(BLACK.mix(0.12))
            .x_desc(axes.x)
            .y_desc(axes.y)
            .axis_desc_style(font(14))
            .label_style(font(12))
            .x_label_formatter(&|v| v.to_string())
            .y_label_formatter(&|v| short(*v))
            .draw()?;
        draw_lines(&mut chart, &clamped)?;
        Ok(())
    })
}

fn draw_lines<'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    series: &[LineSeries2],
) -> DrawResult
where
    X: Ranged<ValueType = i64>,
    Y: Ranged<ValueType = f64>,
{
    for s in series {
        let color = s.color;
        chart
            .draw_series(LineSeries::new(
                s.points.iter().copied(),
                color.stroke_width(2),
            ))?
            .label(s.name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
    }
    if series.len() > 1 {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.4))
            .label_font(font(13))
            .draw()?;
    }
    Ok(())
}

/// A target point (base frame, mm) and the unit tool z axis (the SMR axis) there.
pub struct PosePoint {
    pub position: [f64; 3],
    pub axis: [f64; 3],
}

/// 3-D view of the poses (Fig. 4): target points with a short tick along each
/// tool z axis, equal scales on the three axes. Base z is drawn vertical.
pub fn poses_3d(title: &str, poses: &[PosePoint], size: (u32, u32)) -> Result<String, String> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in poses {
        for i in 0..3 {
            lo[i] = lo[i].min(p.position[i]);
            hi[i] = hi[i].max(p.position[i]);
        }
    }
    if !lo[0].is_finite() {
        return Err("no poses".into());
    }
    let span = (0..3).map(|i| hi[i] - lo[i]).fold(0.0, f64::max).max(1.0);
    let tick = span * 0.09;
    let half = span / 2.0 + tick * 1.2;
    let range = |i: usize| {
        let centre = (lo[i] + hi[i]) / 2.0;
        (centre - half)..(centre + half)
    };
    let (rx, ry, rz) = (range(0), range(1), range(2));
    // plotters' 3-D coordinates are (X, Y vertical, Z depth), drawn right-handed.
    // Base (x, y, z) → (X, Y, Z) = (y, z, x): a rotation, so the view is not mirrored.
    let at = |p: [f64; 3]| (p[1], p[2], p[0]);
    // The x and y tick labels meet at the front corner: leave out those next to it.
    let corner_free = |v: f64, end: f64| {
        if end - v < 0.08 * 2.0 * half {
            String::new()
        } else {
            format!("{v:.0}")
        }
    };
    render(size, title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, font(17))
            .margin(16)
            .build_cartesian_3d(ry.clone(), rz.clone(), rx.clone())?;
        chart.with_projection(|mut pb| {
            pb.yaw = 0.65;
            pb.pitch = 0.3;
            pb.scale = 0.8;
            pb.into_matrix()
        });
        chart
            .configure_axes()
            .light_grid_style(BLACK.mix(0.06))
            .bold_grid_style(BLACK.mix(0.15))
            .max_light_lines(2)
            .label_style(font(11))
            .x_formatter(&|v| corner_free(*v, ry.end))
            .y_formatter(&|v| format!("{v:.0}"))
            .z_formatter(&|v| corner_free(*v, rx.end))
            .draw()?;
        // Axis names beside the edges that carry the tick labels with this projection.
        let out = 2.0 * half * 0.22;
        let mid = |r: &std::ops::Range<f64>| (r.start + r.end) / 2.0;
        let names = [
            ("y (mm)", (mid(&ry), rz.start, rx.end + out)),
            ("x (mm)", (ry.end + out, rz.start, mid(&rx))),
            ("z (mm)", (ry.start, rz.end + out * 0.3, rx.end)),
        ];
        chart.draw_series(
            names
                .iter()
                .map(|(name, p)| Text::new(name.to_string(), *p, font(14).color(&BLACK))),
        )?;
        let axis_color = RGBColor(230, 120, 20);
        chart
            .draw_series(poses.iter().map(|p| {
                let end = [0, 1, 2].map(|i| p.position[i] + tick * p.axis[i]);
                PathElement::new(vec![at(p.position), at(end)], axis_color.stroke_width(2))
            }))?
            .label("tool z axis (SMR axis)")
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], axis_color.stroke_width(2))
            });
        let point_color = RGBColor(31, 90, 170);
        chart
            .draw_series(
                poses
                    .iter()
                    .map(|p| Circle::new(at(p.position), 3, point_color.filled())),
            )?
            .label("target point")
            .legend(move |(x, y)| Circle::new((x + 9, y), 4, point_color.filled()));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK.mix(0.4))
            .label_font(font(13))
            .draw()?;
        Ok(())
    })
}

/// One cell of a heat map: its centre (mm) and value, `None` where there is none
/// (drawn grey).
pub struct HeatCell {
    pub x: f64,
    pub y: f64,
    pub value: Option<f64>,
}

/// What a heat map draws besides its cells.
pub struct HeatMap<'a> {
    pub title: &'a str,
    pub x: &'a str,
    pub y: &'a str,
    /// Name of the value, for the colour bar.
    pub value: &'a str,
    /// The colour scale's ends (shared by the slices of one map).
    pub value_range: (f64, f64),
    /// Cell width and height (mm).
    pub cell_mm: (f64, f64),
    /// Points drawn over the cells (the calibration positions).
    pub overlay: &'a [(f64, f64)],
    /// A rectangle outlined over the cells: lower and upper corners (the box
    /// the overlay points span).
    pub outline: Option<((f64, f64), (f64, f64))>,
}

/// The viridis colour map at `t` in [0, 1], from nine of its colours: perceptually
/// even and legible in grey, so low and high read the same for every reader.
pub fn viridis(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 9] = [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let scaled = t * (STOPS.len() - 1) as f64;
    let k = (scaled.floor() as usize).min(STOPS.len() - 2);
    let f = scaled - k as f64;
    let mix = |a: u8, b: u8| (a as f64 + (b as f64 - a as f64) * f).round() as u8;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// A heat map of cells on a regular grid with a colour bar, points and a
/// rectangle drawn over it; equal scales are not enforced (the page's width is).
pub fn heat_map(map: &HeatMap, cells: &[HeatCell], size: (u32, u32)) -> Result<String, String> {
    let (dx, dy) = map.cell_mm;
    let (x_lo, x_hi, y_lo, y_hi) = cells.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), cell| (a.min(cell.x), b.max(cell.x), c.min(cell.y), d.max(cell.y)),
    );
    if !x_lo.is_finite() || !y_lo.is_finite() {
        return Err("no grid points".into());
    }
    let (x_lo, x_hi, y_lo, y_hi) = (
        x_lo - dx / 2.0,
        x_hi + dx / 2.0,
        y_lo - dy / 2.0,
        y_hi + dy / 2.0,
    );
    let (v_lo, v_hi) = map.value_range;
    let v_hi = if v_hi > v_lo { v_hi } else { v_lo + 1.0 };
    let color_of = |v: f64| viridis((v - v_lo) / (v_hi - v_lo));
    render(size, map.title, |root| {
        let (main, bar) = root.split_horizontally(size.0.saturating_sub(110));
        let mut chart = ChartBuilder::on(&main)
            .caption(map.title, font(17))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(70)
            .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(map.x)
            .y_desc(map.y)
            .axis_desc_style(font(14))
            .label_style(font(12))
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        chart.draw_series(cells.iter().map(|cell| {
            let color = cell.value.map_or(RGBColor(225, 225, 225), color_of);
            Rectangle::new(
                [
                    (cell.x - dx / 2.0, cell.y - dy / 2.0),
                    (cell.x + dx / 2.0, cell.y + dy / 2.0),
                ],
                color.filled(),
            )
        }))?;
        if let Some(((bx_lo, by_lo), (bx_hi, by_hi))) = map.outline {
            chart.draw_series(std::iter::once(Rectangle::new(
                [(bx_lo, by_lo), (bx_hi, by_hi)],
                WHITE.stroke_width(2),
            )))?;
        }
        chart.draw_series(
            map.overlay
                .iter()
                .map(|&p| Circle::new(p, 4, ShapeStyle::from(&RGBColor(214, 39, 40)).filled())),
        )?;
        chart.draw_series(
            map.overlay
                .iter()
                .map(|&p| Circle::new(p, 4, WHITE.stroke_width(1))),
        )?;
        let mut scale = ChartBuilder::on(&bar)
            .margin_top(40)
            .margin_bottom(54)
            .margin_right(8)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..1.0, v_lo..v_hi)?;
        scale
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc(map.value)
            .axis_desc_style(font(13))
            .label_style(font(11))
            .y_label_formatter(&|v| short(*v))
            .draw()?;
        const STEPS: usize = 64;
        let step = (v_hi - v_lo) / STEPS as f64;
        scale.draw_series((0..STEPS).map(|k| {
            let lo = v_lo + step * k as f64;
            Rectangle::new(
                [(0.0, lo), (1.0, lo + step)],
                color_of(lo + step / 2.0).filled(),
            )
        }))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_labels() {
        assert_eq!(short(0.0), "0");
        assert_eq!(short(1327.583), "1328");
        assert_eq!(short(2.5), "2.5");
        assert_eq!(short(0.0005), "0.0005");
        assert_eq!(short(0.12345), "0.123");
        assert_eq!(short(-40.0), "-40");
    }

    #[test]
    fn bins_cover_the_range_and_count_every_value() {
        let values = [0.0, 0.1, 0.5, 0.99, 1.0];
        let counts = bin_counts(&values, 0.0, 1.0, 4);
        assert_eq!(counts, vec![2, 0, 1, 2]);
        assert_eq!(counts.iter().sum::<u32>(), 5);
        assert_eq!(histogram_range(&[2.0, 2.0]), (0.0, 2.0));
        assert_eq!(histogram_range(&[0.0, 0.0]), (0.0, 1.0));
        assert_eq!(histogram_range(&[]), (0.0, 1.0));
    }

    #[test]
    fn charts_are_svg_and_deterministic() {
        let values = [0.1, 0.2, 0.25, 0.4];
        let series = [HistogramSeries {
            name: "a<b",
            color: RGBColor(0, 0, 255),
            values: &values,
        }];
        let one = histogram("t", &series, 5, (400, 300)).unwrap();
        let two = histogram("t", &series, 5, (400, 300)).unwrap();
        assert_eq!(one, two);
        assert!(one.starts_with("<svg class=\"chart\""), "{}", &one[..80]);
        assert!(one.trim_end().ends_with("</svg>"));
        let lines = [LineSeries2 {
            name: "m",
            color: RGBColor(0, 0, 0),
            points: vec![(1, 10.0), (2, 0.1), (3, 0.0)],
        }];
        let axes = Axes {
            title: "c",
            x: "iteration",
            y: "rms",
        };
        assert!(
            log_line_chart(&axes, &lines, (400, 300))
                .unwrap()
                .contains("<polyline")
        );
        assert!(
            line_chart(&axes, &lines, (400, 300))
                .unwrap()
                .contains("<polyline")
        );
        let poses = [
            PosePoint {
                position: [900.0, 0.0, 900.0],
                axis: [0.0, 0.0, 1.0],
            },
            PosePoint {
                position: [1100.0, 200.0, 1100.0],
                axis: [-1.0, 0.0, 0.0],
            },
        ];
        assert!(
            poses_3d("p", &poses, (500, 400))
                .unwrap()
                .contains("<circle")
        );
        assert!(poses_3d("p", &[], (500, 400)).is_err());
        let cells = [
            HeatCell {
                x: 0.0,
                y: 0.0,
                value: Some(0.1),
            },
            HeatCell {
                x: 10.0,
                y: 0.0,
                value: None,
            },
        ];
        let map = HeatMap {
            title: "m",
            x: "x",
            y: "y",
            value: "u95 (mm)",
            value_range: (0.0, 0.2),
            cell_mm: (10.0, 10.0),
            overlay: &[(0.0, 0.0)],
            outline: Some(((0.0, 0.0), (5.0, 5.0))),
        };
        let svg = heat_map(&map, &cells, (600, 400)).unwrap();
        assert!(svg.contains("<circle") && svg.contains("<rect"));
        assert!(heat_map(&map, &[], (600, 400)).is_err());
    }

    #[test]
    fn viridis_runs_from_purple_to_yellow() {
        assert_eq!(viridis(0.0), RGBColor(68, 1, 84));
        assert_eq!(viridis(1.0), RGBColor(253, 231, 37));
        assert_eq!(viridis(2.0), viridis(1.0));
        assert_eq!(viridis(0.5), RGBColor(33, 144, 141));
    }
}
