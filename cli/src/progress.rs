//! Progress on standard error. indicatif draws its bars only on a terminal (its stderr target
//! hides itself otherwise), and the rig's per-file line is written only there, so logs get
//! the summaries alone, without carriage returns or escape codes.

use std::io::IsTerminal;
use std::path::Path;
use std::time::Duration;

use facesim::rig::{FaceRig, RigError};
use indicatif::{ProgressBar, ProgressStyle};

/// A spinner that shows the current step and the time spent.
pub fn spinner() -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// A bar of `len` steps drawn with `template` (indicatif's syntax; `=> ` progress chars).
pub fn bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(template)
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar
}

/// Loads the rig, with a line of progress per file on a terminal and only the summary in a
/// log (the error names the file that failed).
pub fn load_rig(rig_dir: &Path) -> Result<FaceRig, RigError> {
    let terminal = std::io::stderr().is_terminal();
    eprintln!("loading the rig from {}…", rig_dir.display());
    let rig = FaceRig::load_with_progress(rig_dir, &|p| {
        if terminal {
            eprint!("\r  {}/{} {}\x1b[K", p.done, p.total, p.file.display())
        }
    })?;
    let summary = format!(
        "  loaded {} shapes and {} identities in {:.2} s",
        rig.shape_names().len(),
        rig.identity_count(),
        rig.load_time().as_secs_f64()
    );
    if terminal {
        eprintln!("\r{summary}\x1b[K");
    } else {
        eprintln!("{summary}");
    }
    Ok(rig)
}
