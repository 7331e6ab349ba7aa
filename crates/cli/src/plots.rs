//! Eval plots like the paper's Fig. 11 (histograms of N, log scale) and Fig. 12 (cos θ
//! histograms, simulator in black and model in red; the (cos θ, α), (cos θ, β) densities
//! at g = 0.4, simulator and model side by side).
//!
//! Drawn with plotters into a memory buffer and written as PNG through the atomic writer.

use std::path::Path;

use anyhow::{Context, Result, anyhow};
use cvae::eval::{Columns, GS, TAUS};
use plotters::chart::SeriesLabelPosition;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

/// DejaVu Sans (Bitstream Vera licence, see assets/fonts/LICENSE): plotters' pure-Rust
/// text path needs a font in memory, and system fonts differ between machines.
static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");

fn init_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One grid cell's data: (τ, g, model columns, simulator columns).
pub type Panel<'a> = (f64, f64, &'a Columns, &'a Columns);

/// The columns the plots of a setting at `g` read (log N and cos θ; α and β at the g of
/// the 2-D figures), the others left empty: what `eval` keeps of the grid's samples.
pub fn plotted(c: &Columns, g: f64) -> Columns {
    let mut slim = Columns::default();
    let wanted: &[usize] = if g == GS[2] {
        &[LOG_N, COS, ALPHA, BETA]
    } else {
        &[LOG_N, COS]
    };
    for &q in wanted {
        slim.0[q] = c.0[q].clone();
    }
    slim
}

const LOG_N: usize = 1;
const COS: usize = 2;
const ALPHA: usize = 3;
const BETA: usize = 4;

fn histogram(v: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<f64> {
    let mut h = vec![0f64; bins];
    let w = (hi - lo) / bins as f64;
    for &x in v {
        if x >= lo && x <= hi {
            let i = (((x - lo) / w) as usize).min(bins - 1);
            h[i] += 1.0;
        }
    }
    let total = v.len().max(1) as f64 * w;
    h.iter_mut().for_each(|c| *c /= total);
    h
}

fn steps(h: &[f64], lo: f64, hi: f64) -> Vec<(f64, f64)> {
    let w = (hi - lo) / h.len() as f64;
    h.iter()
        .enumerate()
        .flat_map(|(i, &c)| [(lo + i as f64 * w, c), (lo + (i + 1) as f64 * w, c)])
        .collect()
}

fn encode_png(buf: &[u8], w: u32, h: u32) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()?.write_image_data(buf)?;
    }
    Ok(out)
}

