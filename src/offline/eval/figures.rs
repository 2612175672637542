//! The evaluation report's figures, drawn with plotters as SVG: residual
//! decay bands, curves over a shared axis (or on log-log axes), trajectory
//! plots and time snapshots of a scene.

use std::path::Path;

use anyhow::{Result, anyhow};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Obstacle, Problem};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::measures::Band;

/// Font of titles and labels.
const FONT: &str = "sans-serif";

/// A named, coloured series of points.
pub struct Curve {
    /// Legend label.
    pub label: String,
    /// Colour index (see [`colour`]).
    pub colour: usize,
    /// Points `(x, y)`.
    pub points: Vec<(f64, f64)>,
}

/// A named, coloured residual band.
pub struct BandCurve {
    /// Legend label.
    pub label: String,
    /// Colour index (see [`colour`]).
    pub colour: usize,
    /// The band.
    pub band: Band,
}

/// One panel of residual bands.
pub struct BandPanel {
    /// Panel title.
    pub title: String,
    /// Y axis label.
    pub y_desc: String,
    /// The bands.
    pub bands: Vec<BandCurve>,
}

/// One trajectory panel: a problem and the plan drawn over it.
pub struct PlanPanel<'a> {
    /// Panel title.
    pub title: String,
    /// The problem (starts, goals, obstacles, workspace).
    pub problem: &'a Problem,
    /// The plan's coefficients.
    pub xi: &'a [f64],
}

/// The colour of series `i`: the methods keep one colour each across figures.
pub fn colour(i: usize) -> RGBColor {
    const COLOURS: [RGBColor; 5] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
    ];
    COLOURS[i % COLOURS.len()]
}

/// A distinct colour per robot.
fn robot_colour(i: usize, n: usize) -> RGBColor {
    let (r, g, b) = hsl_to_rgb(i as f64 / n.max(1) as f64, 0.7, 0.45);
    RGBColor(r, g, b)
}

