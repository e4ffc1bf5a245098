//! What the offline commands share: loading a BOP dataset's models, built once and cached.

use std::path::Path;

use indicatif::{ProgressBar, ProgressStyle};
use ppfd_bop::dataset::BopDataset;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_models::Pose;

/// Loads the model of `mesh_path` from the cache ([`store::default_cache_dir`], the daemon's
/// default too), or builds it and caches it.
pub fn load_or_build(
    mesh_path: &Path,
    object_id: u32,
    params: &ModelParams,
) -> Result<ObjectModel, String> {
    load_or_build_in(&store::default_cache_dir(), mesh_path, object_id, params)
}

/// [`load_or_build`] with the cache in `cache_dir`. The cached model is used if built with the
/// same parameters and object id from the same bytes of the mesh file (then the mesh is not
/// parsed) or from the same mesh (its fingerprint); otherwise it is rebuilt and replaced.
fn load_or_build_in(
    cache_dir: &Path,
    mesh_path: &Path,
    object_id: u32,
    params: &ModelParams,
) -> Result<ObjectModel, String> {
    let cached = store::cache_file(cache_dir, mesh_path);
    let bytes = std::fs::read(mesh_path).map_err(|e| format!("{}: {e}", mesh_path.display()))?;
    let source_crc = store::source_crc(&bytes);
    if cached.is_file() {
        if let Ok(model) = store::load_built_from_file(&cached, params, source_crc) {
            if model.object_id() == object_id {
                return Ok(model);
            }
        }
    }
    let mesh = Mesh::from_ply_reader(&bytes[..], mesh_path).map_err(|e| e.to_string())?;
    if cached.is_file() {
        match store::load_expecting(&cached, params, mesh.fingerprint()) {
            Ok(model) if model.object_id() == object_id => {
                // The same mesh in a rewritten file: record the file's CRC for the next run.
                if model.source_crc() != source_crc {
                    if let Ok(updated) = ObjectModel::clone_with_source_crc(&model, source_crc) {
                        if store::save(&updated, &cached).is_ok() {
                            return Ok(updated);
                        }
                    }
                }
                return Ok(model);
            }
            Ok(model) => tracing::info!(
                "{}: object {}, not {object_id}: rebuilding",
                cached.display(),
                model.object_id()
            ),
            Err(e) => tracing::info!("{e}"),
        }
    }
    let name = mesh_path
        .file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    let model = ObjectModel::build(&mesh, object_id, &name, params)
        .and_then(|m| m.with_source_crc(source_crc))
        .map_err(|e| e.to_string())?;
    if std::fs::create_dir_all(cache_dir).is_ok() {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("ppf-offline-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// An ASCII PLY file of a closed box of `size` mm.
    fn write_box_ply(path: &Path, [sx, sy, sz]: [f32; 3]) {
        let mesh = ppfd_models::synthetic::parts::box_mesh(nalgebra::Vector3::new(sx, sy, sz));
        std::fs::write(path, mesh.to_ply_ascii()).unwrap();
    }

    fn diagonal([x, y, z]: [f32; 3]) -> f32 {
        (x * x + y * y + z * z).sqrt()
    }

    #[test]
    fn a_cached_model_is_rebuilt_when_its_mesh_changes() {
        let root = scratch("rebuild");
        let cache = root.join("cache");
        let ply = root.join("obj_000003.ply");
        let params = ModelParams::default();
        let (a, b) = ([50.0, 30.0, 20.0], [50.0, 30.0, 45.0]);
        write_box_ply(&ply, a);
        let first = load_or_build_in(&cache, &ply, 3, &params).unwrap();
        assert!((first.diameter_mm() - diagonal(a)).abs() < 0.01);
        let cached = store::cache_file(&cache, &ply);
        assert!(cached.is_file(), "the built model is cached");

        // Unchanged mesh: the cached model is used. A copy renamed "earlier" tells it apart
        // from a rebuilt one.
        let mesh = Mesh::from_ply_file(&ply).unwrap();
        store::save(
            &ObjectModel::build(&mesh, 3, "earlier", &params).unwrap(),
            &cached,
        )
        .unwrap();
        assert_eq!(
            load_or_build_in(&cache, &ply, 3, &params).unwrap().name(),
            "earlier"
        );
        // Accepted by its mesh, it now records the file's CRC: the next run reads no mesh.
        let crc = store::source_crc(&std::fs::read(&ply).unwrap());
        let recorded = store::load(&cached).unwrap();
        assert_eq!((recorded.name(), recorded.source_crc()), ("earlier", crc));
        assert!(store::load_built_from_file(&cached, &params, crc).is_ok());

        // The mesh file replaced by another mesh (its modification time kept or not): rebuilt.
        write_box_ply(&ply, b);
        let second = load_or_build_in(&cache, &ply, 3, &params).unwrap();
        assert!(
            (second.diameter_mm() - diagonal(b)).abs() < 0.01,
            "diameter {} mm is the old mesh's",
            second.diameter_mm()
        );
        assert_eq!(second.name(), "obj_000003");
        let fingerprint = Mesh::from_ply_file(&ply).unwrap().fingerprint();
        assert_eq!(
            store::load(&cached).unwrap().mesh_fingerprint(),
            fingerprint
        );

        // A model file of an older format is rebuilt, not an error.
        let mut old = std::fs::read(&cached).unwrap();
        old[8..12].copy_from_slice(&(store::FORMAT_VERSION - 1).to_le_bytes());
        std::fs::write(&cached, old).unwrap();
        let third = load_or_build_in(&cache, &ply, 3, &params).unwrap();
        assert!((third.diameter_mm() - diagonal(b)).abs() < 0.01);
        assert!(store::load(&cached).is_ok(), "the old file is replaced");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
