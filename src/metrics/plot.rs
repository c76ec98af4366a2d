//! Dependency-free SVG line plots: a [`Figure`] is a grid of [`Panel`]s, each with axes, "nice"
//! ticks (1-2-5 steps, or decades on a log-x axis), grid lines, labels, a legend and one polyline
//! with point markers per [`Series`]. Non-finite points are skipped (they break the line).
//!
//! ```
//! use gscodec::metrics::plot::{Figure, Panel, Series};
//! let panel = Panel::new("RD", "bytes", "PSNR (dB)")
//!     .log_x(true)
//!     .series(Series::new("l1ssim", vec![(1e4, 25.0), (1e5, 30.0)]));
//! let svg = Figure::new(vec![panel]).to_svg();
//! assert!(svg.starts_with("<svg") && svg.contains("l1ssim"));
//! ```

use std::fmt::Write;

/// Series colours (Tableau 10), used in order.
pub const PALETTE: [&str; 10] =
    ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"];

/// One named curve.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// (x, y) points, drawn in the given order.
    pub points: Vec<(f64, f64)>,
}

impl Series {
    /// A named series.
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series { name: name.into(), points }
    }
}

/// One set of axes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Panel {
    /// Title above the axes.
    pub title: String,
    /// Label under the x-axis.
    pub x_label: String,
    /// Label left of the y-axis.
    pub y_label: String,
    /// Logarithmic x-axis (non-positive x values are skipped).
    pub log_x: bool,
    /// Curves, coloured in order from [`PALETTE`].
    pub series: Vec<Series>,
}

impl Panel {
    /// An empty panel with a title and axis labels.
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        Panel { title: title.into(), x_label: x_label.into(), y_label: y_label.into(), ..Default::default() }
    }

    /// Sets a logarithmic x-axis.
    pub fn log_x(mut self, on: bool) -> Self {
        self.log_x = on;
        self
    }

    /// Adds a curve.
    pub fn series(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }
}

/// A grid of panels written as one SVG document.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Panels, filled row by row.
    pub panels: Vec<Panel>,
    /// Panels per row.
    pub columns: usize,
    /// Size of one panel in pixels (width, height).
    pub panel_size: (f64, f64),
}

const MARGIN_LEFT: f64 = 64.0;
const MARGIN_RIGHT: f64 = 16.0;
const MARGIN_TOP: f64 = 30.0;
const MARGIN_BOTTOM: f64 = 46.0;

impl Figure {
    /// A figure of the given panels, up to 3 per row, 420×320 px each.
    pub fn new(panels: Vec<Panel>) -> Self {
        let columns = panels.len().clamp(1, 3);
        Figure { panels, columns, panel_size: (420.0, 320.0) }
    }

    /// The SVG document.
    pub fn to_svg(&self) -> String {
        let cols = self.columns.max(1);
        let rows = self.panels.len().div_ceil(cols).max(1);
        let (pw, ph) = self.panel_size;
        let (w, h) = (pw * cols as f64, ph * rows as f64);
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="Helvetica, Arial, sans-serif" font-size="12">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        for (i, panel) in self.panels.iter().enumerate() {
            let (ox, oy) = ((i % cols) as f64 * pw, (i / cols) as f64 * ph);
            draw_panel(&mut s, panel, ox, oy, pw, ph);
        }
        s.push_str("</svg>\n");
        s
    }
}

/// An axis mapping data values to pixels.
struct Axis {
    log: bool,
    lo: f64,
    hi: f64,
    px_lo: f64,
    px_hi: f64,
}

