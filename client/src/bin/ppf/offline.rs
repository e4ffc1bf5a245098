//! What the offline commands share: loading a BOP dataset's models, built once and cached.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use ppfd_models::bop::BopDataset;
use ppfd_models::mesh::Mesh;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::{store, Pose};

/// Where built models are cached: `$PPFD_CACHE`, else `$XDG_CACHE_HOME/ppfd`, else
/// `~/.cache/ppfd`, else the system temporary directory.
pub fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("PPFD_CACHE") {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_CACHE_HOME") {
        return PathBuf::from(d).join("ppfd");
    }
    if let Some(h) = std::env::var_os("HOME") {
        return PathBuf::from(h).join(".cache/ppfd");
    }
    std::env::temp_dir().join("ppfd-cache")
}

/// A cache file name that changes whenever the mesh file does (path, size, modification time).
fn cache_path(mesh: &Path) -> std::io::Result<PathBuf> {
    let meta = std::fs::metadata(mesh)?;
    let modified = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let canonical = std::fs::canonicalize(mesh)?;
    let key = format!("{}|{}|{}", canonical.display(), meta.len(), modified);
    let hash = crc32fast::hash(key.as_bytes());
    let stem = mesh.file_stem().unwrap_or_default().to_string_lossy();
    Ok(cache_dir().join(format!("{stem}-{hash:08x}.{}", store::EXTENSION)))
}

/// Loads the model of `mesh` from the cache, or builds it and caches it.
pub fn load_or_build(
    mesh_path: &Path,
    object_id: u32,
    params: &ModelParams,
) -> Result<ObjectModel, String> {
    let cached = cache_path(mesh_path).map_err(|e| format!("{}: {e}", mesh_path.display()))?;
    if let Ok(model) = store::load_expecting(&cached, params) {
        if model.object_id() == object_id {
            return Ok(model);
        }
    }
    let name = mesh_path
        .file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    let mesh = Mesh::from_ply_file(mesh_path).map_err(|e| e.to_string())?;
    let model = ObjectModel::build(&mesh, object_id, &name, params).map_err(|e| e.to_string())?;
    if std::fs::create_dir_all(cache_dir()).is_ok() {
        if let Err(e) = store::save(&model, &cached) {
            tracing::warn!("could not cache {}: {e}", cached.display());
        }
    }
    Ok(model)
}

/// The models of `ids` in `dataset`, with a progress bar when there are several to build.
pub fn dataset_models(dataset: &BopDataset, ids: &[u32]) -> Result<Vec<ObjectModel>, String> {
    let params = ModelParams::default();
    let bar = ProgressBar::new(ids.len() as u64);
    bar.set_style(ProgressStyle::with_template("models {bar:30} {pos}/{len} {msg}").unwrap());
    let mut out = Vec::new();
    for &id in ids {
        bar.set_message(format!("object {id}"));
        let path = dataset.model_path(id).map_err(|e| e.to_string())?;
        out.push(load_or_build(&path, id, &params)?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(out)
}

/// Translation error (mm) and rotation error (degrees) of `est` against `gt`.
pub fn pose_errors(est: &Pose, gt: &Pose) -> (f32, f32) {
    let dt = (est.translation.vector - gt.translation.vector).norm();
    let dr = est.rotation.angle_to(&gt.rotation).to_degrees();
    (dt, dr)
}

/// Like [`pose_errors`], the smallest over the object's discrete symmetries (identity
/// included): a pose turned by a symmetry of the object is as right as the ground truth.
pub fn symmetric_pose_errors(est: &Pose, gt: &Pose, symmetries: &[Pose]) -> (f32, f32) {
    let mut best = pose_errors(est, gt);
    for s in symmetries {
        let e = pose_errors(est, &(gt * s));
        if e.0 + e.1 < best.0 + best.1 {
            best = e;
        }
    }
    best
}
