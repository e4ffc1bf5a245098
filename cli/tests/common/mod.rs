//! What the command-line tests share: where the real data is, and scratch folders.

use std::path::PathBuf;

/// `../shared/data/<name>` beside the project, when it is there; `None` (the caller skips,
/// saying why) when it is not, except under `CI=true`, where the data must be there.
pub fn shared_data(name: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(name);
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("CI=true but the data is missing at {}", dir.display());
    }
    eprintln!(
        "skipped: no data at {} (the test runs when it is there)",
        dir.display()
    );
    None
}

/// The real LM-O frame's dataset ([`shared_data`]).
#[allow(dead_code)] // not every test file reads it
pub fn lmo() -> Option<PathBuf> {
    shared_data("lmo")
}

/// A fresh scratch directory, `<temp>/ppf-<name>-<pid>`, removed when dropped.
#[allow(dead_code)] // not every test file writes files
pub struct Scratch(pub PathBuf);

#[allow(dead_code)]
impl Scratch {
    pub fn new(name: &str) -> Scratch {
        let dir = std::env::temp_dir().join(format!("ppf-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Scratch(dir)
    }

    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
