//! Where the render surface creases beyond the rig, by the bindings of the creased edges'
//! vertices: each single shape at weight 1 on the neutral, final preset, contact on and the
//! deep lining's pass, as `facesim bench shapes` poses it
//! ([`facesim::model::creases`]). For each creased edge, the kinds of binding of the four
//! vertices of its two triangles (embedded, blended, rigid, between the bones) and whether
//! the embedded ones share one element, and those elements' volumes (against the median
//! element's) and shape quality (the mean ratio of `geometry::shell::shape_quality`: 1
//! regular, 0 flat).
//!
//! With `--rebind`, the neutral's render bindings are first chosen again by today's importer
//! (the tissue must be the sample's), to measure a change of the bindings without rebuilding
//! the sample.
//!
//! `cargo run --release -p facesim --example crease_bindings -- [--rebind] [SHAPE…]`
use std::collections::BTreeMap;

use anyhow::{Context, Result};
use facesim::contact::surface::FaceContact;
use facesim::drive::Codes;
use facesim::geometry::shell::shape_quality;
use facesim::model::Binding;
use facesim::model::contact_region::FaceContactSettings;
use facesim::model::deep_lining::{DeepLining, LiningMemory};
use facesim::sim::Quality;
use facesim::stats::median;

fn main() -> Result<()> {
    let mut only: Vec<String> = std::env::args().skip(1).collect();
    let rebind = only.iter().any(|a| a == "--rebind");
    only.retain(|a| a != "--rebind");
    let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)?;
    let face = sample
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .context("neutral")?;
    let rig = facesim::rig::FaceRig::load(facesim::rig::DEFAULT_RIG_DIR)?;
    let mut model = face.model.clone();
    if rebind {
        let built =
            facesim::model::build_face(&rig, None, &facesim::model::Lod::Coarse.settings())?;
        anyhow::ensure!(
            built.mesh == model.mesh,
            "the rebuilt tissue is not the sample's"
        );
        let changed = (built.render.bindings.iter())
            .zip(&model.render.bindings)
            .filter(|(a, b)| a != b)
            .count();
        println!(
            "rebound {changed} of {} render vertices",
            model.render.bindings.len()
        );
        model.render = built.render;
    }
    let model = &model;
    let mut sim = model.simulator()?;
    let surfaces = FaceContact::new(model, &FaceContactSettings::default())?;
    let pass = DeepLining::new(model, &surfaces)?;
    sim.set_contact(surfaces)?;
    let settings = Quality::Final.settings();
    let audit = facesim::model::creases::CreaseAudit::new(model);
    let kind = |v: u32| match &model.render.bindings[v as usize] {
        Binding::Embedded { .. } => "E",
        Binding::Blended { .. } => "B",
        Binding::Rigid(_) => "R",
        Binding::Bones { .. } => "J",
    };
    let element = |v: u32| model.render.bindings[v as usize].element();
    // Element volumes relative to the median element's, and shape quality (the mesh report's
    // mean ratio).
    let volumes: Vec<f64> = (0..model.mesh.tets.len())
        .map(|e| model.mesh.signed_volume(e))
        .collect();
    let median_volume = median(&volumes);
    let relative_volume = |e: u32| volumes[e as usize] / median_volume;
    let quality = |e: u32| {
        let p = model.mesh.tets[e as usize].map(|v| model.mesh.vertices[v as usize]);
        shape_quality(&p, volumes[e as usize])
    };
    let embedded: Vec<u32> = model
        .render
        .bindings
        .iter()
        .filter_map(|b| b.element())
        .collect();
    println!(
        "embedded render vertices' elements: median volume {:.2} of the median element's, \
         median quality {:.2}",
        median(
            &embedded
                .iter()
                .map(|&e| relative_volume(e))
                .collect::<Vec<_>>()
        ),
        median(&embedded.iter().map(|&e| quality(e)).collect::<Vec<_>>()),
    );
    for (name, expression) in facesim::bench::shapes::single_shapes() {
        if !only.is_empty() && !only.contains(&name) {
            continue;
        }
        let code = Codes {
            expression,
            ..Default::default()
        };
        let a = face.actuation.actuate(&code)?;
        let mut state = sim.rest_state();
        sim.solve(&a.tensors, &a.bones(), &mut state, &settings)?;
        let mut posed = model.render_positions(state.flat_positions(), &a.bones());
        pass.apply(&mut posed, &mut LiningMemory::default());
        let goal = facesim::model::target(&rig, model, &code)?.render;
        let creased = audit.creased(&posed);
        let mut kinds: BTreeMap<String, usize> = BTreeMap::new();
        let mut err = Vec::new();
        let mut creased_volumes = Vec::new();
        let mut creased_quality = Vec::new();
        for f in &creased {
            let ([a, b], [t1, t2]) = (f.edge, f.triangles);
            let mut vs: Vec<u32> = model.render.triangles[t1]
                .iter()
                .chain(&model.render.triangles[t2])
                .copied()
                .collect();
            vs.sort_unstable();
            vs.dedup();
            let mut k: Vec<&str> = vs.iter().map(|&v| kind(v)).collect();
            k.sort_unstable();
            k.dedup();
            let mut elements: Vec<_> = vs.iter().filter_map(|&v| element(v)).collect();
            elements.sort_unstable();
            elements.dedup();
            creased_volumes.extend(elements.iter().map(|&e| relative_volume(e)));
            creased_quality.extend(elements.iter().map(|&e| quality(e)));
            let key = format!("{} in {} elements", k.join(""), elements.len());
            *kinds.entry(key).or_default() += 1;
            for v in [a, b] {
                err.push(10.0 * (posed[v as usize] - goal[v as usize]).norm());
            }
        }
        println!(
            "{name}: {} creased edges (rig {}), their vertices' median error {:.2} mm, \
             their elements' median volume {:.2} of the median element's and quality {:.2}; \
             {kinds:?}",
            creased.len(),
            audit.creased(&goal).len(),
            median(&err),
            median(&creased_volumes),
            median(&creased_quality),
        );
    }
    Ok(())
}
