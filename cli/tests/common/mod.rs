//! What the command-line tests share: scratch folders, and showing what a command printed. The real data is found with
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

/// Prints what `command` gave, for a failing test to show.
#[allow(dead_code)]
pub fn show(command: &std::process::Command, out: &std::process::Output) {
    eprintln!(
        "{command:?}: {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
