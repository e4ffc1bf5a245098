//! The production engine: `ppfd_models`' detector over models read from model files.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ppfd_models::detect::detector::{DetectOptions as ModelOptions, Detector};
use ppfd_models::geometry::camera::{DepthFrame, Intrinsics};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_protocol::control::ModelInfo;
use ppfd_protocol::detect::{DetectCounts, LatencyBreakdown, PoseHypothesis, Status};
use ppfd_protocol::text;

use crate::engine::{
    DetectOptions, DetectionEngine, EngineError, EngineOutput, FrameView, LoadedModel,
};

/// Extension of model files.
pub const MODEL_EXTENSION: &str = "ppfm";

/// Detection with `ppfd_models::detect::detector::Detector`; models are `.ppfm` files (read without
/// decoding) or PLY meshes, built once and saved as `.ppfm` for the next start.
///
/// A model file beside a PLY mesh of the same name, or in the model cache, is that mesh's
/// cache: it is used only while it was built from the same mesh (the fingerprint of the mesh as
/// read, so an ASCII file re-saved as binary keeps its model) with the same parameters and
/// object id; otherwise the model is rebuilt. Hence every PLY mesh is read at each load.
#[derive(Debug, Default)]
pub struct PpfEngine {
    detector: Detector,
    model_params: ModelParams,
}

impl PpfEngine {
    /// An engine with the given parameters.
    pub fn new(detector: Detector, model_params: ModelParams) -> Self {
        PpfEngine {
            detector,
            model_params,
        }
    }

    /// An engine with the configuration's detector parameters and the default model
    /// parameters.
    pub fn from_config(config: &crate::config::DaemonConfig) -> crate::Result<Self> {
        Ok(Self::new(
            Detector::new(config.detect_params()?),
            ModelParams::default(),
        ))
    }
}

fn ext_is(path: &Path, ext: &str) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext))
}

/// The object id a file name implies: the digits of its stem (`obj_000005.ply` → 5).
pub fn object_id_of_file(path: &Path) -> Option<u32> {
    let stem = path.file_stem()?.to_str()?;
    let digits: String = stem
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_digit())
        .collect();
    digits.chars().rev().collect::<String>().parse().ok()
}

fn model_error(e: ppfd_models::Error) -> EngineError {
    use ppfd_models::Error;
    let status = match &e {
        Error::InvalidFrame(_) => Status::InvalidFrame,
        Error::UnknownObject(_) => Status::UnknownObject,
        Error::DeadlineExceeded { .. } => Status::DeadlineExceeded,
        // Only a client that is gone has its detection cancelled: the answer goes nowhere.
        Error::Cancelled { .. } => Status::Internal,
        Error::InvalidParameter(_) => Status::InvalidRequest,
        Error::Io { .. } | Error::Ply { .. } | Error::InvalidMesh(_) | Error::ModelStore { .. } => {
            Status::ModelError
        }
        _ => Status::Internal,
    };
    let value = if let Error::UnknownObject(id) = e {
        id as u64
    } else {
        0
    };
    EngineError {
        status,
        message: e.to_string(),
        value,
    }
}

fn info_of(model: &ObjectModel) -> ModelInfo {
    ModelInfo {
        object_id: model.object_id(),
        point_count: model.point_count() as u32,
        table_entries: model.table_entry_count() as u64,
        byte_size: model.byte_size() as u64,
        diameter_mm: model.diameter_mm(),
        name: text::encode_truncated(model.name()),
        ..Default::default()
    }
}

fn loaded(model: ObjectModel, source: &Path) -> LoadedModel {
    LoadedModel {
        info: info_of(&model),
        source: source.to_path_buf(),
        data: Box::new(model),
    }
}

impl PpfEngine {
    /// Where the model built from `ply` is saved: in `cache_dir` ([`store::cache_file`]), or
    /// beside the mesh without one (the daemon always gives one).
    fn cache_path(ply: &Path, cache_dir: Option<&Path>) -> PathBuf {
        match cache_dir {
            Some(dir) => store::cache_file(dir, ply),
            None => ply.with_extension(MODEL_EXTENSION),
        }
    }

