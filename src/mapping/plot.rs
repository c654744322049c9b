//! Heatmap pictures in the style of the paper's Fig. 3: one panel per measurement, a row per
//! identity, a column per bin, colour = share of the sampled points in the bin (viridis,
//! scaled to the panel's largest share, with a colour bar), axis ticks and titles drawn with
//! plotters in the built-in font, written as PNG.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::plot::{Canvas, FONT, PlotError, draw_error, rgb, viridis};

const CELL_W: usize = 7;
const CELL_H: usize = 28;
const PAD: usize = 16;
const BAR_W: usize = 14;
/// Text sizes (pixels): titles, row names and ticks.
const TITLE: u32 = 19;
const TEXT: u32 = 16;
/// Room for a row name or a colour-bar label, per character (DejaVu Sans at [`TEXT`] is
/// narrower than this on average).
const CHAR_W: usize = 10;

/// One panel: its title, the x range and the shares (rows × bins).
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    pub title: String,
    pub lo: f64,
    pub hi: f64,
    pub shares: Vec<Vec<f64>>,
}

fn tick(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Where the figure's parts go (pixels, origin top left).
struct Layout {
    label_w: usize,
    panel_w: usize,
    top: usize,
    grid_h: usize,
    bar_h: usize,
    width: usize,
    height: usize,
}

impl Layout {
    fn new(rows: &[String], panels: &[Panel]) -> Self {
        let label_w = rows.iter().map(|r| r.chars().count()).max().unwrap_or(0) * CHAR_W + PAD;
        let bins_max = panels
            .iter()
            .map(|p| p.shares.first().map_or(0, |r| r.len()))
            .max()
            .unwrap_or(0);
        let legend_w = BAR_W + 6 + 6 * CHAR_W;
        let panel_w = bins_max * CELL_W + PAD + legend_w + 2 * PAD;
        let grid_h = rows.len() * CELL_H;
        // The colour bar is at least tall enough for its two labels.
        let bar_h = grid_h.max(3 * TEXT as usize);
        let top = PAD + TITLE as usize + PAD;
        Layout {
            label_w,
            panel_w,
            top,
            grid_h,
            bar_h,
            width: PAD + label_w + panels.len() * panel_w,
            height: top + grid_h.max(bar_h) + 12 + TEXT as usize + 2 * PAD,
        }
    }

    /// The left edge of panel `p`'s grid.
    fn x0(&self, p: usize) -> usize {
        PAD + self.label_w + p * self.panel_w
    }

    /// The top-left pixel of the cell of `row`, `bin` in panel `p`.
    fn cell(&self, p: usize, row: usize, bin: usize) -> (usize, usize) {
        (self.x0(p) + bin * CELL_W, self.top + row * CELL_H)
    }
}

fn filled(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    (x, y): (usize, usize),
    (w, h): (usize, usize),
    colour: [u8; 3],
) -> Result<(), PlotError> {
    let (x, y) = (x as i32, y as i32);
    area.draw(&Rectangle::new(
        [(x, y), (x + w as i32, y + h as i32)],
        rgb(colour).filled(),
    ))
    .map_err(draw_error)
}

fn text(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    s: &str,
    (x, y): (usize, usize),
    size: u32,
    h: HPos,
) -> Result<(), PlotError> {
    let style = TextStyle::from((FONT, size)).pos(Pos::new(h, VPos::Top));
    area.draw(&Text::new(s.to_string(), (x as i32, y as i32), style))
        .map_err(draw_error)
}

/// Panels side by side with shared row labels; values outside a panel's range are counted in
/// its end bins (the tick labels say so with < and >).
pub fn heatmap_figure(rows: &[String], panels: &[Panel]) -> Result<Canvas, PlotError> {
    let l = Layout::new(rows, panels);
    Canvas::draw(l.width, l.height, |area| {
        for (r, name) in rows.iter().enumerate() {
            let y = l.top + r * CELL_H + (CELL_H - TEXT as usize) / 2;
            text(area, name, (PAD, y), TEXT, HPos::Left)?;
        }
        for (p, panel) in panels.iter().enumerate() {
            let x0 = l.x0(p);
            let bins = panel.shares.first().map_or(0, |r| r.len());
            let max = panel
                .shares
                .iter()
                .flatten()
                .copied()
                .fold(0.0_f64, f64::max)
                .max(1e-12);
            text(
                area,
                &panel.title,
                (x0 + bins * CELL_W / 2, PAD),
                TITLE,
                HPos::Center,
            )?;
            for (r, shares) in panel.shares.iter().enumerate() {
                for (b, s) in shares.iter().enumerate() {
                    filled(
                        area,
                        l.cell(p, r, b),
                        (CELL_W, CELL_H - 2),
                        viridis(s / max),
                    )?;
                }
            }
            // x axis: ticks at both ends and the middle.
            let axis_y = l.top + l.grid_h;
            filled(area, (x0, axis_y), (bins * CELL_W, 1), [0, 0, 0])?;
            for (f, label, h) in [
                (0.0, format!("<{}", tick(panel.lo)), HPos::Left),
                (0.5, tick(0.5 * (panel.lo + panel.hi)), HPos::Center),
                (1.0, format!(">{}", tick(panel.hi)), HPos::Right),
            ] {
                let x = x0 + (f * (bins * CELL_W) as f64).round() as usize;
                filled(
                    area,
                    (x.min(x0 + bins * CELL_W - 1), axis_y),
                    (1, 6),
                    [0, 0, 0],
                )?;
                text(area, &label, (x, axis_y + 9), TEXT, h)?;
            }
            // Colour bar: 0 % at the bottom, the panel's largest share at the top.
            let bx = x0 + bins * CELL_W + PAD;
            for y in 0..l.bar_h {
                let t = 1.0 - y as f64 / (l.bar_h.max(2) - 1) as f64;
                filled(area, (bx, l.top + y), (BAR_W, 1), viridis(t))?;
            }
            let lx = bx + BAR_W + 6;
            text(
                area,
                &format!("{:.1}%", 100.0 * max),
                (lx, l.top),
                TEXT,
                HPos::Left,
            )?;
            let bottom = l.top + l.bar_h - TEXT as usize;
            text(area, "0%", (lx, bottom), TEXT, HPos::Left)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_figure_colours_each_cell_by_its_share_and_round_trips_through_png() {
        let rows = vec!["A".to_string(), "B".to_string()];
        let panels = vec![Panel {
            title: "DET".into(),
            lo: 0.5,
            hi: 1.5,
            shares: vec![vec![0.0, 1.0, 0.0], vec![0.5, 0.0, 0.5]],
        }];
        let c = heatmap_figure(&rows, &panels).unwrap();
        let layout = Layout::new(&rows, &panels);
        let cell = |r: usize, b: usize| {
            let (x, y) = layout.cell(0, r, b);
            c.pixel(x + 1, y + 1)
        };
        assert_eq!(cell(0, 1), viridis(1.0));
        assert_eq!(cell(0, 0), viridis(0.0));
        assert_eq!(cell(1, 0), viridis(0.5));
        let dir = crate::rig::test_support::temp_dir("plot");
        let path = dir.join("h.png");
        c.write_png(&path).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(
            (info.width as usize, info.height as usize),
            (c.width, c.height)
        );
        assert_eq!(&buf[..info.buffer_size()], &c.pixels[..]);
    }
}