/// A 4 × 4 grid (rows τ, columns g) of 1-D histograms of column `q`.
fn histogram_grid(panels: &[Panel], q: usize, title: &str, log_y: bool) -> Result<Vec<u8>> {
    init_font();
    let (w, h) = (1400u32, 1200u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        // A right margin: the last column's "1.0" tick label ran off the image.
        let root = root
            .titled(title, ("sans-serif", 24))
            .map_err(|e| anyhow!("plot: {e}"))?
            .margin(0, 0, 0, 14);
        let cells = root.split_evenly((TAUS.len(), GS.len()));
        for (cell, &(tau, g, model, sim)) in cells.iter().zip(panels) {
            let (lo, hi) = match q {
                LOG_N => {
                    let m = sim.0[q]
                        .iter()
                        .chain(&model.0[q])
                        .cloned()
                        .fold(0.0, f64::max);
                    (0.0, m.max(1.0))
                }
                _ => (-1.0, 1.0),
            };
            let bins = 50;
            let hs = histogram(&sim.0[q], lo, hi, bins);
            let hm = histogram(&model.0[q], lo, hi, bins);
            let top = hs.iter().chain(&hm).cloned().fold(0.0, f64::max).max(1e-9) * 1.1;
            let caption = format!("τ = {tau}, g = {g}");
            let mut b = ChartBuilder::on(cell);
            b.caption(caption, ("sans-serif", 15))
                .margin(6)
                .x_label_area_size(22)
                .y_label_area_size(52);
            let y_desc = if log_y { "density (log)" } else { "density" };
            if log_y {
                let floor = 1e-4 * top;
                let mut chart = b
                    .build_cartesian_2d(lo..hi, (floor..top).log_scale())
                    .map_err(|e| anyhow!("plot: {e}"))?;
                chart
                    .configure_mesh()
                    .disable_mesh()
                    .x_labels(5)
                    .y_labels(4)
                    .y_desc(y_desc)
                    .label_style(("sans-serif", 11))
                    .draw()
                    .map_err(|e| anyhow!("plot: {e}"))?;
                for (hist, colour) in [(&hs, BLACK), (&hm, RED)] {
                    let pts = steps(hist, lo, hi)
                        .into_iter()
                        .map(|(x, y)| (x, y.max(floor)));
                    chart
                        .draw_series(LineSeries::new(pts, colour.stroke_width(2)))
                        .map_err(|e| anyhow!("plot: {e}"))?;
                }
            } else {
                let mut chart = b
                    .build_cartesian_2d(lo..hi, 0.0..top)
                    .map_err(|e| anyhow!("plot: {e}"))?;
                chart
                    .configure_mesh()
                    .disable_mesh()
                    .x_labels(5)
                    .y_labels(4)
                    .y_desc(y_desc)
                    .label_style(("sans-serif", 11))
                    .draw()
                    .map_err(|e| anyhow!("plot: {e}"))?;
                for (hist, colour) in [(&hs, BLACK), (&hm, RED)] {
                    chart
                        .draw_series(LineSeries::new(steps(hist, lo, hi), colour.stroke_width(2)))
                        .map_err(|e| anyhow!("plot: {e}"))?;
                }
            }
        }
        root.present().map_err(|e| anyhow!("plot: {e}"))?;
    }
    encode_png(&buf, w, h)
}

