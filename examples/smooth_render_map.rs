//! Experiment (kept in history only; see docs/performance/fidelity.md, "Creases"): the render
//! surface through a smooth map of the tissue (each sim vertex's mean deformation gradient,
//! blended by clamped barycentric weights) against the bindings' barycentric map: creases and
//! errors against the rig, the tissue boundary's own creases, neutral, final, contact on.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p facesim --example smooth_render_map -- jawOpen mouthClose mouthSmile_L mouthRollUpper`
use anyhow::{Context, Result};
use facesim::contact::surface::FaceContact;
use facesim::drive::Codes;
use facesim::model::Binding;
use facesim::model::contact_region::FaceContactSettings;
use facesim::model::deep_lining::{DeepLining, LiningMemory};
use facesim::rig::Region;
use facesim::sim::Quality;
use nalgebra::{Matrix3, Point3, Vector3};

fn main() -> Result<()> {
    let only: Vec<String> = std::env::args().skip(1).collect();
    let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)?;
    let face = sample
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .context("neutral")?;
    let rig = facesim::rig::FaceRig::load(facesim::rig::DEFAULT_RIG_DIR)?;
    let model = &face.model;
    let mut sim = model.simulator()?;
    let surfaces = FaceContact::new(model, &FaceContactSettings::default())?;
    let pass = DeepLining::new(model, &surfaces)?;
    sim.set_contact(surfaces)?;
    let settings = Quality::Final.settings();
    let audit = facesim::model::creases::CreaseAudit::new(model);
    let mesh = &model.mesh;
    let rest_x: Vec<f64> = mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let region: Vec<Option<Region>> = model
        .render
        .rig_vertices
        .iter()
        .map(|&v| Region::of_vertex(v as usize))
        .collect();
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
        let x = state.flat_positions();
        let goal = facesim::model::target(&rig, model, &code)?.render;
        // Per sim vertex: volume-weighted mean deformation gradient of its elements.
        let p = |xs: &[f64], v: u32| {
            Point3::new(
                xs[3 * v as usize],
                xs[3 * v as usize + 1],
                xs[3 * v as usize + 2],
            )
        };
        let mut fbar = vec![Matrix3::zeros(); mesh.vertices.len()];
        let mut vol = vec![0.0; mesh.vertices.len()];
        for t in &mesh.tets {
            let [a0, a1, a2, a3] = t.map(|v| p(&rest_x, v));
            let [b0, b1, b2, b3] = t.map(|v| p(x, v));
            let dm = Matrix3::from_columns(&[a1 - a0, a2 - a0, a3 - a0]);
            let ds = Matrix3::from_columns(&[b1 - b0, b2 - b0, b3 - b0]);
            let f = ds * dm.try_inverse().unwrap();
            let v = dm.determinant().abs() / 6.0;
            for &i in t {
                fbar[i as usize] += f * v;
                vol[i as usize] += v;
            }
        }
        for (f, v) in fbar.iter_mut().zip(&vol) {
            if *v > 0.0 {
                *f /= *v;
            }
        }
        let smooth_at = |element: u32, weights: &[f64; 4], rest: &Point3<f64>| {
            let mut w = weights.map(|w| w.max(0.0));
            let s: f64 = w.iter().sum();
            w.iter_mut().for_each(|w| *w /= s);
            let t = mesh.tets[element as usize];
            let mut out = Vector3::zeros();
            for k in 0..4 {
                let i = t[k];
                out += w[k] * (p(x, i).coords + fbar[i as usize] * (rest - p(&rest_x, i)));
            }
            Point3::from(out)
        };
        let mut smooth = model.render_positions(x, &a.bones());
        for (i, b) in model.render.bindings.iter().enumerate() {
            let rest = &model.render.rest[i];
            match b {
                Binding::Embedded { element, weights } => {
                    smooth[i] = smooth_at(*element, weights, rest)
                }
                Binding::Blended {
                    element,
                    weights,
                    bone,
                    embedded,
                } if *embedded > 0.0 => {
                    let rigid = a.bones().target(*bone, &model.jaw_pivot, rest);
                    smooth[i] = rigid + (smooth_at(*element, weights, rest) - rigid) * *embedded;
                }
                _ => {}
            }
        }
        let mut bary = model.render_positions(x, &a.bones());
        pass.apply(&mut bary, &mut LiningMemory::default());
        pass.apply(&mut smooth, &mut LiningMemory::default());
        {
            let c = audit.creased(&bary);
            let mut len: Vec<f64> = c
                .iter()
                .map(|e| {
                    10.0 * (model.render.rest[e.edge[0] as usize]
                        - model.render.rest[e.edge[1] as usize])
                        .norm()
                })
                .collect();
            len.sort_by(f64::total_cmp);
            let mut all: Vec<f64> = model
                .render
                .triangles
                .iter()
                .map(|t| {
                    10.0 * (model.render.rest[t[0] as usize] - model.render.rest[t[1] as usize])
                        .norm()
                })
                .collect();
            all.sort_by(f64::total_cmp);
            let mut rel: Vec<f64> = c
                .iter()
                .map(|e| {
                    let (a, b) = (e.edge[0] as usize, e.edge[1] as usize);
                    ((bary[a] - goal[a]) - (bary[b] - goal[b])).norm()
                        / (model.render.rest[a] - model.render.rest[b]).norm()
                })
                .collect();
            rel.sort_by(f64::total_cmp);
            if !len.is_empty() {
                println!(
                    "  creased edges' rest length median {:.2} mm (all edges {:.2}); error difference along them / length median {:.2}",
                    len[len.len() / 2],
                    all[all.len() / 2],
                    rel[rel.len() / 2]
                );
            }
        }
        let stats = |pos: &[Point3<f64>]| {
            let mut skin: Vec<f64> = (0..pos.len())
                .filter(|&i| region[i] == Some(Region::FaceSkin))
                .map(|i| 10.0 * (pos[i] - goal[i]).norm())
                .collect();
            skin.sort_by(f64::total_cmp);
            let lining: Vec<f64> = (0..pos.len())
                .filter(|&i| region[i] == Some(Region::MouthSocket))
                .map(|i| 10.0 * (pos[i] - goal[i]).norm())
                .collect();
            format!(
                "creases {:3}, skin max {:5.2} p95 {:.2} mean {:.3}, lining mean {:.2}",
                audit.audit(pos).edges,
                skin.last().unwrap(),
                skin[(skin.len() - 1) * 95 / 100],
                skin.iter().sum::<f64>() / skin.len() as f64,
                lining.iter().sum::<f64>() / lining.len() as f64
            )
        };
        // The tissue's own boundary: faces of one element only, edges between two of them.
        let mut faces: std::collections::HashMap<[u32; 3], Vec<[u32; 3]>> = Default::default();
        for t in &mesh.tets {
            for skip in 0..4 {
                let f: Vec<u32> = (0..4).filter(|&k| k != skip).map(|k| t[k]).collect();
                // Oriented outward: the skipped vertex lies behind.
                let mut tri = [f[0], f[1], f[2]];
                let (a0, a1, a2, o) = (
                    p(&rest_x, tri[0]),
                    p(&rest_x, tri[1]),
                    p(&rest_x, tri[2]),
                    p(&rest_x, t[skip]),
                );
                if (a1 - a0).cross(&(a2 - a0)).dot(&(o - a0)) > 0.0 {
                    tri.swap(1, 2);
                }
                let mut key = tri;
                key.sort_unstable();
                faces.entry(key).or_default().push(tri);
            }
        }
        let boundary: Vec<[u32; 3]> = faces
            .values()
            .filter(|v| v.len() == 1)
            .map(|v| v[0])
            .collect();
        let normal = |xs: &[f64], t: &[u32; 3]| {
            let [a0, a1, a2] = t.map(|v| p(xs, v));
            (a1 - a0)
                .cross(&(a2 - a0))
                .try_normalize(0.0)
                .unwrap_or_default()
        };
        let mut edges: std::collections::HashMap<[u32; 2], Vec<usize>> = Default::default();
        for (k, t) in boundary.iter().enumerate() {
            for j in 0..3 {
                let (a, b) = (t[j], t[(j + 1) % 3]);
                edges.entry([a.min(b), a.max(b)]).or_default().push(k);
            }
        }
        let tissue_creases = edges
            .values()
            .filter(|ts| ts.len() == 2)
            .filter(|ts| {
                normal(&rest_x, &boundary[ts[0]]).dot(&normal(&rest_x, &boundary[ts[1]])) > 0.0
                    && normal(x, &boundary[ts[0]]).dot(&normal(x, &boundary[ts[1]])) < -0.5
            })
            .count();
        println!(
            "  tissue boundary creases {tissue_creases} of {} edges",
            edges.len()
        );
        println!(
            "{name:15} rig creases {:3}\n  barycentric: {}\n  smooth:      {}",
            audit.audit(&goal).edges,
            stats(&bary),
            stats(&smooth)
        );
    }
    Ok(())
}
