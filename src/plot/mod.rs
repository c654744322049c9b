//! Pictures without a plotting crate: an RGB [`Canvas`] with filled boxes, lines and text in
//! the built-in bitmap font, written as PNG; the figures (mapping heatmaps, trade-off charts)
//! draw on it.

pub mod font;
pub mod scatter;

use std::path::{Path, PathBuf};

/// Why a picture could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing a PNG: {0}")]
    Png(String),
}

/// Text scale: each font pixel is SCALE × SCALE.
pub const SCALE: usize = 2;
pub const WHITE: [u8; 3] = [255, 255, 255];
pub const BLACK: [u8; 3] = [0, 0, 0];

/// An RGB picture.
#[derive(Clone, Debug, PartialEq)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
}

impl Canvas {
    pub fn new(width: usize, height: usize) -> Self {
        Canvas {
            width,
            height,
            pixels: vec![255; width * height * 3],
        }
    }

    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]]
    }

    pub fn set(&mut self, x: usize, y: usize, c: [u8; 3]) {
        if x < self.width && y < self.height {
            let i = 3 * (y * self.width + x);
            self.pixels[i..i + 3].copy_from_slice(&c);
        }
    }

    pub fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, c: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.set(xx, yy, c);
            }
        }
    }

    pub fn text(&mut self, s: &str, x: usize, y: usize) {
        let mut lit = Vec::new();
        font::draw(s, x, y, SCALE, |px, py| lit.push((px, py)));
        for (px, py) in lit {
            self.set(px, py, BLACK);
        }
    }

    pub fn text_centered(&mut self, s: &str, cx: usize, y: usize) {
        let w = font::text_width(s, SCALE);
        self.text(s, cx.saturating_sub(w / 2), y);
    }

    /// A 2-pixel-wide straight line between two points (in pixels; off-canvas parts clipped).
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), c: [u8; 3]) {
        let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().max(1.0) as usize;
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
            if x >= 0.0 && y >= 0.0 {
                self.fill(x.round() as usize, y.round() as usize, 2, 2, c);
            }
        }
    }

    /// Writes the picture as an 8-bit RGB PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), PlotError> {
        let io = |e: std::io::Error| PlotError::Io {
            path: path.to_path_buf(),
            source: e,
        };
        let file = std::fs::File::create(path).map_err(io)?;
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            self.width as u32,
            self.height as u32,
        );
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let png_err = |e: png::EncodingError| PlotError::Png(e.to_string());
        let mut w = enc.write_header().map_err(png_err)?;
        w.write_image_data(&self.pixels).map_err(png_err)?;
        w.finish().map_err(png_err)
    }
}

/// Viridis at t ∈ [0, 1] (piecewise linear through 5 of its colours).
pub fn viridis(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [68.0, 1.0, 84.0],
        [59.0, 82.0, 139.0],
        [33.0, 145.0, 140.0],
        [94.0, 201.0, 98.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f64;
    [0, 1, 2].map(|k| (STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f).round() as u8)
}
