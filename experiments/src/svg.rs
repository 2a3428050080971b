//! Small, dependency-free SVG charts: line charts with confidence bands, and dot-and-whisker
//! charts over categories.
//!
//! Hand-written rather than drawn with a plotting crate so charts need no font files or system
//! libraries and render the same everywhere (text is left to the SVG viewer).
//!
//! Every method keeps one colour in every figure of every experiment: a series' colour comes
//! from its name through [`colour_by_name`] (the [`Method`]'s colour), never from its position
//! in a chart. Each series is
//! drawn inside `<g class="series" data-name="…" data-colour="…">` groups (and its legend entry
//! inside `<g class="legend" …>`), so tests and scripts can find what was drawn for whom.

use std::fmt::Write;

use crate::method::{Method, colour_by_name};

/// One point of a series: `x`, mean `y`, and the band `[lo, hi]` around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandPoint {
    /// Horizontal position.
    pub x: f64,
    /// The line's value.
    pub y: f64,
    /// Lower edge of the band.
    pub lo: f64,
    /// Upper edge of the band.
    pub hi: f64,
}

/// A named line with its band.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text, and the key of the series' colour.
    pub name: String,
    /// Points in increasing `x`.
    pub points: Vec<BandPoint>,
    /// `None` — every experiment's figures — draws the series in its method's colour
    /// ([`colour_by_name`] of `name`). For charts of series that are not methods (a
    /// benchmark's percentiles), a slot in a general colour-blind-safe palette.
    pub colour: Option<usize>,
}

impl Series {
    /// A method's series, named as the method and drawn in its colour in every figure.
    pub fn method(method: Method, points: Vec<BandPoint>) -> Self {
        Self {
            name: method.name().into_owned(),
            points,
            colour: None,
        }
    }

    /// The colour the series is drawn in.
    fn colour(&self) -> &'static str {
        match self.colour {
            Some(slot) => SLOT_COLOURS[slot % SLOT_COLOURS.len()],
            None => colour_by_name(&self.name),
        }
    }
}

/// A line chart: title, axis labels and series.
#[derive(Debug, Clone, PartialEq)]
pub struct LineChart {
    /// Title above the plot.
    pub title: String,
    /// Label of the horizontal axis.
    pub x_label: String,
    /// Label of the vertical axis.
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
    /// Draw a marker on each point (for charts with few points).
    pub markers: bool,
}

/// A mean with its 95 % interval, as a category chart draws it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// The dot.
    pub mean: f64,
    /// Lower end of the whisker.
    pub lo: f64,
    /// Upper end of the whisker.
    pub hi: f64,
}

/// One method's values over a category chart's categories.
#[derive(Debug, Clone, PartialEq)]
pub struct CategorySeries {
    /// Legend text, and the key of the series' colour.
    pub name: String,
    /// One entry per category, in the chart's order; `None` (or a non-finite mean) where the
    /// method has no value there.
    pub values: Vec<Option<Interval>>,
}

/// A dot-and-whisker chart over categories (e.g. one test task each): every method's value
/// is a dot with its interval inside its category's slot, and nothing joins categories — they
/// are not an ordered scale. A category where no series has a value is marked "not run".
#[derive(Debug, Clone, PartialEq)]
pub struct CategoryChart {
    /// Title above the plot.
    pub title: String,
    /// Label of the horizontal axis.
    pub x_label: String,
    /// Label of the vertical axis.
    pub y_label: String,
    /// Category labels, left to right.
    pub categories: Vec<String>,
    /// The methods, each with one entry per category.
    pub series: Vec<CategorySeries>,
}

/// Colour-blind-safe palette (Okabe–Ito) for series that are not methods ([`Series::colour`]).
const SLOT_COLOURS: [&str; 8] = [
    "#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442",
];

const WIDTH: f64 = 760.0;
const HEIGHT: f64 = 460.0;
const LEFT: f64 = 80.0;
const RIGHT: f64 = 170.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 60.0;
/// Horizontal room per category in a category chart.
const CATEGORY_WIDTH: f64 = 48.0;