/// 2-D densities of (cos θ, `q`) for a few settings: simulator left, model right.
fn density_pairs(panels: &[Panel], q: usize, qname: &str) -> Result<Vec<u8>> {
    init_font();
    let bins = 40usize;
    let (w, h) = (900u32, 260 * panels.len() as u32 + 40);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let root = root
            .titled(
                &format!("(cos θ, {qname}) densities: simulator (left) vs model (right)"),
                ("sans-serif", 20),
            )
            .map_err(|e| anyhow!("plot: {e}"))?;
        let rows = root.split_evenly((panels.len(), 2));
        for (i, &(tau, g, model, sim)) in panels.iter().enumerate() {
            let grids: Vec<Vec<f64>> = [sim, model]
                .iter()
                .map(|c| {
                    let mut d = vec![0f64; bins * bins];
                    for (&x, &y) in c.0[COS].iter().zip(&c.0[q]) {
                        let ix = (((x + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1);
                        let iy = (((y + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1);
                        d[iy * bins + ix] += 1.0;
                    }
                    d
                })
                .collect();
            // A shared colour scale per row so the two panels compare directly.
            let top = grids.iter().flatten().cloned().fold(0.0, f64::max).max(1.0);
            for (k, (d, who)) in grids.iter().zip(["simulator", "model"]).enumerate() {
                let mut chart = ChartBuilder::on(&rows[2 * i + k])
                    .caption(format!("{who}: τ = {tau}, g = {g}"), ("sans-serif", 14))
                    .margin(6)
                    .margin_right(16)
                    // Room for the tick labels and "cos θ" under them (they overlapped).
                    .x_label_area_size(36)
                    .y_label_area_size(40)
                    .build_cartesian_2d(-1.0..1.0, -1.0..1.0)
                    .map_err(|e| anyhow!("plot: {e}"))?;
                chart
                    .configure_mesh()
                    .disable_mesh()
                    .x_desc("cos θ")
                    .y_desc(qname)
                    .x_labels(5)
                    .y_labels(5)
                    .label_style(("sans-serif", 11))
                    .draw()
                    .map_err(|e| anyhow!("plot: {e}"))?;
                let cell = 2.0 / bins as f64;
                chart
                    .draw_series((0..bins * bins).map(|j| {
                        let (ix, iy) = (j % bins, j / bins);
                        let v = (d[j] / top).sqrt();
                        let c = (255.0 * (1.0 - v)) as u8;
                        let x0 = -1.0 + ix as f64 * cell;
                        let y0 = -1.0 + iy as f64 * cell;
                        Rectangle::new(
                            [(x0, y0), (x0 + cell, y0 + cell)],
                            RGBColor(c, c, 255).filled(),
                        )
                    }))
                    .map_err(|e| anyhow!("plot: {e}"))?;
            }
        }
        root.present().map_err(|e| anyhow!("plot: {e}"))?;
    }
    encode_png(&buf, w, h)
}

/// The names of [`render_all`]'s plots, in its order (`eval` checks them before it starts).
pub const PLOT_FILES: [&str; 4] = [
    "fig11_n.png",
    "fig12_cos_theta.png",
    "fig12_cos_alpha.png",
    "fig12_cos_beta.png",
];

/// The plots of [`PLOT_FILES`], named and encoded: `eval` writes them with its metrics as
/// one set (a full disk left three plots and no metrics).
pub fn render_all(panels: &[Panel]) -> Result<Vec<(String, Vec<u8>)>> {
    // The paper's Fig. 12 shows a few settings; pick one per τ at g = 0.4 (index 2).
    let few: Vec<Panel> = panels.iter().filter(|p| p.1 == GS[2]).cloned().collect();
    Ok(vec![
        (
            PLOT_FILES[0].to_string(),
            histogram_grid(
                panels,
                LOG_N,
                "ln N (N: a walk's events): simulator (black) vs model (red), log density",
                true,
            )?,
        ),
        (
            PLOT_FILES[1].to_string(),
            histogram_grid(
                panels,
                COS,
                "cos θ: simulator (black) vs model (red)",
                false,
            )?,
        ),
        (PLOT_FILES[2].to_string(), density_pairs(&few, ALPHA, "α")?),
        (PLOT_FILES[3].to_string(), density_pairs(&few, BETA, "β")?),
    ])
}

/// A log axis's ticks between `lo` and `hi` > 0: labelled ones (1, 2 and 5 times a power
/// of ten) and grid lines (every integer multiple). plotters' own log ticks start at the
/// first power of ten inside the axis and label every multiple, so a short axis got no
/// label and a long one overlapping labels. With fewer than two 1-2-5 ticks inside, every
/// multiple is labelled, and failing that the two ends.
fn log_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let (mut bold, mut light) = (Vec::new(), Vec::new());
    for k in (lo.log10().floor() as i32)..=(hi.log10().ceil() as i32) {
        for m in 1..=9 {
            let v = m as f64 * 10f64.powi(k);
            if (lo..=hi).contains(&v) {
                light.push(v);
                if matches!(m, 1 | 2 | 5) {
                    bold.push(v);
                }
            }
        }
    }
    // Beyond four decades the 1-2-5 labels ran into each other (a training's 1 to 400,000
    // steps): powers of ten alone, where two lie inside.
    let decades: Vec<f64> = bold
        .iter()
        .copied()
        .filter(|v| (v.log10().round() - v.log10()).abs() < 1e-9)
        .collect();
    if hi / lo > 1e4 && decades.len() >= 2 {
        bold = decades;
    }
    if bold.len() < 2 {
        bold.clone_from(&light);
    }
    if bold.len() < 2 {
        bold = vec![lo, hi];
    }
    (bold, light)
}

/// A tick label with three significant digits at most and no trailing zeros (0.05, 20,
/// 0.037); from 10,000 on in thousands or millions (50k, 1.5M), which stay short.
fn compact(v: &f64) -> String {
    if !(v.is_finite() && *v != 0.0) {
        return format!("{v}");
    }
    if v.abs() >= 1e6 {
        return compact(&(v / 1e6)) + "M";
    }
    if v.abs() >= 1e4 {
        return compact(&(v / 1e3)) + "k";
    }
    let decimals = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A series with more points is drawn as a line alone.
const MAX_MARKED_POINTS: usize = 60;

/// One named series of a line plot.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Index into the plot's palette; `None` takes the series' own position. Curves that
    /// belong together (one model's training and held-out losses) share a colour.
    pub colour: Option<usize>,
    /// Drawn dashed, to tell apart two curves of one colour.
    pub dashed: bool,
}

impl Series {
    pub fn new(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            name: name.into(),
            points,
            colour: None,
            dashed: false,
        }
    }
}

/// A line plot of a few series (markers at the points of short ones), optionally on log axes; used by
/// the experiments for time / speed-up curves and by `bench error` for error against time.
/// The legend goes in the upper right, above the lines (the y axis grows to make room).
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    axes: (bool, bool),
    series: &[Series],
) -> Result<()> {
    let png = line_plot_png(path, title, x_label, y_label, axes, series)?;
    scatter_sim::output::write_atomic(path, &png)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// [`line_plot`]'s PNG in memory, for a caller that writes it in a set with other files;
/// `path` only names the plot in errors.
pub fn line_plot_png(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    (log_x, log_y): (bool, bool),
    series: &[Series],
) -> Result<Vec<u8>> {
    init_font();
    let (w, h) = (900u32, 600u32);
    let ((x0, x1), (y0, y1)) = axis_ranges(path, (log_x, log_y), series)?;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let e = |e: &dyn std::fmt::Display| anyhow!("plot {}: {e}", path.display());
        macro_rules! draw {
            ($chart:expr) => {{
                let mut chart = $chart;
                let mut mesh = chart.configure_mesh();
                mesh.x_desc(x_label)
                    .y_desc(y_label)
                    .label_style(("sans-serif", 14));
                if log_x {
                    mesh.x_label_formatter(&compact);
                }
                if log_y {
                    mesh.y_label_formatter(&compact);
                }
                mesh.draw().map_err(|x| e(&x))?;
                for (i, s) in series.iter().enumerate() {
                    let c = COLOURS[s.colour.unwrap_or(i) % COLOURS.len()];
                    let p: Vec<(f64, f64)> = s
                        .points
                        .iter()
                        .cloned()
                        .filter(|&(x, y)| plottable(x, log_x) && plottable(y, log_y))
                        .collect();
                    let drawn = if s.dashed {
                        chart.draw_series(DashedLineSeries::new(p.clone(), 8, 5, c.stroke_width(2)))
                    } else {
                        chart.draw_series(LineSeries::new(p.clone(), c.stroke_width(2)))
                    };
                    let dashed = s.dashed;
                    drawn
                        .map_err(|x| e(&x))?
                        .label(s.name.clone())
                        .legend(move |(x, y)| {
                            // A dashed key is two strokes with a gap: a dash that the
                            // key's 18 px can show.
                            let (a, b) = if dashed { (7, 11) } else { (9, 9) };
                            EmptyElement::at((x, y))
                                + PathElement::new(vec![(0, 0), (a, 0)], c.stroke_width(2))
                                + PathElement::new(vec![(b, 0), (18, 0)], c.stroke_width(2))
                        });
                    // Markers only where they can be told apart (a training's hundreds
                    // of readings drew a solid band).
                    if p.len() <= MAX_MARKED_POINTS {
                        // A dashed series' markers hollow, so that they stay apart from
                        // those of the solid series of the same colour.
                        let mark = if s.dashed {
                            c.stroke_width(2)
                        } else {
                            c.filled()
                        };
                        chart
                            .draw_series(p.into_iter().map(|q| Circle::new(q, 4, mark)))
                            .map_err(|x| e(&x))?;
                    }
                }
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperRight)
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 14))
                    .draw()
                    .map_err(|x| e(&x))?;
            }};
        }
        let log_axis = |lo: f64, hi: f64, keys: Option<Vec<f64>>| {
            let (bold, light) = log_ticks(lo, hi);
            (lo..hi)
                .log_scale()
                .with_key_points(keys.unwrap_or(bold))
                .with_light_points(light)
        };
        let ladder = || ladder_ticks(series, (x0, x1));
        let mut b = ChartBuilder::on(&root);
        b.caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60);
        match (log_x, log_y) {
            (false, false) => draw!(b.build_cartesian_2d(x0..x1, y0..y1).map_err(|x| e(&x))?),
            (true, false) => {
                draw!(
                    b.build_cartesian_2d(log_axis(x0, x1, ladder()), y0..y1)
                        .map_err(|x| e(&x))?
                )
            }
            (false, true) => {
                draw!(
                    b.build_cartesian_2d(x0..x1, log_axis(y0, y1, None))
                        .map_err(|x| e(&x))?
                )
            }
            (true, true) => draw!(
                b.build_cartesian_2d(log_axis(x0, x1, ladder()), log_axis(y0, y1, None))
                    .map_err(|x| e(&x))?
            ),
        }
        root.present().map_err(|x| e(&x))?;
    }
    encode_png(&buf, w, h)
}

