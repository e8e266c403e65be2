//! Draws the scaling curve of `benches/scaling.sh` as an SVG: build time per
//! triangle against the number of triangles (log scale), for the whole
//! build with one thread and for the stages after parsing with one and two
//! threads. A flat line is time growing linearly with triangles.
//!
//! ```text
//! cargo run --release --example scaling_svg -- ROWS.csv OUT.svg
//! ```
//!
//! `ROWS.csv` is what `SVG=OUT.svg bash benches/scaling.sh` writes and
//! passes here: one line per input, `name,triangles,whole_1_ms,after_1_ms,
//! whole_2_ms,after_2_ms` (fastest of its runs). Inputs named `scene` make
//! the lines; any other input (the Stanford dragon) is drawn as points of
//! its own. The SVG goes to a temporary file first, renamed into place.

use plotters::prelude::*;
use std::path::Path;

/// One input's row of the scaling table.
struct Row {
    name: String,
    triangles: f64,
    /// ns per triangle: whole build with one thread, after parsing with
    /// one thread, after parsing with two threads.
    ns: [f64; 3],
}

/// Parses `ROWS.csv`, naming the file and the line in any error.
fn read_rows(path: &Path) -> Result<Vec<Row>, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let mut rows = Vec::new();
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let bad = |what: &str| format!("{}: line {}: {what}: {line:?}", path.display(), i + 1);
        let f: Vec<&str> = line.split(',').collect();
        let [name, n, w1, a1, _w2, a2] = f[..] else {
            return Err(bad("expected 6 comma-separated fields"));
        };
        let num = |s: &str| -> Result<f64, String> {
            s.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| bad("not a positive number"))
        };
        let triangles = num(n)?;
        let per = |ms: f64| ms * 1e6 / triangles;
        rows.push(Row {
            name: name.trim().to_string(),
            triangles,
            ns: [per(num(w1)?), per(num(a1)?), per(num(a2)?)],
        });
    }
    if rows.is_empty() {
        return Err(format!("{}: no rows", path.display()));
    }
    Ok(rows)
}

/// The chart as an SVG string.
fn draw(rows: &[Row]) -> Result<String, String> {
    let (lo, hi) = rows.iter().fold((f64::MAX, 0f64), |(lo, hi), r| {
        (lo.min(r.triangles), hi.max(r.triangles))
    });
    let ymax = rows.iter().flat_map(|r| r.ns).fold(0.0, f64::max) * 1.15;
    svpack::report::svg_chart((720, 440), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(
                "svpack build: time per triangle against size",
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d((lo / 1.5..hi * 1.5).log_scale(), 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc("triangles (log scale)")
            .y_desc("ns per triangle")
            .y_label_formatter(&|v| format!("{v:.0}"))
            .x_label_formatter(&|v| {
                if *v >= 1e6 {
                    format!("{}M", v / 1e6)
                } else {
                    format!("{}k", v / 1e3)
                }
            })
            .draw()?;
        let series = [
            ("whole build (OBJ parse included), 1 thread", BLUE),
            ("after parsing, 1 thread", RED),
            ("after parsing, 2 threads", GREEN),
        ];
        let scenes: Vec<&Row> = rows.iter().filter(|r| r.name == "scene").collect();
        for (s, (label, color)) in series.into_iter().enumerate() {
            let pts: Vec<(f64, f64)> = scenes.iter().map(|r| (r.triangles, r.ns[s])).collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            chart.draw_series(pts.iter().map(|&c| Circle::new(c, 4, color.filled())))?;
            // Other inputs (the dragon): rings in the series' colour.
            chart.draw_series(
                rows.iter()
                    .filter(|r| r.name != "scene")
                    .map(|r| Circle::new((r.triangles, r.ns[s]), 7, color.stroke_width(2))),
            )?;
        }
        for r in rows.iter().filter(|r| r.name != "scene") {
            chart.draw_series(std::iter::once(
                EmptyElement::at((r.triangles, r.ns[0]))
                    + Text::new(
                        r.name.clone(),
                        (10, -18),
                        ("sans-serif", 13).into_font().color(&BLACK),
                    ),
            ))?;
        }
        svpack::report::chart_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        Ok(())
    })
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [rows, out] = &args[..] else {
        eprintln!("usage: scaling_svg ROWS.csv OUT.svg");
        std::process::exit(2);
    };
    let out = Path::new(out);
    let svg = read_rows(Path::new(rows)).and_then(|r| draw(&r));
    let written = svg.and_then(|svg| {
        let tmp = out.with_extension("svg.tmp");
        std::fs::write(&tmp, svg)
            .and_then(|()| std::fs::rename(&tmp, out))
            .map_err(|e| format!("{}: cannot write: {e}", out.display()))
    });
    if let Err(e) = written {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
