//! How the skin outside the simulated tissue moves (README, "The bundled sample"): for every
//! face of a sample, how many skin render vertices lie how far outside the tissue, and how far
//! they move when the face performs single shapes (the sample's actuation basis, final preset,
//! no contact) compared with the bones under them and the rig's own target.
//!
//! ```sh
//! cargo run --release -p facesim --example skin_beyond_tissue [-- SAMPLE_DIR [RIG_DIR]]
//! ```
//!
//! With the rig (default `../shared/data/ict-facekit`, skipped if missing) it also shows how
//! far the rig itself moves those vertices for the same codes.
//!
//! The skull never moves in these frames, so skin riding on it should stay at rest: what such a
//! vertex moves is what it "wobbles" by. Each frame is shown twice: with the face's bindings
//! ("now") and with every skin vertex embedded in its nearest element, as face format
//! version 1 bound it (same elements and weights).

use anyhow::{Context, Result};
use facesim::drive::Codes;
use facesim::geometry::embedding::{Embedding, interpolate};
use facesim::model::Binding;
use facesim::rig::{ExpressionCode, Region};
use facesim::sample::{SAMPLE_DIR, Sample};
use facesim::sim::Quality;
use nalgebra::Point3;

const MM: f64 = 10.0;

/// Bins of the distance outside the tissue, cm (upper bounds).
const BINS: [f64; 10] = [0.0, 0.3, 0.5, 0.7, 0.85, 1.0, 1.25, 1.5, 2.0, f64::INFINITY];
const SHAPES: [&str; 4] = ["jawOpen", "mouthSmile_L", "mouthPucker", "jawLeft"];