/// The labelled ticks of a log x axis where every series is drawn at the same few x
/// values (a ladder of densities or absorptions): those values, so that k = 4 and 8 or
/// 2^-11 … 2^-5 are labelled where the 1-2-5 ticks labelled none of them. None otherwise
/// (times, training steps), and the axis keeps its 1-2-5 ticks. `span`: the axis' range.
fn ladder_ticks(series: &[Series], (x0, x1): Span) -> Option<Vec<f64>> {
    let xs = |s: &Series| {
        let mut v: Vec<f64> = s
            .points
            .iter()
            .map(|p| p.0)
            .filter(|&x| plottable(x, true))
            .collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };
    let first = xs(series.first()?);
    let shared = series.iter().all(|s| xs(s) == first);
    // Labels apart on the axis, or 900 and 1,000 ran into each other.
    let width = (x1 / x0).ln();
    let apart = first
        .windows(2)
        .all(|w| (w[1] / w[0]).ln() >= MIN_LADDER_GAP * width);
    (shared && apart && (2..=MAX_LADDER_TICKS).contains(&first.len())).then_some(first)
}

/// Most ticks a ladder gets (more would run into each other on a 900 px axis).
const MAX_LADDER_TICKS: usize = 10;

/// Least gap between neighbouring ladder labels, as a share of the log axis' width (~40 px
/// of the ~820 px plot; 1, 2, 4, 8 are a quarter of theirs apart).
const MIN_LADDER_GAP: f64 = 0.05;

