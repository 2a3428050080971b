//! The arena drawn to scale as SVG: each cell's surface, the marks, the ball, the death spots,
//! and robot paths over it (a run folder's `arena.svg`).

use std::fmt::Write;

use glam::DVec2;

use super::{Arena, MarkColour, Surface};

/// One episode's path: the robot's positions, cm, in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Path {
    /// The legend text ("episode 7").
    pub label: String,
    /// Positions, cm from the south-west corner.
    pub points: Vec<DVec2>,
}

/// Side of the drawn arena, px.
const SIDE_PX: f64 = 600.0;
/// Margin around it (title above, legend to the right).
const MARGIN: f64 = 40.0;
/// Width of the legend column.
const LEGEND_PX: f64 = 190.0;
/// Colours of the paths, oldest to newest (colour-blind-safe, Okabe–Ito).
const PATH_COLOURS: [&str; 6] = [
    "#E69F00", "#56B4E9", "#009E73", "#CC79A7", "#D55E00", "#0072B2",
];

fn surface_fill(surface: Surface) -> &'static str {
    match surface {
        Surface::Carpet => "#ECECEC",
        Surface::Board => "#F7F3E3",
        Surface::Beans => "#D9B99B",
        Surface::Slope => "#CFE3B4",
    }
}

/// The drawing's scale: arena cm to px, north up.
#[derive(Debug, Clone, Copy)]
struct Canvas {
    /// The arena's side, cm.
    side: f64,
    /// px per cm.
    scale: f64,
}

impl Canvas {
    /// Where the arena point `p` (cm from the south-west corner) is drawn: y grows downwards
    /// in SVG.
    fn px(self, p: DVec2) -> (f64, f64) {
        (
            MARGIN + p.x * self.scale,
            MARGIN + (self.side - p.y) * self.scale,
        )
    }
}

impl Arena {
    /// The arena to scale with `paths` over it (oldest first; the last is drawn on top), as a
    /// standalone SVG document titled `title`.
    ///
    /// ```
    /// use tes_perception_sim::arena::{Arena, ArenaId};
    ///
    /// let svg = Arena::new(ArenaId::Env3).to_svg("Env 3", &[]);
    /// assert!(svg.starts_with("<svg") && svg.contains("ball"));
    /// ```
    pub fn to_svg(&self, title: &str, paths: &[Path]) -> String {
        let side = self.side_cm();
        let canvas = Canvas {
            side,
            scale: SIDE_PX / side,
        };
        let mut svg = String::new();
        write_header(&mut svg, title);
        self.draw_cells(&mut svg, canvas);
        self.draw_marks_and_ball(&mut svg, canvas);
        draw_paths(&mut svg, paths, canvas);
        self.draw_legend(&mut svg, paths.len());
        svg.push_str("</svg>\n");
        svg
    }

    /// Each cell's surface, and the death spots' crosses.
    fn draw_cells(&self, svg: &mut String, canvas: Canvas) {
        let n = self.cells();
        let cell = self.cell_cm() * canvas.scale;
        let _ = writeln!(
            svg,
            r##"<g class="cells" stroke="#BBBBBB" stroke-width="0.5">"##
        );
        for y in 0..n {
            for x in 0..n {
                let (left, top) = (MARGIN + x as f64 * cell, MARGIN + (n - 1 - y) as f64 * cell);
                let _ = writeln!(
                    svg,
                    r#"<rect x="{left:.1}" y="{top:.1}" width="{cell:.1}" height="{cell:.1}" fill="{}"/>"#,
                    surface_fill(self.surface(x, y))
                );
                if self.is_death_cell(x, y) {
                    let (a, b) = (cell * 0.2, cell * 0.8);
                    let _ = writeln!(
                        svg,
                        r##"<g class="death" stroke="#C00000" stroke-width="3"><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}"/><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}"/></g>"##,
                        left + a,
                        top + a,
                        left + b,
                        top + b,
                        left + b,
                        top + a,
                        left + a,
                        top + b
                    );
                }
            }
        }
        svg.push_str("</g>\n");
    }

