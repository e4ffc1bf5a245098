//! What the command-line tests share: scratch folders. The real data is found with
//! `ppfd_bop::shared_test_data`.

use std::path::PathBuf;

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