/// Whether a coordinate can be drawn: finite, and positive on a log axis.
fn plottable(v: f64, log: bool) -> bool {
    v.is_finite() && (!log || v > 0.0)
}

/// The series' colours, in order (a series may pick one by its index).
const COLOURS: [RGBColor; 10] = [
    BLACK,
    RED,
    BLUE,
    GREEN,
    MAGENTA,
    CYAN,
    RGBColor(255, 140, 0),
    RGBColor(128, 128, 128),
    RGBColor(128, 64, 0),
    RGBColor(0, 110, 0),
];

/// An axis's range: its lowest and highest value.
type Span = (f64, f64);

/// The x and y ranges that hold every finite point (positive on a log axis) with a margin,
/// the y range grown to make room for the legend above the lines.
fn axis_ranges(
    path: &Path,
    (log_x, log_y): (bool, bool),
    series: &[Series],
) -> Result<(Span, Span)> {
    let pts = || series.iter().flat_map(|s| s.points.iter().cloned());
    let xs: Vec<f64> = pts()
        .map(|p| p.0)
        .filter(|&v| plottable(v, log_x))
        .collect();
    let ys: Vec<f64> = pts()
        .map(|p| p.1)
        .filter(|&v| plottable(v, log_y))
        .collect();
    if xs.is_empty() || ys.is_empty() {
        return Err(anyhow!("plot {}: no finite points", path.display()));
    }
    let span = |v: &[f64], log: bool| {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if log {
            (lo / 1.3, hi * 1.3)
        } else {
            let pad = ((hi - lo) * 0.08).max(1e-9 + lo.abs() * 0.05);
            (lo - pad, hi + pad)
        }
    };
    let (x0, x1) = span(&xs, log_x);
    let (y0, y1) = span(&ys, log_y);
    // The y axis grows by the legend's height (20 px a series on a ~480 px plot), so the
    // legend sits above every line in the upper right.
    let f = ((series.len() as f64 * 20.0 + 24.0) / 480.0).min(0.6);
    let y1 = if log_y {
        y1 * (y1 / y0).powf(f / (1.0 - f))
    } else {
        y1 + (y1 - y0) * f / (1.0 - f)
    };
    Ok(((x0, x1), (y0, y1)))
}

