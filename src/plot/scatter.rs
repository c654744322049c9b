//! A scatter chart on logarithmic axes: one colour per series, its points joined in order,
//! each point labelled, a legend; what `facesim bench tradeoff` draws its time-against-error
//! curves with.

use super::{BLACK, Canvas, SCALE, font};

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

const WIDTH: usize = 900;
const HEIGHT: usize = 600;
const LEFT: usize = 110;
const RIGHT: usize = 40;
const TOP: usize = 76;
const BOTTOM: usize = 80;
const GRID: [u8; 3] = [225, 225, 225];

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

fn decade_label(k: i32) -> String {
    let v = 10f64.powi(k);
    if k < 0 {
        format!("{v:.*}", (-k) as usize)
    } else {
        format!("{v:.0}")
    }
}

/// Draws `chart`; a point that is not finite and positive is an error, not a silent gap.
pub fn draw(chart: &Chart) -> Result<Canvas, String> {
    for s in &chart.series {
        if let Some(p) = s
            .points
            .iter()
            .find(|(x, y)| !(x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0))
        {
            return Err(format!(
                "series {}: point {p:?} cannot go on log axes",
                s.name
            ));
        }
    }
    let all = || chart.series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = decades(all().map(|p| p.0));
    let (y0, y1) = decades(all().map(|p| p.1));
    let (pw, ph) = (WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM);
    let px = |x: f64| LEFT as f64 + (x.log10() - x0 as f64) / (x1 - x0) as f64 * pw as f64;
    let py = |y: f64| (TOP + ph) as f64 - (y.log10() - y0 as f64) / (y1 - y0) as f64 * ph as f64;
    let mut c = Canvas::new(WIDTH, HEIGHT);
    let char_h = font::HEIGHT * SCALE;

    // Grid and ticks at every decade.
    for k in x0..=x1 {
        let x = px(10f64.powi(k)).round() as usize;
        c.fill(x, TOP, 1, ph, GRID);
        c.fill(x, TOP + ph, 1, 6, BLACK);
        c.text_centered(&decade_label(k), x, TOP + ph + 10);
    }
    for k in y0..=y1 {
        let y = py(10f64.powi(k)).round() as usize;
        c.fill(LEFT, y, pw, 1, GRID);
        c.fill(LEFT - 6, y, 6, 1, BLACK);
        let label = decade_label(k);
        c.text(
            &label,
            LEFT - 10 - font::text_width(&label, SCALE),
            y.saturating_sub(char_h / 2),
        );
    }
    c.fill(LEFT, TOP, 1, ph + 1, BLACK);
    c.fill(LEFT, TOP + ph, pw, 1, BLACK);
    c.text_centered(&chart.title, WIDTH / 2, 12);
    c.text_centered(&chart.x_label, LEFT + pw / 2, TOP + ph + 16 + char_h);
    c.text(&chart.y_label, 8, TOP - char_h - 12);

    for s in &chart.series {
        let pts: Vec<(f64, f64)> = s.points.iter().map(|&(x, y)| (px(x), py(y))).collect();
        for w in pts.windows(2) {
            c.line(w[0], w[1], s.colour);
        }
        for (i, &(x, y)) in pts.iter().enumerate() {
            let (x, y) = (x.round() as usize, y.round() as usize);
            c.fill(x.saturating_sub(3), y.saturating_sub(3), 7, 7, s.colour);
            if let Some(label) = s.labels.get(i).filter(|l| !l.is_empty()) {
                c.text(label, x + 6, y.saturating_sub(char_h + 2));
            }
        }
    }
    // Legend, top right, one line per series.
    let legend_w = chart
        .series
        .iter()
        .map(|s| font::text_width(&s.name, SCALE))
        .max()
        .unwrap_or(0)
        + 26;
    let lx = WIDTH - RIGHT - legend_w - 10;
    for (i, s) in chart.series.iter().enumerate() {
        let y = TOP + 10 + i * (char_h + 8);
        c.fill(lx, y + 2, 14, char_h - 4, s.colour);
        c.text(&s.name, lx + 22, y);
    }
    Ok(c)
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
        // x decades 0..2 and y decades -2..0: the two points sit at opposite plot corners.
        let (pw, ph) = (WIDTH - LEFT - RIGHT, HEIGHT - TOP - BOTTOM);
        assert_eq!(c.pixel(LEFT + 1, TOP + ph - 1), PALETTE[0]);
        assert_eq!(c.pixel(LEFT + pw - 1, TOP + 1), PALETTE[0]);
        // The line between them passes through the middle.
        let mid = (LEFT + pw / 2, TOP + ph / 2);
        let near = (0..5).any(|d| c.pixel(mid.0, mid.1 + d - 2) == PALETTE[0]);
        assert!(near);
        assert!(draw(&chart(vec![(1.0, 0.0)])).is_err());
        assert!(draw(&chart(vec![(f64::NAN, 1.0)])).is_err());
    }
}
