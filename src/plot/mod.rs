//! Pictures: an RGB [`Canvas`] that plotters draws on (its bitmap backend over our buffer,
//! text in a built-in font), written as PNG by the `png` crate; the figures (mapping heatmaps,
//! trade-off charts) are drawn with it.

pub mod scatter;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::{BitMapBackend, DrawingArea, IntoDrawingArea};

/// Why a picture could not be drawn or written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("writing a PNG: {0}")]
    Png(String),
    #[error("drawing: {0}")]
    Draw(String),
}

/// The font family every figure's text uses: a subset of DejaVu Sans (`fonts/`, with its
/// licence) built into the binary, so pictures need no system fonts.
pub const FONT: &str = "sans-serif";

/// Registers [`FONT`] with plotters once.
fn register_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(
            FONT,
            plotters::style::FontStyle::Normal,
            include_bytes!("fonts/DejaVuSans-subset.ttf"),
        )
        .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError::Draw("the built-in font does not load".into()))
    }
}

/// A drawing error of plotters, as ours.
pub(crate) fn draw_error(e: impl std::fmt::Display) -> PlotError {
    PlotError::Draw(e.to_string())
}

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
    /// A white picture drawn by `draw` on a plotters drawing area of its size (pixels, origin
    /// top left).
    pub fn draw(
        width: usize,
        height: usize,
        draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), PlotError>,
    ) -> Result<Canvas, PlotError> {
        register_font()?;
        let mut pixels = vec![255; width * height * 3];
        {
            let area = BitMapBackend::with_buffer(&mut pixels, (width as u32, height as u32))
                .into_drawing_area();
            draw(&area)?;
            area.present().map_err(draw_error)?;
        }
        Ok(Canvas {
            width,
            height,
            pixels,
        })
    }

    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.pixels[i], self.pixels[i + 1], self.pixels[i + 2]]
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

/// `c` as a plotters colour.
pub fn rgb(c: [u8; 3]) -> plotters::style::RGBColor {
    plotters::style::RGBColor(c[0], c[1], c[2])
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
