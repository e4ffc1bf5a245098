//! Datasets in the BOP layout (<https://bop.felk.cvut.cz>), and judging pose estimates on them as
//! the BOP benchmark does.
//!
//! - [`dataset::BopDataset`] reads a dataset's object models, camera parameters, test scenes
//!   (depth images) and ground-truth poses ([`dataset::GtPose`]), and its test targets
//!   ([`dataset::TestTarget`]).
//! - [`eval`] reads and writes BOP results files, one [`eval::EstimateRow`] per pose estimate,
//!   and scores them against a `BopDataset` ([`eval::score_results`] → [`eval::ScoreReport`]):
//!   the VSD, MSSD and MSPD pose errors, the BOP 2018 recall and the BOP 2019 average recall.
//!
//! Meshes, depth frames, rendering and poses are those of `ppfd-models`; what they report
//! reaches the caller inside this crate's [`Error`].
//!
//! ```no_run
//! use ppfd_bop::dataset::BopDataset;
//! use ppfd_bop::eval::{read_results, score_results, ScoreOptions};
//! let dataset = BopDataset::open("../shared/data/lmo")?;
//! let rows = read_results("results.csv")?;
//! let report = score_results(&dataset, &rows, &ScoreOptions::default())?;
//! println!("AR {:.3}", report.overall.ar);
//! # Ok::<(), ppfd_bop::Error>(())
//! ```

#![warn(missing_docs)]

pub mod dataset;
mod error;
pub mod eval;

pub use error::{Error, Result};

/// For tests: the dataset `name` of the shared test data (`../shared/data/<name>` beside the
/// workspace, or `$PPFD_SHARED_DATA/<name>`; `""` for the folder itself), or `None` when it is
/// absent, after printing that the test is skipped. Under `CI=true` absent data fails the test
/// instead: the tests that read real data must run in CI.
pub fn shared_test_data(name: &str) -> Option<std::path::PathBuf> {
    let root = std::env::var_os("PPFD_SHARED_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data").into());
    let dir = if name.is_empty() {
        root
    } else {
        root.join(name)
    };
    if dir.is_dir() {
        return Some(dir);
    }
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    assert!(
        !ci,
        "CI=true but the shared test data is missing at {}",
        dir.display()
    );
    println!(
        "skipped: no shared test data at {} (the test runs when it is there)",
        dir.display()
    );
    None
}