#[cfg(test)]
mod tests {
    use super::{
        BETA, COS, Series, axis_ranges, compact, density_pairs, histogram, ladder_ticks, log_ticks,
        steps,
    };
    use cvae::eval::{Columns, GS, TAUS};

    /// A histogram is a density over [lo, hi], both ends counted: of 0, 0.5, 1 and 2, bin
    /// [0, 0.5) holds 0 and bin [0.5, 1] holds 0.5 and 1 (2 is outside): densities 1/2 =
    /// 0.5 and 2/2 = 1.0, over 4 samples × width 0.5.
    #[test]
    fn a_histogram_is_a_density_with_both_ends_counted() {
        assert_eq!(
            histogram(&[0.0, 0.5, 1.0, 2.0], 0.0, 1.0, 2),
            vec![0.5, 1.0]
        );
        assert_eq!(
            steps(&[1.0, 2.0], 0.0, 1.0),
            vec![(0.0, 1.0), (0.5, 1.0), (0.5, 2.0), (1.0, 2.0)]
        );
    }

    /// The density figure puts cos θ across and the quantity up, the simulator's panel
    /// left: the simulator's walks all at cos θ = 0.9, the model's at −0.9, both at
    /// β = −0.9, fill one cell each, drawn pure blue (the row's top density). The image is
    /// 900 × 300 with two 450-px panels, so the simulator's cell lies in the left panel's
    /// right half, the model's in the right panel's left half, both in the lower half.
    #[test]
    fn the_density_figures_put_cos_theta_across_beta_up_and_the_simulator_left() {
        let column = |cos: f64, beta: f64| {
            let mut c = Columns::default();
            c.0[COS] = vec![cos; 100];
            c.0[BETA] = vec![beta; 100];
            c
        };
        let (sim, model) = (column(0.9, -0.9), column(-0.9, -0.9));
        let bytes = density_pairs(&[(TAUS[0], GS[2], &model, &sim)], BETA, "β").unwrap();
        let mut dec = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; dec.output_buffer_size()];
        let info = dec.next_frame(&mut buf).unwrap();
        let w = info.width as usize;
        assert_eq!((w, info.height), (900, 300));
        let blue: Vec<(usize, usize)> = buf
            .chunks(3)
            .enumerate()
            .filter(|(_, p)| p[..] == [0u8, 0, 255][..])
            .map(|(i, _)| (i % w, i / w))
            .collect();
        let (left, right): (Vec<&(usize, usize)>, Vec<_>) = blue.iter().partition(|p| p.0 < 450);
        assert!(!left.is_empty() && !right.is_empty(), "{blue:?}");
        assert!(
            left.iter().all(|p| p.0 > 225),
            "the simulator's cell: {left:?}"
        );
        assert!(
            right.iter().all(|p| p.0 < 675),
            "the model's cell: {right:?}"
        );
        assert!(blue.iter().all(|p| p.1 > 150), "β = −0.9 not low: {blue:?}");
    }

    /// The axes hold every drawable point: on a log x axis x = 0 is dropped and the range
    /// widened by 1.3 either way; a linear y axis is padded by 8 % of its span (4), then
    /// grown for the legend by f/(1 − f), f = 44/480 for one series; a log y axis by the
    /// ratio to that power. The figures are those rules replayed by hand.
    #[test]
    fn the_axes_hold_every_drawable_point_with_room_for_the_legend() {
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1.0);
        let s = [Series::new("s", vec![(0.0, -1.0), (1.0, 1.0), (10.0, 3.0)])];
        let p = std::path::Path::new("p.png");
        let ((x0, x1), (y0, y1)) = axis_ranges(p, (true, false), &s).unwrap();
        assert!(near(x0, 1.0 / 1.3) && near(x1, 13.0), "{x0} {x1}");
        // 3.32 + 4.64 · (44/480)/(1 − 44/480)
        assert!(near(y0, -1.32) && near(y1, 3.788256880733945), "{y0} {y1}");
        let (_, (y0, y1)) = axis_ranges(p, (true, true), &s).unwrap();
        // 3.9 · (3.9 · 1.3)^(f/(1 − f))
        assert!(
            near(y0, 1.0 / 1.3) && near(y1, 4.594224349477525),
            "{y0} {y1}"
        );
    }

    /// A ladder shared by every series labels its own values (k = 4 and 8 had no label
    /// among 1, 2, 5, 10); times that differ between series, a single point or a training's
    /// hundreds of steps keep the 1-2-5 ticks. Zero and negative x (off a log axis) are
    /// left out of the ladder.
    #[test]
    fn a_shared_ladder_labels_its_own_values() {
        let at = |xs: &[f64]| Series::new("s", xs.iter().map(|&x| (x, 1.0)).collect());
        let k = [1.0, 2.0, 4.0, 8.0];
        assert_eq!(
            ladder_ticks(&[at(&k), at(&[8.0, 4.0, 2.0, 1.0, 0.0])], (0.77, 10.4)),
            Some(k.to_vec())
        );
        assert_eq!(
            ladder_ticks(&[at(&k), at(&[1.0, 2.0, 4.0])], (0.77, 10.4)),
            None
        );
        assert_eq!(ladder_ticks(&[at(&[3.0])], (2.3, 3.9)), None);
        let steps: Vec<f64> = (1..=40).map(|i| 500.0 * i as f64).collect();
        assert_eq!(ladder_ticks(&[at(&steps)], (385.0, 26_000.0)), None);
        // A short training's steps: 900 and 1,000 would overlap.
        let short: Vec<f64> = (1..=10).map(|i| 100.0 * i as f64).collect();
        assert_eq!(ladder_ticks(&[at(&short)], (77.0, 1300.0)), None);
        // 10 rungs a factor 2 apart are labelled; 11 are one too many (MAX_LADDER_TICKS).
        let rungs = |n: i32| (0..n).map(|i| 2f64.powi(i)).collect::<Vec<f64>>();
        assert_eq!(
            ladder_ticks(&[at(&rungs(10))], (0.77, 665.0)),
            Some(rungs(10))
        );
        assert_eq!(ladder_ticks(&[at(&rungs(11))], (0.77, 1330.0)), None);
    }

    #[test]
    fn log_axes_label_one_two_and_five_per_decade_or_enough_to_read() {
        let near = |got: &[f64], want: &[f64]| {
            got.len() == want.len() && got.iter().zip(want).all(|(g, w)| (g - w).abs() <= 1e-9 * w)
        };
        // An error axis from 0.03 to 0.26: 0.05 is labelled (plotters started at 0.1).
        let (bold, light) = log_ticks(0.03, 0.26);
        assert!(near(&bold, &[0.05, 0.1, 0.2]), "{bold:?}");
        assert_eq!(light.len(), 9, "{light:?}"); // 0.03 … 0.09, 0.1, 0.2
        // Within a decade without two 1-2-5 ticks: every multiple.
        let (bold, _) = log_ticks(2.5, 9.5);
        assert!(
            near(&bold, &[3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]),
            "{bold:?}"
        );
        // One image's point (the axis spans ×1.69 around it) with no multiple inside: the ends.
        let (bold, _) = log_ticks(1.1, 1.86);
        assert!(near(&bold, &[1.1, 1.86]), "{bold:?}");
        // A training's steps, 1 to 400,000 (and the axis' padding): powers of ten alone
        // (the 1-2-5 labels of five decades ran into each other).
        let (bold, _) = log_ticks(0.77, 520_000.0);
        assert!(near(&bold, &[1.0, 10.0, 100.0, 1e3, 1e4, 1e5]), "{bold:?}");
        for (v, want) in [
            (0.1 * 0.5, "0.05"),
            (0.2, "0.2"),
            (20.0, "20"),
            (2.0 * 10f64.powi(2), "200"),
            (0.0372, "0.0372"),
            (1.86, "1.86"),
            (1234.6, "1235"),
            (50_000.0, "50k"),
            (400_000.0, "400k"),
            (1.5e6, "1.5M"),
        ] {
            assert_eq!(compact(&v), want, "{v}");
        }
    }

    /// Fig. 12's (cos θ, β) figure draws β, and its (cos θ, α) figure draws α. Grids alike
    /// but for β (all +0.9 in one, all −0.9 in the other, so every sample lands in another
    /// row of the 40 × 40 density bins) give two β figures and one α figure; grids alike but
    /// for α (spread, or all +0.9), two α figures and one β figure. One panel, at g = GS[2]
    /// (0.4), the g `render_all` takes for these figures.
    #[test]
    fn the_beta_figure_draws_beta_and_the_alpha_figure_alpha() {
        use super::{ALPHA, BETA, COS, LOG_N, render_all};
        use cvae::eval::{Columns, GS, TAUS};
        let figures = |alpha_spread: bool, beta: f64| {
            let n = 200;
            let mut c = Columns::default();
            c.0[LOG_N] = (0..n).map(|i| (1.0 + (i % 10) as f64).ln()).collect();
            c.0[COS] = (0..n).map(|i| -0.99 + 1.98 * i as f64 / n as f64).collect();
            c.0[ALPHA] = (0..n)
                .map(|i| match alpha_spread {
                    true => ((7 * i) % n) as f64 / n as f64 - 0.5,
                    false => 0.9,
                })
                .collect();
            c.0[BETA] = vec![beta; n];
            render_all(&[(TAUS[0], GS[2], &c, &c)]).unwrap()
        };
        let (up, down, still) = (figures(true, 0.9), figures(true, -0.9), figures(false, 0.9));
        assert_eq!(
            (up[2].0.as_str(), up[3].0.as_str()),
            ("fig12_cos_alpha.png", "fig12_cos_beta.png")
        );
        assert!(up[3].1 != down[3].1, "the β figure does not show β");
        assert!(up[2].1 == down[2].1, "the α figure changed with β");
        assert!(up[2].1 != still[2].1, "the α figure does not show α");
        assert!(up[3].1 == still[3].1, "the β figure changed with α");
    }

    /// The plots read their columns by index into `eval`'s `QUANTITIES`: ln N, cos θ, α and
    /// β must be those columns. An index one off drew the event's distance from the centre
    /// as β, and the figure tests above, which fill the columns by the same indices, passed.
    #[test]
    fn the_plots_column_indices_name_their_quantities() {
        use super::{ALPHA, BETA, COS, LOG_N};
        use cvae::eval::QUANTITIES;
        assert_eq!(
            [
                QUANTITIES[LOG_N],
                QUANTITIES[COS],
                QUANTITIES[ALPHA],
                QUANTITIES[BETA]
            ],
            ["log_n", "cos_theta", "alpha", "beta"]
        );
    }

    /// What `eval` keeps of a grid setting's samples for the plots (`plotted`): ln N and
    /// cos θ at every g, and α and β too at g = 0.4, the g of the (cos θ, α) and (cos θ, β)
    /// figures (`render_all` draws them from the panels at GS[2]); nothing else. α and β
    /// kept at another g left those figures' panels blank (every density bin 0), without
    /// an error.
    #[test]
    fn the_plotted_columns_keep_alpha_and_beta_at_the_figures_g() {
        use super::{ALPHA, BETA, COS, LOG_N, plotted};
        use cvae::eval::{Columns, GS};
        let mut c = Columns::default();
        for (q, col) in c.0.iter_mut().enumerate() {
            *col = vec![q as f64 + 0.5; 3];
        }
        for g in GS {
            let wanted: &[usize] = if g == 0.4 {
                &[LOG_N, COS, ALPHA, BETA]
            } else {
                &[LOG_N, COS]
            };
            let kept = plotted(&c, g);
            for (q, col) in kept.0.iter().enumerate() {
                let want = if wanted.contains(&q) {
                    c.0[q].clone()
                } else {
                    Vec::new()
                };
                assert_eq!(col, &want, "g = {g}, column {q}");
            }
        }
    }
}