fn main() -> Result<()> {
    let dir = std::env::args().nth(1).unwrap_or_else(|| SAMPLE_DIR.into());
    let sample = Sample::load(&dir).with_context(|| format!("loading {dir}"))?;
    let rig_dir = std::env::args()
        .nth(2)
        .unwrap_or_else(|| "../shared/data/ict-facekit".into());
    let rig = std::path::Path::new(&rig_dir)
        .exists()
        .then(|| facesim::rig::FaceRig::load(&rig_dir))
        .transpose()
        .with_context(|| format!("loading the rig in {rig_dir}"))?;
    let mut settings = Quality::Final.settings();
    settings.contact = false;
    let bins = BINS[1..]
        .iter()
        .map(|b| format!("≤{b}"))
        .collect::<Vec<_>>()
        .join(" / ")
        .replace("≤inf", &format!(">{}", BINS[BINS.len() - 2]));
    println!(
        "| face | skin vertices by distance outside the tissue (cm): 0 / {bins} | max distance (cm) | bound: embedded / blended / on the skull / rigid |"
    );
    println!("|---|---|---:|---|");
    let mut motion_rows = Vec::new();
    let mut rig_rows = Vec::new();
    for face in &sample.faces {
        let model = &face.model;
        let render = &model.render;
        let embedding = Embedding::new(&model.mesh, &render.rest);
        let skin: Vec<usize> = (0..render.rest.len())
            .filter(|&i| {
                Region::of_vertex(render.rig_vertices[i] as usize) == Some(Region::FaceSkin)
            })
            .collect();
        let mut counts = [0usize; BINS.len()];
        for &i in &skin {
            let d = embedding.outside_distance[i];
            let bin = BINS.iter().position(|&b| d <= b).unwrap_or(BINS.len() - 1);
            counts[bin] += 1;
        }
        let max = skin
            .iter()
            .map(|&i| embedding.outside_distance[i])
            .fold(0.0, f64::max);
        let kinds = skin.iter().fold([0usize; 4], |mut k, &i| {
            k[match render.bindings[i] {
                Binding::Embedded { .. } => 0,
                Binding::Blended { embedded, .. } if embedded > 0.0 => 1,
                Binding::Blended { .. } => 2,
                Binding::Rigid(_) | Binding::Bones { .. } => 3,
            }] += 1;
            k
        });
        println!(
            "| {} | {} | {max:.2} | {} |",
            face.name,
            counts.map(|c| c.to_string()).join(" / "),
            kinds.map(|c| c.to_string()).join(" / "),
        );
        // How much the rig moves the skin in each distance bin (any of the 19 shapes at 1).
        if let Some(rig) = &rig {
            let mut most = vec![0.0f64; render.rest.len()];
            for name in ExpressionCode::NAMES {
                let codes = Codes {
                    expression: ExpressionCode::single(name, 1.0).context("shape")?,
                    ..Codes::default()
                };
                let t = facesim::model::target(rig, model, &codes)?;
                for &i in &skin {
                    most[i] = most[i].max((t.render[i] - render.rest[i]).norm());
                }
            }
            let mut cells = Vec::new();
            for (b, upper) in BINS.iter().enumerate() {
                let lower = if b == 0 { -1.0 } else { BINS[b - 1] };
                let mut m: Vec<f64> = skin
                    .iter()
                    .filter(|&&i| {
                        let d = embedding.outside_distance[i];
                        d > lower && d <= *upper
                    })
                    .map(|&i| 10.0 * most[i])
                    .collect();
                m.sort_by(f64::total_cmp);
                cells.push(match m.len() {
                    0 => "–".to_string(),
                    n => format!("{:.2} / {:.2}", m[n * 9 / 10], m[n - 1]),
                });
            }
            rig_rows.push(format!("| {} | {} |", face.name, cells.join(" | ")));
        }
        // Skin on the skull (s = 0) and in the blend band (0 < s < 1), and the render edges
        // that touch either: where a seam would show.
        let group = |on_bone: bool| -> Vec<usize> {
            (0..render.rest.len())
                .filter(|&i| match render.bindings[i] {
                    Binding::Blended { embedded, .. } => (embedded == 0.0) == on_bone,
                    _ => false,
                })
                .collect()
        };
        let (far, band) = (group(true), group(false));
        let blended = |i: u32| matches!(render.bindings[i as usize], Binding::Blended { .. });
        let mut edges: Vec<[u32; 2]> = render
            .triangles
            .iter()
            .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
            .filter(|e| blended(e[0]) || blended(e[1]))
            .map(|e| [e[0].min(e[1]), e[0].max(e[1])])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let sim = model.simulator()?;
        for shape in SHAPES {
            let codes = Codes {
                expression: ExpressionCode::single(shape, 1.0).context("shape")?,
                style: face.style,
            };
            let a = face.actuation.actuate(&codes)?;
            let mut state = sim.rest_state();
            if let Err(e) = sim.solve(&a.tensors, &a.bones(), &mut state, &settings) {
                motion_rows.push(format!(
                    "| {} | {shape} | failed: {e} | | | | | |",
                    face.name
                ));
                continue;
            }
            let x = state.flat_positions();
            let now = model.render_positions(x, &a.bones());
            // Version 1 bound every skin vertex to its nearest element (these weights).
            let v1: Vec<Point3<f64>> = (0..render.rest.len())
                .map(|i| match render.bindings[i] {
                    Binding::Blended { .. } => interpolate(
                        &model.mesh.tets[embedding.elements[i] as usize],
                        &embedding.weights[i],
                        x,
                    ),
                    _ => now[i],
                })
                .collect();
            let target = rig
                .as_ref()
                .map(|rig| facesim::model::target(rig, model, &codes))
                .transpose()?;
            let worst = |p: &[Point3<f64>], set: &[usize]| {
                set.iter()
                    .map(|&i| MM * (p[i] - render.rest[i]).norm())
                    .fold(0.0, f64::max)
            };
            let stretch = |p: &[Point3<f64>]| {
                edges
                    .iter()
                    .map(|&[u, v]| {
                        let (u, v) = (u as usize, v as usize);
                        MM * ((p[u] - p[v]).norm() - (render.rest[u] - render.rest[v]).norm()).abs()
                    })
                    .fold(0.0, f64::max)
            };
            // How far the tissue moved under the far skin (its elements' corners).
            let tissue = far
                .iter()
                .flat_map(|&i| model.mesh.tets[embedding.elements[i] as usize])
                .map(|v| {
                    let v = v as usize;
                    let p = Point3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2]);
                    MM * (p - model.mesh.vertices[v]).norm()
                })
                .fold(0.0, f64::max);
            let rig_cells = target.map_or("– | –".to_string(), |t| {
                let all: Vec<usize> = far.iter().chain(&band).copied().collect();
                format!("{:.3} | {:.3}", worst(&t.render, &all), stretch(&t.render))
            });
            motion_rows.push(format!(
                "| {} | {shape} | {} / {} | {:.3} → {:.3} | {:.3} → {:.3} | {:.3} → {:.3} | {tissue:.3} | {rig_cells} |",
                face.name,
                far.len(),
                band.len(),
                worst(&v1, &far),
                worst(&now, &far),
                worst(&v1, &band),
                worst(&now, &band),
                stretch(&v1),
                stretch(&now),
            ));
        }
    }
    println!();
    println!(
        "| face | rig motion (mm, largest over the 19 shapes at 1; 90th pct / max) of skin at 0 | {} cm |",
        bins.replace(" / ", " | ")
    );
    println!("|---|{}", "---|".repeat(BINS.len()));
    for r in rig_rows {
        println!("{r}");
    }
    println!();
    println!(
        "| face | shape at 1 | skin on the skull / blended | on the skull: max motion, version 1 → now (mm) | blended: max motion, version 1 → now (mm) | edges touching them: max length change, version 1 → now (mm) | tissue under the skin on the skull: max motion (mm) | the rig: max motion of those vertices / edge change (mm) |"
    );
    println!("|---|---|---|---|---|---|---:|---|");
    for r in motion_rows {
        println!("{r}");
    }
    Ok(())
}
