//! A small SVG plotter for log-log charts: one panel per scene, one line per series, the
//! Pareto front drawn dashed, the reference's own error as a dotted floor. Hand-written so the
//! chart needs no fonts and no plotting crate; it draws nothing but these charts.

use std::fmt::Write as _;

pub struct Series {
    pub name: String,
    /// (x, y) with both positive; drawn in the given order.
    pub points: Vec<(f64, f64)>,
}

pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
    pub front: Vec<(f64, f64)>,
    /// A horizontal floor line (the reference's estimated error); 0 for none.
    pub floor: f64,
}

const PALETTE: [&str; 14] = [
    "#7f7f7f", "#8c564b", "#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#17becf",
    "#e377c2", "#bcbd22", "#000000", "#aec7e8", "#ffbb78", "#98df8a",
];
const W: f64 = 470.0;
const H: f64 = 330.0;
const LEFT: f64 = 62.0;
const RIGHT: f64 = 14.0;
const TOP: f64 = 28.0;
const BOTTOM: f64 = 44.0;
const COLS: usize = 2;
const LEGEND_ROW: f64 = 16.0;

/// Log-scale axis over the data's range, widened to whole decades' halves.
struct Axis {
    lo: f64,
    hi: f64,
}

impl Axis {
    fn fit(values: impl Iterator<Item = f64>) -> Axis {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values.filter(|v| *v > 0.0 && v.is_finite()) {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() {
            return Axis { lo: 0.0, hi: 1.0 };
        }
        let (mut l, mut h) = (lo.log10() - 0.1, hi.log10() + 0.1);
        if h - l < 1.0 {
            let mid = (h + l) / 2.0;
            l = mid - 0.5;
            h = mid + 0.5;
        }
        Axis { lo: l, hi: h }
    }

    /// Position in `[0, 1]` of a value.
    fn at(&self, v: f64) -> f64 {
        (v.max(1e-300).log10() - self.lo) / (self.hi - self.lo)
    }

    /// Tick values: 1, 2 and 5 times powers of ten inside the range.
    fn ticks(&self) -> Vec<(f64, bool)> {
        let mut t = Vec::new();
        for e in (self.lo.floor() as i32)..=(self.hi.ceil() as i32) {
            for (m, major) in [(1.0, true), (2.0, false), (5.0, false)] {
                let v = m * 10f64.powi(e);
                let l = v.log10();
                if l >= self.lo && l <= self.hi {
                    t.push((v, major));
                }
            }
        }
        t
    }
}

fn label(v: f64) -> String {
    if (1e-2..1e4).contains(&v) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The width of a legend entry: its line and mark, and its name at about 6.5 px a letter.
fn legend_entry_width(name: &str) -> f64 {
    34.0 + 6.5 * name.len() as f64
}

/// The chart as an SVG document.
pub fn render(panels: &[Panel]) -> String {
    let mut names: Vec<&str> = Vec::new();
    for p in panels {
        for s in &p.series {
            if !names.contains(&s.name.as_str()) {
                names.push(&s.name);
            }
        }
    }
    let color = |name: &str| {
        let i = names.iter().position(|n| *n == name).unwrap_or(0);
        PALETTE[i % PALETTE.len()]
    };
    let rows = panels.len().div_ceil(COLS);
    let width = W * COLS as f64;
    // The legend's rows of entries (as laid out below), then the row of the marks' key.
    let mut legend_rows = 1;
    let mut x = 12.0;
    for name in &names {
        let w = legend_entry_width(name);
        if x + w > width - 12.0 {
            x = 12.0;
            legend_rows += 1;
        }
        x += w;
    }
    let legend = 54.0 + LEGEND_ROW * f64::from(legend_rows - 1);
    let height = legend + H * rows as f64;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(
        s,
        r#"<rect width="{width}" height="{height}" fill="white"/>"#
    );
    // Legend: one entry per family, in as many rows as they need, then the marks' key.
    let mut x = 12.0;
    let mut y = 16.0;
    for name in &names {
        let c = color(name);
        let w = legend_entry_width(name);
        if x + w > width - 12.0 {
            x = 12.0;
            y += LEGEND_ROW;
        }
        let _ = writeln!(
            s,
            r#"<line x1="{x}" y1="{y}" x2="{}" y2="{y}" stroke="{c}" stroke-width="2"/><circle cx="{}" cy="{y}" r="3" fill="{c}"/><text x="{}" y="{}">{}</text>"#,
            x + 22.0,
            x + 11.0,
            x + 27.0,
            y + 4.0,
            escape(name)
        );
        x += w;
    }
    let (y, ty) = (y + 22.0, y + 26.0);
    let _ = writeln!(
        s,
        r##"<line x1="12" y1="{y}" x2="34" y2="{y}" stroke="black" stroke-dasharray="5,3"/><circle cx="23" cy="{y}" r="5" fill="none" stroke="black"/><text x="40" y="{ty}">Pareto front</text><line x1="140" y1="{y}" x2="162" y2="{y}" stroke="#999" stroke-dasharray="1,3"/><text x="168" y="{ty}">reference's own error (estimated)</text><text x="{}" y="{ty}" text-anchor="end">x: time, ms (one thread) · y: RMS error, linear RGB</text>"##,
        width - 12.0
    );
    for (k, p) in panels.iter().enumerate() {
        let ox = W * (k % COLS) as f64;
        let oy = legend + H * (k / COLS) as f64;
        draw_panel(&mut s, p, ox, oy, &color);
    }
    s.push_str("</svg>\n");
    s
}

fn draw_panel(s: &mut String, p: &Panel, ox: f64, oy: f64, color: &dyn Fn(&str) -> &'static str) {
    let all = || p.series.iter().flat_map(|se| se.points.iter());
    let xa = Axis::fit(all().map(|q| q.0));
    let ya = Axis::fit(all().map(|q| q.1).chain((p.floor > 0.0).then_some(p.floor)));
    let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let px = |v: f64| ox + LEFT + xa.at(v) * pw;
    let py = |v: f64| oy + TOP + (1.0 - ya.at(v)) * ph;
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" font-weight="bold" font-size="13">{}</text>"#,
        ox + LEFT,
        oy + TOP - 9.0,
        escape(&p.title)
    );
    let _ = writeln!(
        s,
        r##"<rect x="{}" y="{}" width="{pw}" height="{ph}" fill="none" stroke="#444"/>"##,
        ox + LEFT,
        oy + TOP
    );
    for (v, major) in xa.ticks() {
        let x = px(v);
        let shade = if major { "#ccc" } else { "#eee" };
        let _ = writeln!(
            s,
            r#"<line x1="{x}" y1="{}" x2="{x}" y2="{}" stroke="{shade}"/>"#,
            oy + TOP,
            oy + TOP + ph
        );
        if major || xa.hi - xa.lo < 2.5 {
            let _ = writeln!(
                s,
                r#"<text x="{x}" y="{}" text-anchor="middle">{}</text>"#,
                oy + TOP + ph + 14.0,
                label(v)
            );
        }
    }
    for (v, major) in ya.ticks() {
        let y = py(v);
        let shade = if major { "#ccc" } else { "#eee" };
        let _ = writeln!(
            s,
            r#"<line x1="{}" y1="{y}" x2="{}" y2="{y}" stroke="{shade}"/>"#,
            ox + LEFT,
            ox + LEFT + pw
        );
        if major || ya.hi - ya.lo < 2.5 {
            let _ = writeln!(
                s,
                r#"<text x="{}" y="{}" text-anchor="end">{}</text>"#,
                ox + LEFT - 4.0,
                y + 4.0,
                label(v)
            );
        }
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">time (ms)</text>"#,
        ox + LEFT + pw / 2.0,
        oy + H - 10.0
    );
    let _ = writeln!(
        s,
        r#"<text transform="translate({},{}) rotate(-90)" text-anchor="middle">RMS error</text>"#,
        ox + 14.0,
        oy + TOP + ph / 2.0
    );
    if p.floor > 0.0 {
        let y = py(p.floor);
        let _ = writeln!(
            s,
            r##"<line x1="{}" y1="{y}" x2="{}" y2="{y}" stroke="#999" stroke-dasharray="1,3"/>"##,
            ox + LEFT,
            ox + LEFT + pw
        );
    }
    for se in &p.series {
        let c = color(&se.name);
        let pts: Vec<String> = se
            .points
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", px(x), py(y)))
            .collect();
        if pts.len() > 1 {
            let _ = writeln!(
                s,
                r#"<polyline points="{}" fill="none" stroke="{c}" stroke-width="1.6"/>"#,
                pts.join(" ")
            );
        }
        for &(x, y) in &se.points {
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{c}"/>"#,
                px(x),
                py(y)
            );
        }
    }
    if !p.front.is_empty() {
        // A staircase: each front point holds its error until the next, faster-to-slower.
        let mut d = String::new();
        for (i, &(x, y)) in p.front.iter().enumerate() {
            if i == 0 {
                let _ = write!(d, "M{:.1},{:.1}", px(x), py(y));
            } else {
                let _ = write!(d, " H{:.1} V{:.1}", px(x), py(y));
            }
        }
        let _ = writeln!(
            s,
            r#"<path d="{d}" fill="none" stroke="black" stroke-dasharray="5,3"/>"#
        );
        for &(x, y) in &p.front {
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="5.5" fill="none" stroke="black"/>"#,
                px(x),
                py(y)
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_axis_maps_decades_linearly() {
        let a = Axis { lo: -2.0, hi: 1.0 };
        assert!((a.at(0.01) - 0.0).abs() < 1e-12);
        assert!((a.at(10.0) - 1.0).abs() < 1e-12);
        assert!((a.at(0.1) - 1.0 / 3.0).abs() < 1e-12);
        let ticks: Vec<f64> = a.ticks().iter().filter(|t| t.1).map(|t| t.0).collect();
        assert_eq!(ticks, vec![0.01, 0.1, 1.0, 10.0]);
    }

    #[test]
    fn renders_a_well_formed_document_with_every_series() {
        let panel = Panel {
            title: "a < b".into(),
            series: vec![
                Series {
                    name: "jitter".into(),
                    points: vec![(1.0, 0.1), (4.0, 0.03)],
                },
                Series {
                    name: "adaptive t=0.03".into(),
                    points: vec![(2.0, 0.02)],
                },
            ],
            front: vec![(1.0, 0.1), (2.0, 0.02)],
            floor: 0.001,
        };
        let svg = render(&[panel]);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("a &lt; b"));
        assert_eq!(
            svg.matches("<polyline").count(),
            1,
            "one line per series of 2+ points"
        );
        assert!(svg.contains(">jitter<") && svg.contains(">adaptive t=0.03<"));
        assert!(!svg.contains("NaN") && !svg.contains("inf"));
    }

    #[test]
    fn a_long_legend_wraps_into_rows_and_keeps_one_colour_per_family() {
        let names = [
            "center",
            "thesis",
            "grid",
            "jitter",
            "adaptive t=0.3",
            "adaptive t=0.2",
            "adaptive t=0.1",
            "adaptive t=0.07",
            "adaptive t=0.05",
            "adaptive t=0.03",
            "adaptive t=0.01",
            "POV-Ray AM1",
            "POV-Ray AM2",
        ];
        let panel = Panel {
            title: "p".into(),
            series: names
                .iter()
                .map(|n| Series {
                    name: (*n).into(),
                    points: vec![(1.0, 0.1)],
                })
                .collect(),
            front: vec![],
            floor: 0.0,
        };
        let svg = render(&[panel]);
        let width = W * COLS as f64;
        // Legend entries are the lines drawn 2 px wide: (x1, y1, stroke).
        let attr = |line: &str, key: &str| -> String {
            let from = line.find(&format!(" {key}=\"")).expect("attribute present") + key.len() + 3;
            line[from..]
                .split('"')
                .next()
                .expect("closing quote")
                .to_string()
        };
        let entries: Vec<(f64, f64, String)> = svg
            .lines()
            .filter(|l| l.starts_with("<line") && l.contains("stroke-width=\"2\""))
            .map(|l| {
                let num = |k| attr(l, k).parse::<f64>().expect("a number");
                (num("x1"), num("y1"), attr(l, "stroke"))
            })
            .collect();
        assert_eq!(entries.len(), names.len());
        let mut colours: Vec<&str> = entries.iter().map(|e| e.2.as_str()).collect();
        colours.sort_unstable();
        colours.dedup();
        assert_eq!(colours.len(), names.len(), "a colour per family");
        let rows: Vec<f64> = entries.iter().map(|e| e.1).collect();
        assert!(rows.windows(2).any(|w| w[1] > w[0]), "wrapped: {rows:?}");
        for (e, name) in entries.iter().zip(names) {
            assert!(
                e.0 + legend_entry_width(name) <= width - 12.0 + 1e-9,
                "{name} overflows"
            );
        }
        for pair in entries.windows(2) {
            let same_row = pair[0].1 == pair[1].1;
            assert!(!same_row || pair[1].0 > pair[0].0, "entries overlap");
        }
    }
}
