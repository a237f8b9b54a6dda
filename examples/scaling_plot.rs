//! Draws the README's scaling chart from `benches/scaling.sh`'s table:
//! `cargo run --release --example scaling_plot -- assets/scaling.csv assets/scaling.svg`.
//!
//! Two log-log panels, wall time and peak memory against size, one line per
//! workload (`what`), so linear growth shows as a line of slope one.

use std::collections::BTreeMap;
use std::error::Error;

use plotters::prelude::*;

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// One measured point: size, seconds, peak memory (MB).
type Point = (f64, f64, f64);

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: scaling_plot TABLE.csv OUT.svg";
    let (table, out) = (args.next().ok_or(usage)?, args.next().ok_or(usage)?);
    let mut series: BTreeMap<String, Vec<Point>> = BTreeMap::new();
    for (number, line) in std::fs::read_to_string(&table)?.lines().enumerate().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        let [what, size, seconds, rss_mb] = fields[..] else {
            return Err(format!(
                "{table}:{}: expected what,size,seconds,max_rss_mb",
                number + 1
            )
            .into());
        };
        series.entry(what.to_string()).or_default().push((
            size.parse()?,
            seconds.parse()?,
            rss_mb.parse()?,
        ));
    }
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
        .map_err(|_| "the font could not be registered")?;
    let root = SVGBackend::new(&out, (1000, 420)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((1, 2));
    let colours = [BLUE, RED, GREEN, MAGENTA];
    for (panel, (title, value)) in panels.iter().zip([
        ("wall time (s)", (|p: &Point| p.1) as fn(&Point) -> f64),
        ("peak memory (MB)", |p: &Point| p.2),
    ]) {
        let all = series.values().flatten();
        let (x_lo, x_hi) = all
            .clone()
            .fold((f64::MAX, 0.0_f64), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (y_lo, y_hi) = all.fold((f64::MAX, 0.0_f64), |(a, b), p| {
            (a.min(value(p)), b.max(value(p)))
        });
        let mut chart = ChartBuilder::on(panel)
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                (x_lo / 2.0..x_hi * 2.0).log_scale(),
                (y_lo / 2.0..y_hi * 2.0).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc("rows or candidates")
            .x_label_formatter(&|x| format!("{x:.0e}"))
            .y_label_formatter(&|y| format!("{y}"))
            .label_style(("sans-serif", 12))
            .draw()?;
        for ((what, points), colour) in series.iter().zip(colours.iter().cycle()) {
            let line: Vec<(f64, f64)> = points.iter().map(|p| (p.0, value(p))).collect();
            chart
                .draw_series(LineSeries::new(line.clone(), colour.stroke_width(2)))?
                .label(what.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                });
            chart.draw_series(line.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 12))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    root.present()?;
    println!("wrote {out}");
    Ok(())
}
