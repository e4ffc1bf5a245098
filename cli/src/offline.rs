//! What the offline commands share: loading a BOP dataset's models, built once and cached
//! ([`ppfd::model_cache`]), with the symmetries of the `models_info.json` beside the meshes.

use indicatif::{ProgressBar, ProgressStyle};
use ppfd::model_cache::{load_or_build, MeshSource, ModelFiles};
use ppfd_bop::dataset::BopDataset;
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};
use rayon::prelude::*;

/// The models of `ids` in `dataset`, with a progress bar when there are several to build.
pub fn dataset_models(dataset: &BopDataset, ids: &[u32]) -> Result<Vec<ObjectModel>, String> {
    let params = ModelParams::default();
    let bar = ProgressBar::new(ids.len() as u64);
    bar.set_style(ProgressStyle::with_template("models {bar:30} {pos}/{len}").unwrap());
    // Loading checks each file against its mesh, and a missing one is built: the objects are
    // independent, so they load side by side, in the order asked for.
    let out = ids
        .par_iter()
        .map(|&id| {
            let path = dataset.model_path(id).map_err(|e| e.to_string())?;
            // In the daemon's default cache, on the daemon's terms.
            let files = ModelFiles::of_mesh(&path, Some(&store::default_cache_dir()));
            // A mesh refused for what it holds is named by its file, as a malformed one is.
            let cached = load_or_build(MeshSource::File(&path), id, &params, &files).map_err(
                |e| match e {
                    ppfd_models::Error::InvalidMesh(_) => format!("{}: {e}", path.display()),
                    e => e.to_string(),
                },
            )?;
            // With the symmetry of the models_info.json beside the mesh, as the daemon's.
            if let Some(why) = &cached.symmetry_left_out {
                bar.suspend(|| eprintln!("warning: {why}"));
            }
            if let Some(w) = ppfd_models::limits::small_diameter(cached.model.diameter_mm()) {
                bar.suspend(|| eprintln!("warning: {}: {w}", path.display()));
            }
            bar.inc(1);
            Ok(cached.model)
        })
        .collect::<Result<Vec<ObjectModel>, String>>()?;
    bar.finish_and_clear();
    Ok(out)
}