    /// The green and blue marks, then the ball.
    fn draw_marks_and_ball(&self, svg: &mut String, canvas: Canvas) {
        for (colour, fill) in [
            (MarkColour::Green, "#2CA02C"),
            (MarkColour::Blue, "#1F5FBF"),
        ] {
            let _ = writeln!(svg, r#"<g class="marks" data-colour="{}">"#, colour.name());
            for &m in self.marks(colour) {
                let (cx, cy) = canvas.px(m);
                let _ = writeln!(
                    svg,
                    r#"<rect x="{:.1}" y="{:.1}" width="8" height="8" fill="{fill}"/>"#,
                    cx - 4.0,
                    cy - 4.0
                );
            }
            svg.push_str("</g>\n");
        }
        let cell = self.cell_cm() * canvas.scale;
        let (bx, by) = canvas.px(self.ball());
        let _ = writeln!(
            svg,
            r##"<circle class="ball" cx="{bx:.1}" cy="{by:.1}" r="{:.1}" fill="#2060FF" stroke="#002080" stroke-width="1.5"/>"##,
            (cell * 0.3).max(5.0)
        );
    }

    /// The legend below the paths' entries (`paths` of them): the marks, the ball, the
    /// death spots, the surfaces, the arena's size and how a path starts and ends.
    fn draw_legend(&self, svg: &mut String, paths: usize) {
        let lx = MARGIN * 1.5 + SIDE_PX;
        let first = MARGIN + 40.0 + paths as f64 * 18.0;
        let _ = writeln!(svg, r#"<g class="legend">"#);
        for (i, (swatch, text)) in self.legend_rows(lx).iter().enumerate() {
            let y = first + i as f64 * 18.0;
            let swatch = swatch
                .replace("{y0}", &format!("{:.1}", y - 5.0))
                .replace("{y1}", &format!("{:.1}", y + 4.0))
                .replace("{y2}", &format!("{:.1}", y - 7.0));
            let _ = writeln!(
                svg,
                "{swatch}<text x=\"{}\" y=\"{:.1}\">{}</text>",
                lx + 30.0,
                y + 4.0,
                escape(text)
            );
        }
        svg.push_str("</g>\n");
    }

    /// The legend's rows, each (a swatch drawn at the row's y, placeholders `{y0}`, `{y1}`,
    /// `{y2}` for its offsets, at `lx`; the text).
    fn legend_rows(&self, lx: f64) -> Vec<(String, String)> {
        let mut rows: Vec<(String, String)> = Vec::new();
        for (text, fill) in [
            ("green mark", "#2CA02C"),
            ("blue mark", "#1F5FBF"),
            ("ball (+2)", "#2060FF"),
        ] {
            rows.push((
                format!(
                    r#"<rect x="{}" y="{{y0}}" width="10" height="10" fill="{fill}"/>"#,
                    lx + 7.0
                ),
                text.to_owned(),
            ));
        }
        rows.push((
            format!(
                r##"<text x="{}" y="{{y1}}" fill="#C00000" font-weight="bold">X</text>"##,
                lx + 7.0
            ),
            "death spot (-1)".to_owned(),
        ));
        let mut surfaces = vec![self.layout().floor, self.layout().governing_surface];
        surfaces.dedup();
        for s in surfaces {
            rows.push((
                format!(
                    r##"<rect x="{}" y="{{y2}}" width="14" height="14" fill="{}" stroke="#BBBBBB"/>"##,
                    lx + 5.0,
                    surface_fill(s)
                ),
                s.name().to_owned(),
            ));
        }
        let (n, side) = (self.cells(), self.side_cm());
        rows.push((
            String::new(),
            format!("{n} x {n} cells, {side:.0} cm a side"),
        ));
        rows.push((String::new(), "dot: start, square: end".to_owned()));
        rows
    }
}

/// The document's opening, its white background and its title.
fn write_header(svg: &mut String, title: &str) {
    let width = MARGIN * 2.0 + SIDE_PX + LEGEND_PX;
    let height = MARGIN * 2.0 + SIDE_PX;
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(
        svg,
        r#"<rect width="100%" height="100%" fill="white"/><text x="{MARGIN}" y="24" font-size="15">{}</text>"#,
        escape(title)
    );
}

/// The robot's paths, oldest first, each coloured, with its start and end and an entry in
/// the legend.
fn draw_paths(svg: &mut String, paths: &[Path], canvas: Canvas) {
    for (i, path) in paths.iter().enumerate() {
        let colour = PATH_COLOURS
            [(i + PATH_COLOURS.len() - paths.len() % PATH_COLOURS.len()) % PATH_COLOURS.len()];
        let points: Vec<String> = path
            .points
            .iter()
            .filter(|p| p.is_finite())
            .map(|&p| {
                let (x, y) = canvas.px(p);
                format!("{x:.1},{y:.1}")
            })
            .collect();
        let _ = writeln!(
            svg,
            r#"<g class="path" data-name="{}"><polyline points="{}" fill="none" stroke="{colour}" stroke-width="2" stroke-opacity="0.85"/>"#,
            escape(&path.label),
            points.join(" ")
        );
        if let (Some(first), Some(last)) = (path.points.first(), path.points.last()) {
            let ((sx, sy), (ex, ey)) = (canvas.px(*first), canvas.px(*last));
            let _ = writeln!(
                svg,
                r#"<circle cx="{sx:.1}" cy="{sy:.1}" r="4" fill="{colour}"/><rect x="{:.1}" y="{:.1}" width="8" height="8" fill="white" stroke="{colour}" stroke-width="2"/>"#,
                ex - 4.0,
                ey - 4.0
            );
        }
        let ly = MARGIN + 20.0 + i as f64 * 18.0;
        let lx = MARGIN * 1.5 + SIDE_PX;
        let _ = writeln!(
            svg,
            r#"<line x1="{lx}" y1="{ly}" x2="{}" y2="{ly}" stroke="{colour}" stroke-width="3"/><text x="{}" y="{}">{}</text></g>"#,
            lx + 24.0,
            lx + 30.0,
            ly + 4.0,
            escape(&path.label)
        );
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arena::ArenaId;

    #[test]
    fn the_picture_draws_every_cell_mark_death_spot_and_path() {
        for id in [ArenaId::Env1, ArenaId::Env2, ArenaId::Env3] {
            let arena = Arena::new(id);
            let start = arena.state_pose(0).unwrap().position;
            let path = Path {
                label: "episode <3>".into(),
                points: vec![start, start + DVec2::new(10.0, 5.0)],
            };
            let svg = arena.to_svg("arena", &[path.clone(), path]);
            let n = arena.cells();
            assert!(svg.matches("<rect x=").count() >= n * n);
            let deaths = (0..n)
                .flat_map(|y| (0..n).map(move |x| (x, y)))
                .filter(|&(x, y)| arena.is_death_cell(x, y))
                .count();
            assert!(deaths > 0);
            assert_eq!(svg.matches(r#"class="death""#).count(), deaths);
            assert_eq!(svg.matches(r#"class="path""#).count(), 2);
            assert_eq!(svg.matches(r#"class="ball""#).count(), 1);
            assert!(svg.contains("episode &lt;3&gt;"), "labels are escaped");
            assert!(svg.trim_end().ends_with("</svg>"));
        }
    }
}
