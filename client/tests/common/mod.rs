//! What the command-line tests share: where the real data is.

use std::path::PathBuf;

/// `../shared/data/lmo` beside the project, when it is there; `None` (the caller skips, saying
/// why) when it is not, except under `CI=true`, where the data must be there.
pub fn lmo() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/lmo");
    if dir.join("test").is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but the LM-O data is missing at {}", dir.display());
    }
    eprintln!(
        "skipped: no LM-O data at {} (the test runs when it is there)",
        dir.display()
    );
    None
}
