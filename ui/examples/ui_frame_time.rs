//! UI frame time while the simulator is busy: the editor (headless, egui_kittest) on the
//! bundled sample, its worker solving at the final preset, a slider moving every UI frame so
//! the worker never rests. Times each UI frame on the UI thread (egui layout, the panels,
//! taking the latest frame and preparing the viewport's vertex data; the GPU's draw is not
//! included, there is no GPU here) and counts the physics frames that arrived meanwhile.
//!
//! `cargo run --release -p facesim-ui --example ui_frame_time`

use std::sync::Arc;
use std::time::Instant;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use facesim::session::SessionHandle;
use facesim::sim::Quality;
use facesim_ui::app::EditorApp;

fn main() -> anyhow::Result<()> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(facesim::sample::SAMPLE_DIR);
    for quality in Quality::ALL {
        let session: Arc<dyn SessionHandle> = Arc::new(facesim_ui::faces::open_sample_session(
            &dir,
            quality,
            facesim_ui::faces::Actuation::Basis,
        )?);
        let mut harness = Harness::builder()
            .with_size(egui::vec2(1400.0, 900.0))
            .build_eframe(|cc| EditorApp::new(cc, session.clone()));
        while harness.state().last_frame.is_none() {
            std::thread::sleep(std::time::Duration::from_millis(10));
            harness.step();
        }
        let first = harness.state().last_frame.as_ref().map(|f| f.index);
        let (mut ms, steps) = (Vec::new(), 300);
        let (mut slow, mut arrivals) = (Vec::new(), 0);
        for k in 0..steps {
            let tick = Instant::now();
            let seen = harness.state().last_frame.as_ref().map(|f| f.index);
            let w = 0.5 + 0.5 * (k as f64 * 0.05).sin();
            harness
                .get_by_role_and_label(egui::accesskit::Role::Slider, "jawOpen")
                .set_value_accesskit(w);
            let start = Instant::now();
            harness.step();
            let t = start.elapsed().as_secs_f64() * 1e3;
            ms.push(t);
            let arrived = harness.state().last_frame.as_ref().map(|f| f.index) != seen;
            arrivals += usize::from(arrived);
            if t > 30.0 {
                slow.push(format!("{t:.0} ms (new physics frame: {arrived})"));
            }
            // Pace the UI at 60 Hz, as a display would.
            std::thread::sleep(
                std::time::Duration::from_secs_f64(1.0 / 60.0).saturating_sub(tick.elapsed()),
            );
        }
        let last = harness.state().last_frame.as_ref().map(|f| f.index);
        ms.sort_by(f64::total_cmp);
        println!(
            "{:<11} UI frame median {:.2} ms, p95 {:.2} ms, max {:.2} ms over {steps} frames; {} physics frames arrived meanwhile",
            quality.name(),
            ms[steps / 2],
            ms[steps * 95 / 100],
            ms[steps - 1],
            last.zip(first).map_or(0, |(l, f)| l - f)
        );
        println!("  UI frames with a new physics frame: {arrivals}; slow: {slow:?}");
    }
    Ok(())
}
