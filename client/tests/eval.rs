//! `ppf eval` refuses a results file it cannot write before it detects anything (a run over a
//! dataset takes minutes to hours). Reads `../shared/data/lmo`; runs whenever the data is there,
//! and always under `CI=true`.
#![cfg(feature = "cli")]

use std::path::PathBuf;
use std::process::Command;

fn lmo() -> Option<PathBuf> {
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

#[test]
fn an_unwritable_results_file_is_refused_before_any_detection() {
    let Some(dataset) = lmo() else { return };
    let out = std::env::temp_dir()
        .join(format!("ppf-eval-missing-{}", std::process::id()))
        .join("results.csv");
    let cache = std::env::temp_dir().join(format!("ppf-eval-cache-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let run = Command::new(env!("CARGO_BIN_EXE_ppf"))
        .arg("eval")
        .arg(&dataset)
        .arg("--out")
        .arg(&out)
        // No model cache of the user's is touched: nothing may be built at all.
        .env(
            "PPFD_CACHE",
            std::env::temp_dir().join("ppf-eval-unused-cache"),
        )
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("results.csv") && stderr.contains("No such file"),
        "{stderr}"
    );
    assert!(
        !stderr.contains("estimates"),
        "nothing was detected: {stderr}"
    );
    assert!(!cache.exists(), "no model was built before the refusal");
}
