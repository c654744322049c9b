//! The expression/style networks' inference on the sample's faces (`facesim bench nets`):
//! N_A over every element with the first layer's code part cached and without, and the whole
//! codes → actuation step.

use std::sync::Arc;
use std::time::Instant;

use crate::drive::{ActuationModel, Codes};
use crate::generative::generative_face::FaceWarp;
use crate::generative::{GenerativeError, GenerativeFace, GenerativeNets};
use crate::nn::{CodeBatch, Mlp, Pass, Tape};
use crate::rig::ExpressionCode;
use crate::sample::Sample;
use crate::stats::median;
use crate::table::Table;

/// One face's timings (median ms over the samples).
pub struct NetsRow {
    pub face: String,
    pub elements: usize,
    pub cached_ms: f64,
    pub uncached_ms: f64,
    pub actuate_ms: f64,
}

/// Times `nets` on every face of `sample`, `samples` times each, on a jawOpen 0.6 code.
pub fn bench(
    sample: &Sample,
    nets: Arc<GenerativeNets>,
    samples: usize,
) -> Result<Vec<NetsRow>, GenerativeError> {
    let codes = Codes {
        expression: ExpressionCode::single("jawOpen", 0.6).expect("a code shape"),
        style: Default::default(),
    };
    let mut rows = Vec::new();
    for f in &sample.faces {
        let g = GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref())?;
        let u = nets.modulation(std::slice::from_ref(&codes))?;
        let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
        let u32: Vec<f32> = u.iter().map(|&v| v as f32).collect();
        let mut tape = Tape::new();
        let na32: Mlp<f32> = nets.actuation.cast();
        let warp = FaceWarp::new(&f.model, f.mapping.as_ref(), &nets.frame)?;
        let x = warp.input::<f32>();
        let (mut cached, mut full, mut actuate) = (Vec::new(), Vec::new(), Vec::new());
        let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
        for _ in 0..samples {
            let t = Instant::now();
            g.canonical_logs(&u, &mut tape)?;
            cached.push(ms(t));
            let t = Instant::now();
            na32.forward(
                x.as_ref(),
                Some(&CodeBatch::shared(&u32)),
                Pass::Value,
                &mut tape,
                faer::Par::Seq,
            )?;
            full.push(ms(t));
            let t = Instant::now();
            std::hint::black_box(g.actuate(&codes)?);
            actuate.push(ms(t));
        }
        rows.push(NetsRow {
            face: f.name.clone(),
            elements: g.element_count(),
            cached_ms: median(&cached),
            uncached_ms: median(&full),
            actuate_ms: median(&actuate),
        });
    }
    Ok(rows)
}

/// The rows as a Markdown table.
pub fn table(rows: &[NetsRow]) -> String {
    let mut table = Table::new(
        &[
            "face",
            "elements",
            "N_A, cached first layer (median ms)",
            "N_A, no cache (median ms)",
            "actuate: codes → tensors + jaw (median ms)",
        ],
        "lrrrr",
    );
    for r in rows {
        table.row([
            r.face.clone(),
            r.elements.to_string(),
            format!("{:.2}", r.cached_ms),
            format!("{:.2}", r.uncached_ms),
            format!("{:.2}", r.actuate_ms),
        ]);
    }
    table.to_string()
}
