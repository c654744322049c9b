//! Heatmap pictures in the style of the paper's Fig. 3: one panel per measurement, a row per
//! identity, a column per bin, colour = share of the sampled points in the bin (viridis,
//! scaled to the panel's largest share, with a colour bar), axis ticks and titles drawn with
//! the built-in bitmap font, written as PNG.

use crate::plot::{BLACK, Canvas, SCALE, WHITE, font, viridis};

const CELL_W: usize = 7;
const CELL_H: usize = 26;
const PAD: usize = 14;
const BAR_W: usize = 14;

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

/// Panels side by side with shared row labels; values outside a panel's range are counted in
/// its end bins (the tick labels say so with < and >).
pub fn heatmap_figure(rows: &[String], panels: &[Panel]) -> Canvas {
    let char_h = font::HEIGHT * SCALE;
    let label_w = rows
        .iter()
        .map(|r| font::text_width(r, SCALE))
        .max()
        .unwrap_or(0)
        + PAD;
    let bins_max = panels
        .iter()
        .map(|p| p.shares.first().map_or(0, |r| r.len()))
        .max()
        .unwrap_or(0);
    let grid_w = bins_max * CELL_W;
    let legend_w = BAR_W + 6 + font::text_width("100.0%", SCALE);
    let panel_w = grid_w + PAD + legend_w + 2 * PAD;
    let grid_h = rows.len() * CELL_H;
    // The colour bar is at least tall enough for its two labels.
    let bar_h = grid_h.max(3 * char_h);
    let top = PAD + char_h + PAD;
    let height = top + grid_h.max(bar_h - 2 * char_h) + 8 + 2 * char_h + 2 * PAD;
    let width = PAD + label_w + panels.len() * panel_w;
    let mut c = Canvas::new(width, height);
    for (r, name) in rows.iter().enumerate() {
        let y = top + r * CELL_H + (CELL_H - char_h) / 2;
        c.text(name, PAD, y);
    }
    for (p, panel) in panels.iter().enumerate() {
        let x0 = PAD + label_w + p * panel_w;
        let bins = panel.shares.first().map_or(0, |r| r.len());
        let max = panel
            .shares
            .iter()
            .flatten()
            .copied()
            .fold(0.0_f64, f64::max)
            .max(1e-12);
        c.text_centered(&panel.title, x0 + bins * CELL_W / 2, PAD);
        for (r, shares) in panel.shares.iter().enumerate() {
            for (b, s) in shares.iter().enumerate() {
                let colour = viridis(s / max);
                c.fill(
                    x0 + b * CELL_W,
                    top + r * CELL_H,
                    CELL_W,
                    CELL_H - 2,
                    colour,
                );
            }
        }
        // x axis: ticks at both ends and the middle.
        let axis_y = top + grid_h;
        c.fill(x0, axis_y, bins * CELL_W, 1, BLACK);
        for (f, label) in [
            (0.0, format!("<{}", tick(panel.lo))),
            (0.5, tick(0.5 * (panel.lo + panel.hi))),
            (1.0, format!(">{}", tick(panel.hi))),
        ] {
            let x = x0 + (f * (bins * CELL_W) as f64).round() as usize;
            c.fill(x.min(x0 + bins * CELL_W - 1), axis_y, 1, 6, BLACK);
            let w = font::text_width(&label, SCALE);
            let lx = if f == 0.0 {
                x
            } else if f == 1.0 {
                x.saturating_sub(w)
            } else {
                x.saturating_sub(w / 2)
            };
            c.text(&label, lx, axis_y + 8);
        }
        // Colour bar: 0 % at the bottom, the panel's largest share at the top.
        let bx = x0 + bins * CELL_W + PAD;
        for y in 0..bar_h {
            let t = 1.0 - y as f64 / (bar_h.max(2) - 1) as f64;
            c.fill(bx, top + y, BAR_W, 1, viridis(t));
        }
        c.text(&format!("{:.1}%", 100.0 * max), bx + BAR_W + 6, top);
        c.text("0%", bx + BAR_W + 6, top + bar_h - char_h);
    }
    c.fill(0, height - 1, width, 1, WHITE);
    c
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
        let c = heatmap_figure(&rows, &panels);
        let label_w = font::text_width("A", SCALE) + PAD;
        let top = PAD + font::HEIGHT * SCALE + PAD;
        let cell =
            |r: usize, b: usize| c.pixel(PAD + label_w + b * CELL_W + 1, top + r * CELL_H + 1);
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