impl Axis {
    fn fit(values: impl Iterator<Item = f64>, log: bool, px_lo: f64, px_hi: f64) -> Self {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values {
            let v = if log { v.log10() } else { v };
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() {
            (lo, hi) = (0.0, 1.0);
        }
        if hi - lo < 1e-12 * lo.abs().max(1e-300) || hi == lo {
            let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
            (lo, hi) = (lo - pad, hi + pad);
        }
        let pad = (hi - lo) * 0.05;
        Axis { log, lo: lo - pad, hi: hi + pad, px_lo, px_hi }
    }

    fn px(&self, v: f64) -> f64 {
        let v = if self.log { v.log10() } else { v };
        self.px_lo + (v - self.lo) / (self.hi - self.lo) * (self.px_hi - self.px_lo)
    }

    /// Tick values (in data units) and their labels.
    fn ticks(&self) -> Vec<(f64, String)> {
        if self.log {
            let (a, b) = (self.lo.floor() as i32, self.hi.ceil() as i32);
            let mults: &[f64] = if self.hi - self.lo < 1.5 { &[1.0, 2.0, 5.0] } else { &[1.0] };
            let mut t = Vec::new();
            for e in a..=b {
                for m in mults {
                    let v = m * 10f64.powi(e);
                    if (self.lo..=self.hi).contains(&v.log10()) {
                        t.push((v, si_label(v)));
                    }
                }
            }
            t
        } else {
            let step = nice_step((self.hi - self.lo) / 8.0);
            let decimals = (-step.log10().floor()).max(0.0) as usize;
            let first = (self.lo / step).ceil() as i64;
            let last = (self.hi / step).floor() as i64;
            (first..=last).map(|k| k as f64 * step).map(|v| (v, format!("{v:.decimals$}"))).collect()
        }
    }
}

/// The 1-2-5 step at or above `raw`.
fn nice_step(raw: f64) -> f64 {
    let p = 10f64.powf(raw.log10().floor());
    let f = raw / p;
    p * if f <= 1.0 {
        1.0
    } else if f <= 2.0 {
        2.0
    } else if f <= 5.0 {
        5.0
    } else {
        10.0
    }
}

/// Compact label for a log-axis tick: 500, 2k, 10M, 0.01.
fn si_label(v: f64) -> String {
    let trim = |x: f64| {
        let s = format!("{x:.2}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    };
    match v.abs() {
        a if a >= 1e9 => format!("{}G", trim(v / 1e9)),
        a if a >= 1e6 => format!("{}M", trim(v / 1e6)),
        a if a >= 1e3 => format!("{}k", trim(v / 1e3)),
        a if a >= 1.0 || a == 0.0 => trim(v),
        _ => format!("{v}"),
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn draw_panel(s: &mut String, panel: &Panel, ox: f64, oy: f64, pw: f64, ph: f64) {
    let (x0, x1) = (ox + MARGIN_LEFT, ox + pw - MARGIN_RIGHT);
    let (y0, y1) = (oy + ph - MARGIN_BOTTOM, oy + MARGIN_TOP);
    let usable = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite() && (!panel.log_x || p.0 > 0.0);
    let points = || panel.series.iter().flat_map(|se| se.points.iter().filter(|p| usable(p)));
    let xa = Axis::fit(points().map(|p| p.0), panel.log_x, x0, x1);
    let ya = Axis::fit(points().map(|p| p.1), false, y0, y1);

    let _ = writeln!(s, r#"<g>"#);
    let _ = writeln!(
        s,
        r#"<text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="14" font-weight="bold">{}</text>"#,
        (x0 + x1) / 2.0,
        oy + 20.0,
        escape(&panel.title)
    );
    for (v, label) in xa.ticks() {
        let x = xa.px(v);
        let _ = writeln!(s, r##"<line x1="{x:.1}" y1="{y0:.1}" x2="{x:.1}" y2="{y1:.1}" stroke="#e5e5e5"/>"##);
        let _ = writeln!(s, r##"<line x1="{x:.1}" y1="{y0:.1}" x2="{x:.1}" y2="{:.1}" stroke="#333"/>"##, y0 + 4.0);
        let _ = writeln!(s, r#"<text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"#, y0 + 17.0, escape(&label));
    }
    for (v, label) in ya.ticks() {
        let y = ya.px(v);
        let _ = writeln!(s, r##"<line x1="{x0:.1}" y1="{y:.1}" x2="{x1:.1}" y2="{y:.1}" stroke="#e5e5e5"/>"##);
        let _ = writeln!(s, r##"<line x1="{:.1}" y1="{y:.1}" x2="{x0:.1}" y2="{y:.1}" stroke="#333"/>"##, x0 - 4.0);
        let _ = writeln!(s, r#"<text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"#, x0 - 7.0, y + 4.0, escape(&label));
    }
    let _ = writeln!(s, r##"<rect x="{x0:.1}" y="{y1:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="#333"/>"##, x1 - x0, y0 - y1);
    let _ =
        writeln!(s, r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#, (x0 + x1) / 2.0, oy + ph - 10.0, escape(&panel.x_label));
    let (lx, ly) = (ox + 16.0, (y0 + y1) / 2.0);
    let _ = writeln!(
        s,
        r#"<text x="{lx:.1}" y="{ly:.1}" text-anchor="middle" transform="rotate(-90 {lx:.1} {ly:.1})">{}</text>"#,
        escape(&panel.y_label)
    );

    if points().next().is_none() {
        let _ =
            writeln!(s, r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#888">no data</text>"##, (x0 + x1) / 2.0, (y0 + y1) / 2.0);
    }
    for (i, se) in panel.series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        // Polylines broken at unusable points.
        for run in se.points.split(|p| !usable(p)).filter(|r| !r.is_empty()) {
            let coords: Vec<String> = run.iter().map(|p| format!("{:.1},{:.1}", xa.px(p.0), ya.px(p.1))).collect();
            let _ = writeln!(s, r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="2"/>"#, coords.join(" "));
        }
        for p in se.points.iter().filter(|p| usable(p)) {
            let _ = writeln!(s, r#"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{color}"/>"#, xa.px(p.0), ya.px(p.1));
        }
    }
    // Legend, in the inside corner that covers the fewest drawn points and line samples.
    let named: Vec<(usize, &Series)> = panel.series.iter().enumerate().filter(|(_, se)| !se.name.is_empty()).collect();
    if !named.is_empty() {
        let width = 34.0 + 7.0 * named.iter().map(|(_, se)| se.name.chars().count()).max().unwrap_or(0) as f64;
        let height = 8.0 + 16.0 * named.len() as f64;
        let mut samples = Vec::new();
        for se in &panel.series {
            for run in se.points.split(|p| !usable(p)) {
                for (i, p) in run.iter().enumerate() {
                    let (px, py) = (xa.px(p.0), ya.px(p.1));
                    samples.push((px, py));
                    if let Some(q) = run.get(i + 1) {
                        let (qx, qy) = (xa.px(q.0), ya.px(q.1));
                        samples.extend((1..10).map(|k| k as f64 / 10.0).map(|t| (px + t * (qx - px), py + t * (qy - py))));
                    }
                }
            }
        }
        let corners =
            [(x0 + 8.0, y1 + 8.0), (x1 - 8.0 - width, y1 + 8.0), (x1 - 8.0 - width, y0 - 8.0 - height), (x0 + 8.0, y0 - 8.0 - height)];
        let covered = |&(bx, by): &(f64, f64)| {
            samples.iter().filter(|(x, y)| *x >= bx - 4.0 && *x <= bx + width + 4.0 && *y >= by - 4.0 && *y <= by + height + 4.0).count()
        };
        let (lx, ly) = corners.iter().copied().min_by_key(|c| covered(c)).unwrap_or(corners[0]);
        let _ = writeln!(
            s,
            r##"<rect x="{lx:.1}" y="{ly:.1}" width="{width:.1}" height="{height:.1}" fill="white" fill-opacity="0.85" stroke="#bbb"/>"##
        );
        for (row, (i, se)) in named.iter().enumerate() {
            let y = ly + 12.0 + 16.0 * row as f64;
            let color = PALETTE[i % PALETTE.len()];
            let _ = writeln!(
                s,
                r#"<line x1="{:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="{color}" stroke-width="2"/>"#,
                lx + 6.0,
                lx + 24.0
            );
            let _ = writeln!(s, r#"<text x="{:.1}" y="{:.1}">{}</text>"#, lx + 29.0, y + 4.0, escape(&se.name));
        }
    }
    let _ = writeln!(s, "</g>");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_are_1_2_5() {
        assert_eq!(nice_step(0.013), 0.02);
        assert_eq!(nice_step(3.0), 5.0);
        assert_eq!(nice_step(7.0), 10.0);
        assert_eq!(nice_step(100.0), 100.0);
    }

    #[test]
    fn linear_ticks_cover_the_range_with_round_labels() {
        let a = Axis::fit([0.81, 0.93].into_iter(), false, 0.0, 100.0);
        let t = a.ticks();
        let labels: Vec<&str> = t.iter().map(|(_, l)| l.as_str()).collect();
        assert_eq!(labels, ["0.82", "0.84", "0.86", "0.88", "0.90", "0.92"]);
        assert!(t.iter().all(|(v, _)| (a.lo..=a.hi).contains(v)));
    }

    #[test]
    fn log_ticks_are_decades_or_1_2_5() {
        let wide = Axis::fit([2e3, 5e6].into_iter(), true, 0.0, 100.0);
        let labels: Vec<String> = wide.ticks().into_iter().map(|(_, l)| l).collect();
        assert_eq!(labels, ["10k", "100k", "1M"]);
        let narrow = Axis::fit([3e4, 2.1e5].into_iter(), true, 0.0, 100.0);
        let labels: Vec<String> = narrow.ticks().into_iter().map(|(_, l)| l).collect();
        assert_eq!(labels, ["50k", "100k", "200k"]);
    }

    #[test]
    fn axis_maps_ends_to_the_pixel_range_inside_padding() {
        let a = Axis::fit([10.0, 20.0].into_iter(), false, 100.0, 200.0);
        assert!((a.px(15.0) - 150.0).abs() < 1e-9);
        assert!(a.px(10.0) > 100.0 && a.px(20.0) < 200.0);
        let flat = Axis::fit([5.0, 5.0].into_iter(), false, 0.0, 1.0);
        assert!(flat.hi > flat.lo);
    }

    #[test]
    fn svg_has_one_polyline_per_series_and_escapes_text() {
        let panel = Panel::new("a<b", "x", "y")
            .series(Series::new("one", vec![(1.0, 1.0), (2.0, 3.0)]))
            .series(Series::new("two & three", vec![(1.0, 2.0), (f64::NAN, 1.0), (2.0, 2.5), (3.0, 2.0)]));
        let svg = Figure::new(vec![panel, Panel::new("empty", "x", "y")]).to_svg();
        // "two" is split at its NaN point into a single point run and a two-point run.
        assert_eq!(svg.matches("<polyline").count(), 3);
        assert_eq!(svg.matches("<circle").count(), 5);
        assert!(svg.contains("a&lt;b") && svg.contains("two &amp; three") && svg.contains("no data"));
        assert!(svg.trim_end().ends_with("</svg>"));
    }
}