fn hsl_to_rgb(h: f64, s: f64, l: f64) -> (u8, u8, u8) {
    let c = (1.0 - (2.0 * l - 1.0).abs()) * s;
    let x = c * (1.0 - ((h * 6.0) % 2.0 - 1.0).abs());
    let (r, g, b) = match (h * 6.0) as usize {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = l - c / 2.0;
    let byte = |v: f64| ((v + m) * 255.0).round().clamp(0.0, 255.0) as u8;
    (byte(r), byte(g), byte(b))
}

/// Residual decay: one panel per entry of `panels` (in a grid of
/// `columns`), mean lines with 10-90% bands on a log axis.
pub fn residual_bands(path: &Path, panels: &[BandPanel], columns: usize) -> Result<()> {
    let rows = panels.len().div_ceil(columns.max(1));
    let root = SVGBackend::new(path, (480 * columns as u32, 360 * rows as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    for (area, panel) in root.split_evenly((rows, columns)).iter().zip(panels) {
        let length = panel.bands.iter().map(|b| b.band.mean.len()).max().unwrap_or(1).max(2);
        let values = panel.bands.iter().flat_map(|b| b.band.low.iter().chain(&b.band.high));
        let (lo, hi) = log_range(values);
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, (FONT, 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..(length - 1) as f64, (lo..hi).log_scale())?;
        chart.configure_mesh().x_desc("iteration").y_desc(panel.y_desc.as_str()).draw()?;
        for b in &panel.bands {
            let c = colour(b.colour);
            let upper = b.band.high.iter().enumerate().map(|(l, &v)| (l as f64, v.clamp(lo, hi)));
            let lower = b.band.low.iter().enumerate().rev().map(|(l, &v)| (l as f64, v.clamp(lo, hi)));
            let outline: Vec<(f64, f64)> = upper.chain(lower).filter(|p| p.1.is_finite()).collect();
            chart.draw_series(std::iter::once(Polygon::new(outline, c.mix(0.18).filled())))?;
            let line: Vec<(f64, f64)> = b
                .band
                .mean
                .iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite())
                .map(|(l, &v)| (l as f64, v.clamp(lo, hi)))
                .collect();
            chart
                .draw_series(LineSeries::new(line, c.stroke_width(2)))?
                .label(b.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        }
        chart.configure_series_labels().background_style(WHITE.mix(0.85)).border_style(BLACK).draw()?;
    }
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

/// A range covering the finite positive `values` on a log axis.
fn log_range<'a>(values: impl Iterator<Item = &'a f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && **v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    if lo > hi { (1e-4, 1.0) } else { (lo.max(1e-8) / 2.0, hi * 2.0) }
}

/// Curves over a shared x axis (log-scaled if `log_x`), y in `y_range`.
pub fn curves(
    path: &Path,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    curves: &[Curve],
    log_x: bool,
    y_range: (f64, f64),
) -> Result<()> {
    let root = SVGBackend::new(path, (720, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let xs = curves.iter().flat_map(|c| c.points.iter().map(|p| p.0)).filter(|x| x.is_finite());
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    let (x0, x1) = if x0 < x1 { (x0, x1) } else { (0.0, 1.0) };
    let mut builder = ChartBuilder::on(&root);
    builder.caption(title, (FONT, 20)).margin(14).x_label_area_size(40).y_label_area_size(56);
    if log_x {
        let mut chart = builder.build_cartesian_2d((x0..x1).log_scale(), y_range.0..y_range.1)?;
        chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw()?;
        draw_curves(&mut chart, curves)?;
    } else {
        let mut chart = builder.build_cartesian_2d(x0..x1, y_range.0..y_range.1)?;
        chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).draw()?;
        draw_curves(&mut chart, curves)?;
    }
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

/// Curves on log-log axes, the x axis labelled at the points' x values
/// (points with a value of 0 or less, which a log axis cannot show, are
/// left out).
pub fn log_log(path: &Path, title: &str, (x_desc, y_desc): (&str, &str), curves: &[Curve]) -> Result<()> {
    let shown: Vec<Curve> = curves
        .iter()
        .map(|c| Curve {
            label: c.label.clone(),
            colour: c.colour,
            points: c.points.iter().copied().filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite()).collect(),
        })
        .collect();
    let mut xs: Vec<f64> = shown.iter().flat_map(|c| c.points.iter().map(|p| p.0)).collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let (x0, x1) = xs.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    let (x0, x1) = if x0 < x1 { (x0 / 1.25, x1 * 1.25) } else { (1.0, 10.0) };
    let (y0, y1) = log_range(shown.iter().flat_map(|c| c.points.iter().map(|p| &p.1)));
    let root = SVGBackend::new(path, (720, 440)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 20))
        .margin(14)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d((x0..x1).log_scale().with_key_points(xs), (y0..y1).log_scale())?;
    chart.configure_mesh().x_desc(x_desc).y_desc(y_desc).x_label_formatter(&|x| format!("{x}")).draw()?;
    draw_curves(&mut chart, &shown)?;
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

fn draw_curves<'a, X>(chart: &mut ChartContext<'a, SVGBackend<'a>, X>, curves: &[Curve]) -> Result<()>
where
    X: plotters::coord::CoordTranslate<From = (f64, f64)>,
{
    for c in curves {
        let col = colour(c.colour);
        // A point without a value (no successful instance) is left out.
        let points: Vec<(f64, f64)> = c.points.iter().copied().filter(|p| p.1.is_finite()).collect();
        chart
            .draw_series(LineSeries::new(points.clone(), col.stroke_width(2)))?
            .label(c.label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col.stroke_width(2)));
        chart.draw_series(points.into_iter().map(|p| Circle::new(p, 3, col.filled())))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// The workspace box of a 2D problem as plot ranges, with a small margin.
fn plot_ranges(problem: &Problem) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let w = &problem.team.workspace;
    let pad = 0.15;
    ((w.min[0] - pad)..(w.max[0] + pad), (w.min[1] - pad)..(w.max[1] + pad))
}

/// A polygon approximating a disc of `radius` (data units) at `centre`.
fn disc(centre: (f64, f64), radius: f64) -> Vec<(f64, f64)> {
    (0..32)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 32.0;
            (centre.0 + radius * a.cos(), centre.1 + radius * a.sin())
        })
        .collect()
}

/// Positions of every robot at `samples` instants, `[robot][instant]`.
fn paths(problem: &Problem, xi: &[f64], samples: usize) -> Vec<Vec<(f64, f64)>> {
    let n = problem.robots();
    let p = JointPlan::new(&problem.team, xi.to_vec()).sampled(samples, 0);
    (0..n).map(|i| (0..samples).map(|k| (p[i * samples + k], p[(n + i) * samples + k])).collect()).collect()
}

/// A chart over data coordinates.
type Chart<'a> = ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws the workspace box and the obstacles at time `t`.
fn draw_scene<'a>(chart: &mut Chart<'a>, problem: &Problem, t: f64) -> Result<()> {
    let w = &problem.team.workspace;
    let corners = [(w.min[0], w.min[1]), (w.max[0], w.min[1]), (w.max[0], w.max[1]), (w.min[0], w.max[1])];
    let mut outline = corners.to_vec();
    outline.push(corners[0]);
    chart.draw_series(std::iter::once(PathElement::new(outline, BLACK.stroke_width(1))))?;
    for o in &problem.obstacles {
        draw_obstacle(chart, o, t)?;
    }
    Ok(())
}

fn draw_obstacle<'a>(chart: &mut Chart<'a>, o: &Obstacle, t: f64) -> Result<()> {
    let p = o.at(t);
    chart.draw_series(std::iter::once(Polygon::new(disc((p[0], p[1]), o.shape.radius), BLACK.mix(0.35).filled())))?;
    if o.velocity.norm() > 0.0 {
        let q = p + o.velocity * 0.5;
        chart
            .draw_series(std::iter::once(PathElement::new(vec![(p[0], p[1]), (q[0], q[1])], BLACK.stroke_width(2))))?;
    }
    Ok(())
}