    fn load_ply(
        &self,
        path: &Path,
        object_id: Option<u32>,
        cache_dir: Option<&Path>,
    ) -> Result<LoadedModel, EngineError> {
        let id = object_id
            .or_else(|| object_id_of_file(path))
            .ok_or_else(|| {
                EngineError::new(
                    Status::ModelError,
                    format!(
                        "{}: no object id: name the file obj_<id>.ply or give an id",
                        path.display()
                    ),
                )
            })?;
        if id == 0 {
            // Refused before the model is built (the registry refuses it anyway).
            return Err(crate::registry::object_id_zero(path));
        }
        let began = std::time::Instant::now();
        let bytes = std::fs::read(path).map_err(|source| {
            model_error(ppfd_models::Error::Io {
                path: path.to_path_buf(),
                source,
            })
        })?;
        let source_crc = store::source_crc(&bytes);
        let cache = Self::cache_path(path, cache_dir);
        let beside = path.with_extension(MODEL_EXTENSION);
        let mut candidates = vec![beside];
        if cache != candidates[0] {
            candidates.push(cache.clone());
        }
        // A model cache written before its files were named after their mesh's path held
        // `<stem>.ppfm`: still good if built from this mesh.
        if let (Some(dir), Some(file)) = (cache_dir, candidates[0].file_name()) {
            candidates.push(dir.join(file));
        }
        // First without parsing the mesh: a model built from these very bytes.
        for candidate in candidates.iter().filter(|p| p.is_file()) {
            match store::load_built_from_file(candidate, &self.model_params, source_crc) {
                Ok(model) if model.object_id() == id => {
                    tracing::info!(path = %candidate.display(), "using the model built earlier from this file");
                    return Ok(loaded(model, candidate));
                }
                Ok(_) => {}
                Err(e) => {
                    tracing::debug!(path = %candidate.display(), reason = %e, "not built from this file")
                }
            }
        }
        let mesh = Mesh::from_ply_reader(&bytes[..], path).map_err(model_error)?;
        let read_ms = began.elapsed().as_millis() as u64;
        let fingerprint = mesh.fingerprint();
        for candidate in candidates.iter().filter(|p| p.is_file()) {
            match store::load_expecting(candidate, &self.model_params, fingerprint) {
                Ok(model) if model.object_id() == id => {
                    tracing::info!(path = %candidate.display(), "using the model built earlier");
                    // The same mesh in a rewritten file: record the file's new CRC, so that the
                    // next start need not parse the mesh again.
                    let model = match with_file_crc(model, candidate, source_crc) {
                        Ok(updated) => updated,
                        Err((model, e)) => {
                            tracing::debug!(path = %candidate.display(), error = %e, "CRC not recorded");
                            model
                        }
                    };
                    return Ok(loaded(model, candidate));
                }
                Ok(model) => tracing::info!(
                    path = %candidate.display(),
                    cached = model.object_id(),
                    wanted = id,
                    "model built earlier has another object id; not used"
                ),
                Err(e) => {
                    tracing::info!(path = %candidate.display(), reason = %e, "model built earlier refused")
                }
            }
        }
        let started = std::time::Instant::now();
        let name = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("object");
        let model = ObjectModel::build(&mesh, id, name, &self.model_params)
            .and_then(|m| m.with_source_crc(source_crc))
            .map_err(model_error)?;
        tracing::info!(
            path = %path.display(),
            object_id = id,
            points = model.point_count(),
            read_ms,
            build_ms = started.elapsed().as_millis() as u64,
            "model built from mesh"
        );
        if let Some(dir) = cache.parent() {
            let _ = std::fs::create_dir_all(dir);
        }
        match store::save(&model, &cache) {
            // Read the saved file back: what the next start will use is checked now.
            Ok(()) => match store::load(&cache) {
                Ok(read_back) => Ok(loaded(read_back, &cache)),
                Err(_) => Ok(loaded(model, path)),
            },
            Err(e) => {
                tracing::warn!(path = %cache.display(), error = %e, "built model not cached");
                Ok(loaded(model, path))
            }
        }
    }
}