/// "Nice" tick positions covering `[lo, hi]`.
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-12);
    let raw = span / 6.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| span / s <= 7.0)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + step * 1e-9 {
        out.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    out
}

/// [`ticks`] for a whole-numbered axis: only whole numbers (every one, when the span is short).
fn whole_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let nice = ticks(lo, hi);
    if nice.iter().all(|t| *t == t.trunc()) {
        return nice;
    }
    let (first, last) = (lo.ceil() as i64, hi.floor() as i64);
    (first..=last).map(|t| t as f64).collect()
}

fn fmt_tick(v: f64) -> String {
    if v.abs() >= 1000.0 || v == v.trunc() {
        format!("{v:.0}")
    } else if (v * 10.0) == (v * 10.0).trunc() {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

/// Escapes text for element content and attribute values.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// `[lo, hi]` widened when empty or degenerate, then padded by 5 % each side.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, mut hi) = if lo.is_finite() && hi.is_finite() {
        (lo, hi)
    } else {
        (0.0, 1.0)
    };
    if hi <= lo {
        hi = lo + 1.0;
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// The plot area of a chart `width` wide, with its vertical scale, and what every chart draws
/// around its data: title, horizontal grid lines with their ticks, frame, axis labels.
struct Frame {
    width: f64,
    y0: f64,
    y1: f64,
}

impl Frame {
    fn plot_width(&self) -> f64 {
        self.width - LEFT - RIGHT
    }

    fn plot_height(&self) -> f64 {
        HEIGHT - TOP - BOTTOM
    }

    fn sy(&self, y: f64) -> f64 {
        TOP + (1.0 - (y - self.y0) / (self.y1 - self.y0)) * self.plot_height()
    }

    /// The document's opening, white background and title.
    fn open(&self, svg: &mut String, title: &str) {
        let width = self.width;
        let _ = writeln!(
            svg,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{HEIGHT}" viewBox="0 0 {width} {HEIGHT}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(
            svg,
            r#"<rect width="100%" height="100%" fill="white"/><text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>"#,
            LEFT + self.plot_width() / 2.0,
            escape(title)
        );
    }

    /// Horizontal grid lines with their tick labels.
    fn y_grid(&self, svg: &mut String) {
        for t in ticks(self.y0, self.y1) {
            let y = self.sy(t);
            let _ = writeln!(
                svg,
                r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#e5e5e5"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
                LEFT + self.plot_width(),
                LEFT - 6.0,
                y + 4.0,
                fmt_tick(t)
            );
        }
    }

    /// The plot's frame and both axis labels.
    fn frame_and_labels(&self, svg: &mut String, x_label: &str, y_label: &str) {
        let (pw, ph) = (self.plot_width(), self.plot_height());
        let _ = writeln!(
            svg,
            r##"<rect x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" fill="none" stroke="#444"/>"##
        );
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            LEFT + pw / 2.0,
            HEIGHT - 15.0,
            escape(x_label)
        );
        let _ = writeln!(
            svg,
            r#"<text transform="translate(20,{:.1}) rotate(-90)" text-anchor="middle">{}</text>"#,
            TOP + ph / 2.0,
            escape(y_label)
        );
    }

    /// The `i`-th legend entry: a short line (or a dot) in `colour` and the series' name.
    fn legend(&self, svg: &mut String, i: usize, name: &str, colour: &str, dot: bool) {
        let ly = TOP + 12.0 + 20.0 * i as f64;
        let lx = LEFT + self.plot_width() + 14.0;
        let mark = if dot {
            format!(
                r#"<circle cx="{:.1}" cy="{ly}" r="4" fill="{colour}"/>"#,
                lx + 11.0
            )
        } else {
            format!(
                r#"<line x1="{lx}" y1="{ly}" x2="{:.1}" y2="{ly}" stroke="{colour}" stroke-width="3"/>"#,
                lx + 22.0
            )
        };
        let _ = writeln!(
            svg,
            r#"<g class="legend" data-name="{}" data-colour="{colour}">{mark}<text x="{:.1}" y="{:.1}">{}</text></g>"#,
            escape(name),
            lx + 28.0,
            ly + 4.0,
            escape(name)
        );
    }
}

/// Opens the group holding what is drawn for series `name` in `colour` (`class` "series" or
/// "series band").
fn open_series(svg: &mut String, class: &str, name: &str, colour: &str) {
    let _ = writeln!(
        svg,
        r#"<g class="{class}" data-name="{}" data-colour="{colour}">"#,
        escape(name)
    );
}

impl LineChart {
    /// Renders the chart as a standalone SVG document.
    pub fn to_svg(&self) -> String {
        let (x0, x1, y0, y1) = self.ranges();
        let frame = Frame {
            width: WIDTH,
            y0,
            y1,
        };
        let pw = frame.plot_width();
        let sx = |x: f64| LEFT + (x - x0) / (x1 - x0) * pw;
        let sy = |y: f64| frame.sy(y);

        let mut svg = String::new();
        frame.open(&mut svg, &self.title);
        self.x_grid(&mut svg, &frame, (x0, x1), sx);
        frame.y_grid(&mut svg);
        frame.frame_and_labels(&mut svg, &self.x_label, &self.y_label);
        // Bands first, then lines on top.
        for s in &self.series {
            if s.points.len() >= 2 {
                let colour = s.colour();
                let mut d = String::new();
                for p in &s.points {
                    let _ = write!(d, "{:.1},{:.1} ", sx(p.x), sy(p.hi));
                }
                for p in s.points.iter().rev() {
                    let _ = write!(d, "{:.1},{:.1} ", sx(p.x), sy(p.lo));
                }
                open_series(&mut svg, "series band", &s.name, colour);
                let _ = writeln!(
                    svg,
                    r#"<polygon points="{}" fill="{colour}" fill-opacity="0.18" stroke="none"/>"#,
                    d.trim_end()
                );
                svg.push_str("</g>\n");
            }
        }
        for (i, s) in self.series.iter().enumerate() {
            let colour = s.colour();
            let mut d = String::new();
            for p in &s.points {
                let _ = write!(d, "{:.1},{:.1} ", sx(p.x), sy(p.y));
            }
            open_series(&mut svg, "series", &s.name, colour);
            let _ = writeln!(
                svg,
                r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="2"/>"#,
                d.trim_end()
            );
            if self.markers {
                for p in &s.points {
                    let _ = writeln!(
                        svg,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="3.5" fill="{colour}"/><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}"/>"#,
                        sx(p.x),
                        sy(p.y),
                        sx(p.x),
                        sy(p.lo),
                        sx(p.x),
                        sy(p.hi)
                    );
                }
            }
            svg.push_str("</g>\n");
            frame.legend(&mut svg, i, &s.name, colour, false);
        }
        svg.push_str("</svg>\n");
        svg
    }

    /// The x range and the padded y range the points (and their bands) span; a chart with no
    /// points, or one x value, still gets a range of width 1.
    fn ranges(&self) -> (f64, f64, f64, f64) {
        let (mut x0, mut x1, mut y0, mut y1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for p in self.series.iter().flat_map(|s| s.points.iter()) {
            x0 = x0.min(p.x);
            x1 = x1.max(p.x);
            y0 = y0.min(p.lo.min(p.y));
            y1 = y1.max(p.hi.max(p.y));
        }
        if !x0.is_finite() || !x1.is_finite() {
            (x0, x1) = (0.0, 1.0);
        }
        if x1 <= x0 {
            x1 = x0 + 1.0;
        }
        let (y0, y1) = padded(y0, y1);
        (x0, x1, y0, y1)
    }

    /// The vertical grid lines and their labels over `x0..x1`, placed by `sx`.
    fn x_grid(
        &self,
        svg: &mut String,
        frame: &Frame,
        (x0, x1): (f64, f64),
        sx: impl Fn(f64) -> f64,
    ) {
        let ph = frame.plot_height();
        // Episodes and tasks are counted: when every x is whole, so is every tick.
        let whole_x = self
            .series
            .iter()
            .flat_map(|s| &s.points)
            .all(|p| p.x == p.x.trunc());
        let x_ticks = if whole_x {
            whole_ticks(x0, x1)
        } else {
            ticks(x0, x1)
        };
        for t in x_ticks {
            let x = sx(t);
            let _ = writeln!(
                svg,
                r##"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{:.1}" stroke="#e5e5e5"/><text x="{x:.1}" y="{:.1}" text-anchor="middle">{}</text>"##,
                TOP + ph,
                TOP + ph + 18.0,
                fmt_tick(t)
            );
        }
    }
}

impl CategoryChart {
    /// The value series `s` has at category `c`, if it has a finite one.
    fn value(s: &CategorySeries, c: usize) -> Option<Interval> {
        s.values
            .get(c)
            .copied()
            .flatten()
            .filter(|v| v.mean.is_finite())
    }

    /// Renders the chart as a standalone SVG document.
    ///
    /// Each category is one `<g class="category" data-category="…">` group holding, per
    /// series with a value there, a `<g class="series" …>` group with one dot and one vertical
    /// whisker — or a "not run" mark when no series has a value. No polyline, path or polygon
    /// is drawn, so no line can join two categories.
    pub fn to_svg(&self) -> String {
        let (y0, y1) = self.y_range();
        let n = self.categories.len().max(1);
        let frame = Frame {
            width: LEFT + RIGHT + (CATEGORY_WIDTH * n as f64).max(WIDTH - LEFT - RIGHT),
            y0,
            y1,
        };
        let slot = frame.plot_width() / n as f64;
        let mut svg = String::new();
        frame.open(&mut svg, &self.title);
        frame.y_grid(&mut svg);
        self.guides(&mut svg, &frame, slot);
        frame.frame_and_labels(&mut svg, &self.x_label, &self.y_label);
        for (c, label) in self.categories.iter().enumerate() {
            self.category(&mut svg, &frame, slot, c, label);
        }
        for (i, s) in self.series.iter().enumerate() {
            frame.legend(&mut svg, i, &s.name, colour_by_name(&s.name), true);
        }
        svg.push_str("</svg>\n");
        svg
    }

    /// The vertical range every drawn value and whisker fits in, padded.
    fn y_range(&self) -> (f64, f64) {
        let (mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY);
        for s in &self.series {
            for c in 0..self.categories.len() {
                if let Some(v) = Self::value(s, c) {
                    for y in [v.mean, v.lo, v.hi].into_iter().filter(|y| y.is_finite()) {
                        y0 = y0.min(y);
                        y1 = y1.max(y);
                    }
                }
            }
        }
        padded(y0, y1)
    }

    /// The zero line (when 0 is in range) and light separators between the categories, each
    /// `slot` wide: vertical, never across one.
    fn guides(&self, svg: &mut String, frame: &Frame, slot: f64) {
        if frame.y0 < 0.0 && 0.0 < frame.y1 {
            let _ = writeln!(
                svg,
                r##"<line x1="{LEFT}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#999"/>"##,
                LEFT + frame.plot_width(),
                y = frame.sy(0.0)
            );
        }
        for c in 1..self.categories.len() {
            let x = LEFT + slot * c as f64;
            let _ = writeln!(
                svg,
                r##"<line x1="{x:.1}" y1="{TOP}" x2="{x:.1}" y2="{:.1}" stroke="#f0f0f0"/>"##,
                TOP + frame.plot_height()
            );
        }
    }

    /// Category `c`'s group: its label and every series' dot with its whisker there, side by
    /// side and centred in its `slot`, or a "not run" mark.
    fn category(&self, svg: &mut String, frame: &Frame, slot: f64, c: usize, label: &str) {
        let ph = frame.plot_height();
        let step = (0.8 * slot / self.series.len().max(1) as f64).min(10.0);
        let mid = (self.series.len().max(1) - 1) as f64 / 2.0;
        let centre = LEFT + slot * (c as f64 + 0.5);
        let _ = writeln!(
            svg,
            r#"<g class="category" data-category="{}" data-left="{:.1}" data-right="{:.1}">"#,
            escape(label),
            LEFT + slot * c as f64,
            LEFT + slot * (c as f64 + 1.0)
        );
        let _ = writeln!(
            svg,
            r#"<text x="{centre:.1}" y="{:.1}" text-anchor="middle">{}</text>"#,
            TOP + ph + 18.0,
            escape(label)
        );
        let mut drawn = 0;
        for (j, s) in self.series.iter().enumerate() {
            let Some(v) = Self::value(s, c) else {
                continue;
            };
            drawn += 1;
            dot(
                svg,
                frame,
                &s.name,
                label,
                centre + (j as f64 - mid) * step,
                v,
            );
        }
        if drawn == 0 {
            let _ = writeln!(
                svg,
                r##"<text class="not-run" transform="translate({:.1},{:.1}) rotate(-90)" text-anchor="middle" fill="#999">not run</text>"##,
                centre + 4.0,
                TOP + ph / 2.0
            );
        }
        svg.push_str("</g>\n");
    }
}

/// Series `name`'s dot at `x` with its vertical whisker (a non-finite end drawn at the mean)
/// and a tooltip naming the category `label`.
fn dot(svg: &mut String, frame: &Frame, name: &str, label: &str, x: f64, v: Interval) {
    let colour = colour_by_name(name);
    let (lo, hi) = (
        if v.lo.is_finite() { v.lo } else { v.mean },
        if v.hi.is_finite() { v.hi } else { v.mean },
    );
    open_series(svg, "series", name, colour);
    let _ = writeln!(
        svg,
        r#"<line x1="{x:.1}" y1="{:.1}" x2="{x:.1}" y2="{:.1}" stroke="{colour}" stroke-width="1.5"/><circle cx="{x:.1}" cy="{:.1}" r="3.5" fill="{colour}"><title>{}, {}: {} [{}, {}]</title></circle>"#,
        frame.sy(lo),
        frame.sy(hi),
        frame.sy(v.mean),
        escape(name),
        escape(label),
        fmt_value(v.mean),
        fmt_value(lo),
        fmt_value(hi)
    );
    svg.push_str("</g>\n");
}

/// A value for a tooltip: three decimals.
fn fmt_value(v: f64) -> String {
    format!("{v:.3}")
}

/// What a chart rendered by this module drew for one series, read back from its SVG.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DrawnSeries {
    /// The series' name.
    pub name: String,
    /// The colour its groups declare (`data-colour`).
    pub colour: String,
    /// Every distinct fill and stroke colour used inside its groups and legend entry.
    pub used: Vec<String>,
}

/// What in a figure's drawn series (see [`drawn_series`]) breaks the one-colour-per-method
/// rule: a method not in its [`colour_by_name`], drawn in more than one colour, or sharing its
/// colour with another method of the figure. Empty when the figure keeps the rule.
pub fn colour_problems(drawn: &[DrawnSeries]) -> Vec<String> {
    let mut problems = Vec::new();
    for (i, d) in drawn.iter().enumerate() {
        if d.colour != colour_by_name(&d.name) {
            problems.push(format!("{} is not in its colour", d.name));
        }
        if d.used != [d.colour.clone()] {
            problems.push(format!("{} is drawn in {:?}", d.name, d.used));
        }
        for other in &drawn[i + 1..] {
            if d.colour == other.colour {
                problems.push(format!("{} and {} share a colour", d.name, other.name));
            }
        }
    }
    problems
}

/// Reads back, from an SVG rendered by [`LineChart::to_svg`] or [`CategoryChart::to_svg`],
/// each series in order of first appearance: its declared colour and the colours actually
/// used to draw it. Checks that a figure keeps to [`colour_by_name`] start here.
pub fn drawn_series(svg: &str) -> Vec<DrawnSeries> {
    let mut out: Vec<DrawnSeries> = Vec::new();
    let mut rest = svg;
    while let Some(at) = rest.find("<g class=\"") {
        rest = &rest[at..];
        let tag_end = rest.find('>').map_or(rest.len(), |i| i + 1);
        let tag = &rest[..tag_end];
        let class = attribute(tag, "class").unwrap_or_default();
        if !(class.starts_with("series") || class == "legend") {
            rest = &rest[tag_end..];
            continue;
        }
        // Series and legend groups hold no nested groups: the next `</g>` closes this one.
        let body_end = rest[tag_end..]
            .find("</g>")
            .map_or(rest.len(), |i| tag_end + i);
        let body = &rest[tag_end..body_end];
        let name = attribute(tag, "data-name").unwrap_or_default();
        let colour = attribute(tag, "data-colour").unwrap_or_default();
        let index = match out.iter().position(|d| d.name == name) {
            Some(i) => i,
            None => {
                out.push(DrawnSeries {
                    name: name.clone(),
                    colour: colour.clone(),
                    used: Vec::new(),
                });
                out.len() - 1
            }
        };
        let entry = &mut out[index];
        if entry.colour != colour && !entry.used.contains(&colour) {
            entry.used.push(colour);
        }
        for key in ["fill", "stroke"] {
            let needle = format!(" {key}=\"");
            let mut b = body;
            while let Some(i) = b.find(&needle) {
                b = &b[i + needle.len()..];
                let value = b.split('"').next().unwrap_or_default().to_owned();
                if value != "none" && !entry.used.contains(&value) {
                    entry.used.push(value);
                }
            }
        }
        rest = &rest[body_end..];
    }
    out
}

/// The value of attribute `name` in an opening tag, unescaped.
fn attribute(tag: &str, name: &str) -> Option<String> {
    let needle = format!(" {name}=\"");
    let start = tag.find(&needle)? + needle.len();
    let len = tag[start..].find('"')?;
    Some(
        tag[start..start + len]
            .replace("&quot;", "\"")
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&amp;", "&"),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn band(i: usize) -> BandPoint {
        BandPoint {
            x: i as f64,
            y: i as f64,
            lo: i as f64 - 0.5,
            hi: i as f64 + 0.5,
        }
    }

    fn line_chart(names: &[&str]) -> LineChart {
        LineChart {
            title: "a < b".into(),
            x_label: "episode".into(),
            y_label: "reward".into(),
            series: names
                .iter()
                .map(|n| Series {
                    name: (*n).into(),
                    points: (0..5).map(band).collect(),
                    colour: None,
                })
                .collect(),
            markers: true,
        }
    }

    fn interval(mean: f64) -> Option<Interval> {
        Some(Interval {
            mean,
            lo: mean - 0.25,
            hi: mean + 0.5,
        })
    }

    fn category_chart() -> CategoryChart {
        CategoryChart {
            title: "jumpstart".into(),
            x_label: "test task".into(),
            y_label: "first-episode reward".into(),
            categories: ["0", "1", "2", "3", "4"].map(String::from).to_vec(),
            series: vec![
                CategorySeries {
                    name: "TES".into(),
                    values: vec![None, interval(0.5), interval(-1.0), None, interval(2.0)],
                },
                CategorySeries {
                    name: "loreRL".into(),
                    values: vec![None, interval(-0.5), None, None, interval(1.0)],
                },
                CategorySeries {
                    name: "fEpsG".into(),
                    // A non-finite mean counts as no value.
                    values: vec![None, interval(0.0), interval(f64::NAN), None, interval(0.1)],
                },
            ],
        }
    }

    /// Every number after ` {key}="` in `text`.
    fn numbers(text: &str, key: &str) -> Vec<f64> {
        let needle = format!(" {key}=\"");
        text.match_indices(&needle)
            .map(|(i, _)| {
                let v = &text[i + needle.len()..];
                v[..v.find('"').unwrap()].parse::<f64>().unwrap()
            })
            .collect()
    }

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 10.0), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        // Two episodes (0 and 1) or three: whole ticks, not 0.5 and 1.5.
        assert_eq!(whole_ticks(0.0, 1.0), vec![0.0, 1.0]);
        assert_eq!(whole_ticks(0.0, 2.0), vec![0.0, 1.0, 2.0]);
        assert_eq!(whole_ticks(0.0, 100.0), ticks(0.0, 100.0));
        let t = ticks(-3.2, 1.1);
        assert!(t.first().is_some_and(|&v| v >= -3.2) && t.len() >= 4);
    }

    #[test]
    fn renders_series_bands_and_legend() {
        let svg = line_chart(&["loreRL"]).to_svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("a &lt; b"));
        assert!(svg.contains("<polygon") && svg.contains("<polyline"));
        assert!(svg.contains(">loreRL</text>"));
        assert_eq!(svg.matches("<circle").count(), 5);
    }

    #[test]
    fn a_method_keeps_its_colour_across_figures_and_no_two_share_one() {
        // The same methods in a different order and a different kind of chart.
        let line = line_chart(&["loreRL", "TES", "fEpsG", "Rands 2"]).to_svg();
        let cats = category_chart().to_svg();
        let line_drawn = drawn_series(&line);
        let cat_drawn = drawn_series(&cats);
        assert_eq!(line_drawn.len(), 4);
        assert_eq!(cat_drawn.len(), 3);
        for figure in [&line_drawn, &cat_drawn] {
            assert_eq!(colour_problems(figure), Vec::<String>::new());
        }
        for d in &cat_drawn {
            let same = line_drawn.iter().find(|l| l.name == d.name).unwrap();
            assert_eq!(same.colour, d.colour, "{}", d.name);
        }
    }

    #[test]
    fn a_category_chart_joins_no_two_categories() {
        let svg = category_chart().to_svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        for shape in ["<polyline", "<path", "<polygon"] {
            assert!(!svg.contains(shape), "{shape} drawn");
        }
        // Everything drawn for a category stays inside its slot, and whiskers are vertical.
        let mut groups = 0;
        let mut dots = 0;
        for (at, _) in svg.match_indices("<g class=\"category\"") {
            groups += 1;
            let rest = &svg[at..];
            let tag = &rest[..rest.find('>').unwrap()];
            let left = numbers(tag, "data-left")[0];
            let right = numbers(tag, "data-right")[0];
            // The category group ends at the first `</g>` not closing one of its series groups.
            let mut end = 0;
            let mut depth = 0;
            for (i, _) in rest.match_indices('<') {
                if rest[i..].starts_with("<g ") {
                    depth += 1;
                } else if rest[i..].starts_with("</g>") {
                    depth -= 1;
                    if depth == 0 {
                        end = i;
                        break;
                    }
                }
            }
            let body = &rest[..end];
            let xs: Vec<f64> = ["cx", "x1", "x2"]
                .iter()
                .flat_map(|k| numbers(body, k))
                .collect();
            assert!(
                xs.iter().all(|&x| left < x && x < right),
                "{xs:?} in {left}..{right}"
            );
            assert_eq!(numbers(body, "x1"), numbers(body, "x2"));
            dots += body.matches("<circle").count();
        }
        assert_eq!(groups, 5);
        // 3 + 2 + 2 finite values (fEpsG's NaN at category 2 is not drawn).
        assert_eq!(dots, 7);
        // Categories 0 and 3 ran nothing.
        assert_eq!(svg.matches("class=\"not-run\"").count(), 2);
        assert_eq!(svg.matches(">not run</text>").count(), 2);
    }

    #[test]
    fn series_that_are_not_methods_keep_their_palette_slot() {
        let mut chart = line_chart(&["decision p50", "decision p99"]);
        chart.series[0].colour = Some(0);
        chart.series[1].colour = Some(9);
        let drawn = drawn_series(&chart.to_svg());
        assert_eq!(drawn[0].colour, SLOT_COLOURS[0]);
        assert_eq!(drawn[1].colour, SLOT_COLOURS[1]);
        assert!(drawn.iter().all(|d| d.used == vec![d.colour.clone()]));
    }

    #[test]
    fn empty_charts_still_render() {
        let chart = CategoryChart {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            categories: Vec::new(),
            series: Vec::new(),
        };
        assert!(chart.to_svg().trim_end().ends_with("</svg>"));
        assert!(line_chart(&[]).to_svg().trim_end().ends_with("</svg>"));
    }
}
