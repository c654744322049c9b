//! A scatter chart on logarithmic axes: one colour per series, its points joined in order,
//! each point labelled, a legend; what `facesim bench tradeoff` draws its time-against-error
//! curves with.

use plotters::prelude::*;

use super::{Canvas, FONT, PlotError, draw_error, rgb};

/// Points of one series, joined in the order given.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub name: String,
    pub colour: [u8; 3],
    /// `(x, y)`; both must be finite and positive (log axes).
    pub points: Vec<(f64, f64)>,
    /// One short label per point (may be empty).
    pub labels: Vec<String>,
}

/// A log–log chart.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
}

/// Colours that stay apart on white (Okabe–Ito).
pub const PALETTE: [[u8; 3]; 6] = [
    [0, 114, 178],
    [213, 94, 0],
    [0, 158, 115],
    [204, 121, 167],
    [230, 159, 0],
    [86, 180, 233],
];

const WIDTH: usize = 1000;
const HEIGHT: usize = 620;
/// The legend's column, right of the chart (it never covers the data).
const LEGEND_W: usize = 290;

/// The decades `[lo, hi]` of a log axis that cover `values` (at least one decade wide).
fn decades(values: impl Iterator<Item = f64>) -> (i32, i32) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0, 1);
    }
    let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    (a, b.max(a + 1))
}

/// A tick value on a log axis: `0.001`, `10`, `2000`.
fn tick_label(v: f64) -> String {
    let digits = (-v.log10().floor()).max(0.0) as usize;
    format!("{v:.digits$}")
}

/// Draws `chart`: the curves on log–log axes with a grid, each point's label beside it (a
/// label already drawn at the same place is not drawn again, so coinciding series do not
/// double it), and the legend in a column of its own. A point that is not finite and
/// positive is an error, not a silent gap.
pub fn draw(chart: &Chart) -> Result<Canvas, PlotError> {
    for s in &chart.series {
        if let Some(p) = s
            .points
            .iter()
            .find(|(x, y)| !(x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0))
        {
            return Err(PlotError::Draw(format!(
                "series {}: point {p:?} cannot go on log axes",
                s.name
            )));
        }
    }
    let all = || chart.series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = decades(all().map(|p| p.0));
    let (y0, y1) = decades(all().map(|p| p.1));
    Canvas::draw(WIDTH, HEIGHT, |root| {
        let titled = root.titled(&chart.title, (FONT, 22)).map_err(draw_error)?;
        let (plot_area, legend_area) = titled.split_horizontally((WIDTH - LEGEND_W) as u32);
        let mut c = ChartBuilder::on(&plot_area)
            .margin(14)
            .x_label_area_size(56)
            .y_label_area_size(84)
            .build_cartesian_2d(
                // A hair past the end decades, so their ticks are drawn too.
                (0.999 * 10f64.powi(x0)..1.001 * 10f64.powi(x1)).log_scale(),
                (0.999 * 10f64.powi(y0)..1.001 * 10f64.powi(y1)).log_scale(),
            )
            .map_err(draw_error)?;
        c.configure_mesh()
            .x_desc(&chart.x_label)
            .y_desc(&chart.y_label)
            .axis_desc_style((FONT, 17))
            .label_style((FONT, 15))
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .light_line_style(rgb([238, 238, 238]))
            .bold_line_style(rgb([205, 205, 205]))
            .draw()
            .map_err(draw_error)?;
        let mut placed: Vec<(i32, i32, String)> = Vec::new();
        for s in &chart.series {
            let colour = rgb(s.colour);
            c.draw_series(LineSeries::new(
                s.points.iter().copied(),
                colour.stroke_width(2),
            ))
            .map_err(draw_error)?;
            c.draw_series(s.points.iter().map(|&p| Circle::new(p, 5, colour.filled())))
                .map_err(draw_error)?;
            for (p, label) in s.points.iter().zip(&s.labels) {
                if label.is_empty() {
                    continue;
                }
                let (px, py) = c.backend_coord(p);
                let (mut lx, mut ly) = (px + 9, py - 9);
                let near = |(x, y, _): &&(i32, i32, String), lx: i32, ly: i32| {
                    (x - lx).abs() < 14 && (y - ly).abs() < 16
                };
                if placed.iter().any(|q| near(&q, lx, ly) && q.2 == *label) {
                    continue;
                }
                while placed.iter().any(|q| near(&q, lx, ly)) {
                    ly += 16;
                }
                lx = lx.min((WIDTH - LEGEND_W) as i32 - 20);
                // `backend_coord` is in the whole picture's pixels.
                root.draw(&Text::new(label.clone(), (lx, ly), (FONT, 16)))
                    .map_err(draw_error)?;
                placed.push((lx, ly, label.clone()));
            }
        }
        for (i, s) in chart.series.iter().enumerate() {
            let y = 70 + 28 * i as i32;
            let colour = rgb(s.colour);
            legend_area
                .draw(&PathElement::new(
                    vec![(8, y + 8), (40, y + 8)],
                    colour.stroke_width(2),
                ))
                .map_err(draw_error)?;
            legend_area
                .draw(&Circle::new((24, y + 8), 5, colour.filled()))
                .map_err(draw_error)?;
            legend_area
                .draw(&Text::new(s.name.clone(), (50, y), (FONT, 15)))
                .map_err(draw_error)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chart(points: Vec<(f64, f64)>) -> Chart {
        Chart {
            title: "T".into(),
            x_label: "X".into(),
            y_label: "Y".into(),
            series: vec![Series {
                name: "A".into(),
                colour: PALETTE[0],
                labels: vec![String::new(); points.len()],
                points,
            }],
        }
    }

    #[test]
    fn points_land_on_their_decades_and_bad_points_are_refused() {
        let c = draw(&chart(vec![(1.0, 0.01), (100.0, 1.0)])).unwrap();
        // x decades 0..2 and y decades -2..0: the two points sit at opposite corners of the
        // plot, so the series' colour spans most of the chart's width and height, left of
        // the legend column, and the line between them passes through the middle.
        let (mut lo, mut hi) = ((usize::MAX, usize::MAX), (0, 0));
        for y in 0..c.height {
            for x in 0..WIDTH - LEGEND_W {
                if c.pixel(x, y) == PALETTE[0] {
                    lo = (lo.0.min(x), lo.1.min(y));
                    hi = (hi.0.max(x), hi.1.max(y));
                }
            }
        }
        assert!(hi.0 - lo.0 > (WIDTH - LEGEND_W) * 2 / 3, "{lo:?} {hi:?}");
        assert!(hi.1 - lo.1 > HEIGHT * 2 / 3, "{lo:?} {hi:?}");
        let mid = ((lo.0 + hi.0) / 2, (lo.1 + hi.1) / 2);
        let near = (0..7).any(|d| c.pixel(mid.0, mid.1 + d - 3) == PALETTE[0]);
        assert!(near, "the line misses the middle {mid:?}");
        // The legend's swatch is in its own column.
        let legend =
            (WIDTH - LEGEND_W..WIDTH).any(|x| (0..HEIGHT).any(|y| c.pixel(x, y) == PALETTE[0]));
        assert!(legend);
        assert!(draw(&chart(vec![(1.0, 0.0)])).is_err());
        assert!(draw(&chart(vec![(f64::NAN, 1.0)])).is_err());
    }
}