/// `model`, saved at `path` again with `crc` as its mesh file's CRC (nothing to do when it has
/// it already), and read back; on failure the model as it was, with the reason.
fn with_file_crc(
    model: ObjectModel,
    path: &Path,
    crc: u32,
) -> Result<ObjectModel, (ObjectModel, ppfd_models::Error)> {
    if model.source_crc() == crc {
        return Ok(model);
    }
    let updated = match ObjectModel::clone_with_source_crc(&model, crc) {
        Ok(updated) => updated,
        Err(e) => return Err((model, e)),
    };
    if let Err(e) = store::save(&updated, path) {
        return Err((model, e));
    }
    store::load(path).map_err(|e| (model, e))
}

impl DetectionEngine for PpfEngine {
    fn name(&self) -> &'static str {
        "ppf"
    }

    fn accepts(&self, path: &Path) -> bool {
        ext_is(path, MODEL_EXTENSION) || ext_is(path, "ply")
    }

    fn select(&self, files: Vec<PathBuf>) -> Vec<PathBuf> {
        // A model file beside a PLY mesh is reached through the mesh, which says whether the
        // model still belongs to it.
        let has_mesh = |model: &PathBuf| {
            files
                .iter()
                .any(|p| ext_is(p, "ply") && p.with_extension(MODEL_EXTENSION) == *model)
        };
        let mut out: Vec<PathBuf> = files
            .iter()
            .filter(|p| ext_is(p, MODEL_EXTENSION) && !has_mesh(p))
            .cloned()
            .collect();
        out.extend(files.iter().filter(|p| ext_is(p, "ply")).cloned());
        out
    }

    fn load(
        &self,
        path: &Path,
        object_id: Option<u32>,
        cache_dir: Option<&Path>,
    ) -> Result<LoadedModel, EngineError> {
        if ext_is(path, "ply") {
            return self.load_ply(path, object_id, cache_dir);
        }
        if let Some(mesh) = ["ply", "PLY"]
            .map(|e| path.with_extension(e))
            .into_iter()
            .find(|p| p.is_file())
        {
            return self.load_ply(&mesh, object_id, cache_dir);
        }
        let model = store::load(path).map_err(model_error)?;
        if let Some(id) = object_id {
            if id != model.object_id() {
                return Err(EngineError::new(
                    Status::ModelError,
                    format!(
                        "{} holds object {}, not {id}",
                        path.display(),
                        model.object_id()
                    ),
                ));
            }
        }
        Ok(loaded(model, path))
    }

    fn detect(
        &self,
        frame: &FrameView<'_>,
        models: &[Arc<LoadedModel>],
        options: &DetectOptions,
    ) -> Result<EngineOutput, EngineError> {
        let k = frame.intrinsics;
        let depth_frame = DepthFrame {
            width: frame.width,
            height: frame.height,
            intrinsics: Intrinsics {
                fx: k.fx,
                fy: k.fy,
                cx: k.cx,
                cy: k.cy,
            },
            depth_scale_mm: frame.depth_scale_mm,
            depth: frame.depth,
        };
        let object_models: Vec<&ObjectModel> = models
            .iter()
            .map(|m| {
                m.data.downcast_ref::<ObjectModel>().ok_or_else(|| {
                    EngineError::new(
                        Status::Internal,
                        format!("model {} was not loaded by this engine", m.info.object_id),
                    )
                })
            })
            .collect::<Result<_, _>>()?;
        let opts = ModelOptions {
            hypotheses_per_object: options.hypotheses_per_object,
            deadline: options.deadline,
            cancel: Some(options.cancel.clone()),
        };
        let found = self
            .detector
            .detect(&depth_frame, &object_models, &opts)
            .map_err(model_error)?;

        let mut hypotheses = Vec::new();
        for object in &found.objects {
            for (rank, h) in object
                .hypotheses
                .iter()
                .take(options.hypotheses_per_object)
                .enumerate()
            {
                let r = h.pose.rotation.to_rotation_matrix();
                let m = r.matrix();
                let t = h.pose.translation.vector;
                hypotheses.push(PoseHypothesis {
                    object_id: object.object_id,
                    instance_rank: rank as u32,
                    rotation: [
                        m[(0, 0)],
                        m[(0, 1)],
                        m[(0, 2)],
                        m[(1, 0)],
                        m[(1, 1)],
                        m[(1, 2)],
                        m[(2, 0)],
                        m[(2, 1)],
                        m[(2, 2)],
                    ],
                    translation_mm: [t.x, t.y, t.z],
                    score: h.score,
                    votes: h.votes,
                    checks: h.checks.0,
                });
            }
        }
        let ns = |d: std::time::Duration| d.as_nanos() as u64;
        let t = &found.timings;
        Ok(EngineOutput {
            hypotheses,
            stages: LatencyBreakdown {
                scene_preparation_ns: ns(t.scene_preparation),
                kd_tree_ns: ns(t.kd_tree),
                voting_ns: ns(t.voting),
                clustering_ns: ns(t.clustering),
                rescoring_ns: ns(t.rescoring),
                icp_ns: ns(t.icp),
                filters_ns: ns(t.filters),
                ..Default::default()
            },
            counts: DetectCounts {
                scene_points: found.counts.scene_points,
                reference_points: found.counts.reference_points,
                pairs: found.counts.pairs,
                hypotheses: found.counts.hypotheses,
                returned: 0,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn object_ids_come_from_trailing_digits() {
        assert_eq!(object_id_of_file(Path::new("/m/obj_000005.ply")), Some(5));
        assert_eq!(object_id_of_file(Path::new("part12.ppfm")), Some(12));
        assert_eq!(object_id_of_file(Path::new("duck.ply")), None);
    }

    #[test]
    fn a_model_file_beside_its_mesh_is_reached_through_the_mesh() {
        let e = PpfEngine::default();
        let files = vec![
            PathBuf::from("d/obj_000001.ply"),
            PathBuf::from("d/obj_000001.ppfm"),
            PathBuf::from("d/obj_000002.ply"),
            PathBuf::from("d/obj_000003.ppfm"),
            PathBuf::from("d/readme.txt"),
        ];
        let chosen = e.select(files);
        assert_eq!(
            chosen,
            vec![
                PathBuf::from("d/obj_000003.ppfm"),
                PathBuf::from("d/obj_000001.ply"),
                PathBuf::from("d/obj_000002.ply")
            ]
        );
    }

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ppfd-engine-{name}-{}", std::process::id()));
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

    /// Loads the directory as the daemon does at start: the selected files, by object id.
    fn load_dir(e: &PpfEngine, dir: &Path, cache: Option<&Path>) -> Vec<LoadedModel> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .unwrap()
            .map(|f| f.unwrap().path())
            .collect();
        files.sort();
        e.select(files)
            .iter()
            .map(|p| e.load(p, None, cache).unwrap_or_else(|err| panic!("{err}")))
            .collect()
    }

    /// A model cache written when its files were named `<stem>.ppfm` is still used.
    #[test]
    fn a_model_cached_under_the_earlier_file_name_is_used() {
        let root = scratch("earlier-name");
        let (models, cache) = (root.join("models"), root.join("cache"));
        std::fs::create_dir_all(&models).unwrap();
        std::fs::create_dir_all(&cache).unwrap();
        let ply = models.join("obj_000001.ply");
        write_box_ply(&ply, [60.0, 40.0, 20.0]);
        let mesh = Mesh::from_ply_file(&ply).unwrap();
        let earlier = ObjectModel::build(&mesh, 1, "earlier", &ModelParams::default()).unwrap();
        store::save(&earlier, &cache.join("obj_000001.ppfm")).unwrap();
        let loaded = load_dir(&PpfEngine::default(), &models, Some(&cache));
        assert_eq!(loaded[0].info.name(), "earlier");
        drop(loaded);
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A picking cell whose mesh is replaced gets a model of the new mesh, whether the model
    /// of the old one lies beside the mesh or in the model cache.
    #[test]
    fn a_replaced_mesh_is_rebuilt_not_matched_with_its_old_model() {
        let (a, b) = ([60.0, 40.0, 20.0], [90.0, 40.0, 20.0]);
        for with_cache in [false, true] {
            let root = scratch(if with_cache { "cache" } else { "beside" });
            let (models, cache) = (root.join("models"), root.join("cache"));
            std::fs::create_dir_all(&models).unwrap();
            let cache = with_cache.then_some(cache.as_path());
            let ply = models.join("obj_000001.ply");
            let e = PpfEngine::default();

            write_box_ply(&ply, a);
            let first = load_dir(&e, &models, cache);
            assert_eq!(first.len(), 1);
            assert!((first[0].info.diameter_mm - diagonal(a)).abs() < 0.01);
            let saved = PpfEngine::cache_path(&ply, cache);
            assert_eq!(
                first[0].source, saved,
                "the built model is saved and read back"
            );
            drop(first);

            // Unchanged mesh: the model built earlier is used, not rebuilt. A copy renamed
            // "earlier" tells the two apart.
            let mesh = Mesh::from_ply_file(&ply).unwrap();
            let earlier = ObjectModel::build(&mesh, 1, "earlier", &ModelParams::default()).unwrap();
            store::save(&earlier, &saved).unwrap();
            let again = load_dir(&e, &models, cache);
            assert_eq!(again[0].info.name(), "earlier");
            drop(again);
            // Accepted by its mesh, it now also records the file's CRC (it had none), so the
            // next start takes it without parsing the mesh.
            let file_crc = store::source_crc(&std::fs::read(&ply).unwrap());
            let recorded = store::load(&saved).unwrap();
            assert_eq!(recorded.name(), "earlier");
            assert_eq!(recorded.source_crc(), file_crc);
            drop(recorded);

            // Another mesh under the same name: rebuilt, and the saved model replaced.
            write_box_ply(&ply, b);
            let replaced = load_dir(&e, &models, cache);
            assert_eq!(replaced.len(), 1, "one model for one mesh");
            assert!(
                (replaced[0].info.diameter_mm - diagonal(b)).abs() < 0.01,
                "diameter {} mm is the old mesh's",
                replaced[0].info.diameter_mm
            );
            assert_eq!(replaced[0].info.name(), "obj_000001");
            let fingerprint = Mesh::from_ply_file(&ply).unwrap().fingerprint();
            let on_disk = store::load(&saved).unwrap();
            assert_eq!(on_disk.mesh_fingerprint(), fingerprint);
            drop((replaced, on_disk));

            // The rebuilt model records the bytes of its file, so the next start need not
            // parse the mesh: a model saved under those bytes' CRC is taken as it is. (Shown
            // with a model of a cube of another name, which only this check can accept: its
            // mesh fingerprint is not the file's.)
            let crc = store::source_crc(&std::fs::read(&ply).unwrap());
            assert_eq!(store::load(&saved).unwrap().source_crc(), crc);
            let cube =
                ppfd_models::synthetic::parts::box_mesh(nalgebra::Vector3::new(30.0, 30.0, 30.0));
            let stand_in = ObjectModel::build(&cube, 1, "by-file", &ModelParams::default())
                .unwrap()
                .with_source_crc(crc)
                .unwrap();
            store::save(&stand_in, &saved).unwrap();
            let by_file = load_dir(&e, &models, cache);
            assert_eq!(by_file[0].info.name(), "by-file");
            drop(by_file);
            // Another CRC (the file changed since): the mesh decides, and rebuilds.
            let stale = ObjectModel::build(&cube, 1, "stale", &ModelParams::default())
                .unwrap()
                .with_source_crc(crc ^ 1)
                .unwrap();
            store::save(&stale, &saved).unwrap();
            let rebuilt = load_dir(&e, &models, cache);
            assert_eq!(rebuilt[0].info.name(), "obj_000001");
            assert!((rebuilt[0].info.diameter_mm - diagonal(b)).abs() < 0.01);
            drop(rebuilt);

            // Asking for the model file beside the mesh by name goes through the mesh too.
            if !with_cache {
                write_box_ply(&ply, a);
                let by_name = e.load(&saved, None, None).unwrap();
                assert!((by_name.info.diameter_mm - diagonal(a)).abs() < 0.01);
            }
            std::fs::remove_dir_all(&root).unwrap();
        }
    }
}