/// Trajectory plots of 2D plans side by side: each robot's path, its start
/// (open disc of the robot's size) and goal (cross), obstacles at t = 0
/// (grey; moving ones with a half-second velocity arrow), the workspace box.
pub fn trajectories(path: &Path, panels: &[PlanPanel<'_>]) -> Result<()> {
    let root = SVGBackend::new(path, (460 * panels.len() as u32, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    for (area, panel) in root.split_evenly((1, panels.len())).iter().zip(panels) {
        draw_plan(area, panel, None)?;
    }
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

/// Snapshots of 2D plans: one row per panel, one column per instant in
/// `times` (s): robots as discs of their size at that instant with their
/// path so far, obstacles where they are then.
pub fn snapshots(path: &Path, panels: &[PlanPanel<'_>], times: &[f64]) -> Result<()> {
    let root = SVGBackend::new(path, (330 * times.len() as u32, 350 * panels.len() as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    let areas = root.split_evenly((panels.len(), times.len()));
    for (r, panel) in panels.iter().enumerate() {
        for (c, &t) in times.iter().enumerate() {
            draw_plan(&areas[r * times.len() + c], panel, Some(t))?;
        }
    }
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

/// One plan panel: the whole plan (`at = None`) or its state at an instant.
fn draw_plan(area: &DrawingArea<SVGBackend<'_>, Shift>, panel: &PlanPanel<'_>, at: Option<f64>) -> Result<()> {
    let problem = panel.problem;
    let (xr, yr) = plot_ranges(problem);
    let caption = match at {
        Some(t) => format!("{}, t = {t:.2} s", panel.title),
        None => panel.title.clone(),
    };
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, if at.is_some() { 15 } else { 18 }))
        .margin(10)
        .x_label_area_size(28)
        .y_label_area_size(36)
        .build_cartesian_2d(xr, yr)?;
    chart.configure_mesh().disable_mesh().x_labels(5).y_labels(5).draw()?;
    draw_scene(&mut chart, problem, at.unwrap_or(0.0))?;
    let samples = 200;
    let horizon = problem.team.horizon;
    let radius = problem.team.robot.radius;
    let n = problem.robots();
    for (i, path) in paths(problem, panel.xi, samples).into_iter().enumerate() {
        let c = robot_colour(i, n);
        let upto = match at {
            Some(t) => ((t / horizon) * (samples - 1) as f64).round() as usize + 1,
            None => samples,
        };
        let shown: Vec<(f64, f64)> = path[..upto.min(samples)].to_vec();
        chart.draw_series(std::iter::once(PathElement::new(shown.clone(), c.stroke_width(2))))?;
        let goal = problem.goals[i];
        let s = radius * 0.6;
        for (a, b) in [((-s, -s), (s, s)), ((-s, s), (s, -s))] {
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(goal[0] + a.0, goal[1] + a.1), (goal[0] + b.0, goal[1] + b.1)],
                c.stroke_width(2),
            )))?;
        }
        match at {
            Some(_) => {
                let here = *shown.last().unwrap_or(&path[0]);
                chart.draw_series(std::iter::once(Polygon::new(disc(here, radius), c.mix(0.6).filled())))?;
            }
            None => {
                let mut ring = disc(path[0], radius);
                ring.push(ring[0]);
                chart.draw_series(std::iter::once(PathElement::new(ring, c.stroke_width(1))))?;
            }
        }
    }
    Ok(())
}
