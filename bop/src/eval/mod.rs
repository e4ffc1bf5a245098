//! Judging pose estimates as the BOP benchmark does (<https://bop.felk.cvut.cz>, Hodaň et al.).
//!
//! - [`csv`] reads and writes BOP results files: one [`EstimateRow`] per line.
//! - The pose errors follow the BOP toolkit's `pose_error` module: [`vsd`] (Visible Surface
//!   Discrepancy, on distance maps from rendered depth, with the 2018 and 2019 visibility
//!   rules), [`mssd`] (largest vertex distance, mm) and [`mspd`] (largest projected vertex
//!   distance, pixels), the last two minimised over the object's [`symmetry`] transforms.
//! - [`recall`] matches each target's estimates, best score first, to the ground truth greedily.
//! - [`score_results`] puts it together for a [`BopDataset`](crate::dataset::BopDataset): it renders
//!   the `models_eval/` meshes with [`ppfd_models::geometry::render`], computes every error of every estimate
//!   against every instance of its object, and reports per object and overall
//!   ([`ScoreReport`]):
//!   - the BOP 2018 recall: VSD with δ 15 mm, τ 20 mm and the 2018 visibility rule, correct
//!     below θ 0.3 (SIXD/BOP 2018) or 0.35 (as Vidal et al. 2018 report);
//!   - the BOP 2019 average recall AR = mean(AR_VSD, AR_MSSD, AR_MSPD), each the mean recall
//!     over its grid: VSD over τ ∈ {0.05 … 0.5}·D × θ ∈ {0.05 … 0.5}, MSSD below
//!     {0.05 … 0.5}·D, MSPD below {5 … 50}·width/640 pixels.
//!
//!   Only ground truth at least 10 % visible counts (and can be matched); each target's
//!   `inst_count` best-scored estimates are scored.
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

pub mod csv;
pub mod gt_info;
pub mod mspd;
pub mod mssd;
pub mod recall;
pub mod score;
pub mod symmetry;
pub mod vsd;

pub use csv::{parse_results, read_results, write_results, write_results_file, EstimateRow};
pub use score::{
    image_errors, score_results, score_results_with, summarize, targets_from_ground_truth,
    EvalImage, EvalObject, ObjectScore, ScoreOptions, ScoreReport, TargetErrors, VisibBin,
};
