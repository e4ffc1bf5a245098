//! The production engine: `ppfd_models`' detector over models read from model files or built
//! from PLY meshes.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ppfd_models::detect::detector::{Detector, Hint, RunOptions};
use ppfd_models::detect::diagnosis::diagnose_targets;
use ppfd_models::detect::requirements::{Order, PixelRegion, PoseRestriction, Requirements};
use ppfd_models::geometry::camera::{DepthFrame, Intrinsics};
use ppfd_models::model::store;
use ppfd_models::model::{ModelParams, ObjectModel};
use ppfd_protocol::control::ModelInfo;
use ppfd_protocol::detect::{
    order, DetectCounts, LatencyBreakdown, PoseHint, PoseHypothesis,
    Requirements as WireRequirements, Status,
};
use ppfd_protocol::text;

use crate::engine::{
    DetectionEngine, EngineError, EngineOptions, EngineOutput, FrameView, LoadedModel,
};
use crate::model_cache::{self, MeshSource, ModelFiles};

use ppfd_models::model::store::EXTENSION as MODEL_EXTENSION;

/// Detection with `ppfd_models::detect::detector::Detector`; models are `.ppfm` files (read without
/// decoding) or PLY meshes, built once and saved as `.ppfm` for the next start.
///
/// A model file beside a PLY mesh of the same name, or in the model cache, is that mesh's
/// cache ([`crate::model_cache`]): it is used only while it was built from the same mesh file
/// (its bytes, or failing that the mesh as read, so an ASCII file re-saved as binary keeps its
/// model) with the same parameters and object id; otherwise the model is rebuilt.
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

/// The object id a file name implies: the digits of its stem (`obj_000005.ply` → 5); none when
/// they do not fit a `u32`.
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
        Error::DeadlineExceeded { .. } => Status::DeadlineExceeded,
        // Only a client that is gone has its detection cancelled: the answer goes nowhere.
        Error::Cancelled { .. } => Status::Internal,
        Error::InvalidParameter(_) => Status::InvalidRequest,
        Error::Io { .. }
        | Error::File { .. }
        | Error::Ply { .. }
        | Error::InvalidMesh(_)
        | Error::ModelStore { .. } => Status::ModelError,
    };
    EngineError {
        status,
        message: e.to_string(),
        value: 0,
    }
}

/// A wire hint as the detector's (its rotation checked to be one by the contract,
/// [`PoseHint::problem`]).
fn hint_of(h: &PoseHint) -> Hint {
    Hint {
        object_id: h.object_id,
        pose: h.isometry(),
    }
}

/// The detector's requirements of the wire's, refused as an invalid request where they are
/// out of range.
pub fn detector_requirements(wire: &WireRequirements) -> Result<Requirements, EngineError> {
    let r = &wire.region_of_interest;
    let p = &wire.pose_restriction;
    Ok(Requirements {
        min_score: wire.min_score,
        instance_distance_fraction: (wire.instance_distance_fraction != 0.0)
            .then_some(wire.instance_distance_fraction),
        region: (!r.is_whole_frame()).then_some(PixelRegion {
            x: r.x,
            y: r.y,
            width: r.width,
            height: r.height,
        }),
        pose_restriction: if p.is_unrestricted() {
            None
        } else {
            Some(
                PoseRestriction::new(p.model_axis, p.camera_direction, p.max_angle_deg)
                    .map_err(model_error)?,
            )
        },
        order: if wire.order == order::DISTANCE {
            Order::Distance
        } else {
            Order::Score
        },
    })
}

fn info_of(model: &ObjectModel) -> ModelInfo {
    let symmetry = model.symmetry();
    ModelInfo {
        object_id: model.object_id(),
        point_count: model.point_count() as u32,
        table_entries: model.table_entry_count() as u64,
        byte_size: model.byte_size() as u64,
        diameter_mm: model.diameter_mm(),
        discrete_symmetries: symmetry.discrete.len().min(u16::MAX as usize) as u16,
        continuous_symmetry: symmetry.continuous.is_some() as u16,
        name: text::encode_truncated(model.name()),
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
    /// The model of the mesh file `path`, from the model cache ([`crate::model_cache`]) or built
    /// and saved there (beside the mesh without a cache; the daemon always gives one).
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
                        "{}: no object id: name the file obj_<id>.ply (an id of at most {}) or \
                         give an id",
                        path.display(),
                        u32::MAX
                    ),
                )
            })?;
        if id == 0 {
            // Refused before the model is built (the registry refuses it anyway).
            return Err(crate::registry::object_id_zero(path));
        }
        let files = ModelFiles::of_mesh(path, cache_dir);
        let cached =
            model_cache::load_or_build(MeshSource::File(path), id, &self.model_params, &files)
                .map_err(model_error)?;
        // A model built now warned as it was built; one reused warns at each load, as the log
        // of a daemon's start is where a cell looks.
        if cached.origin != model_cache::Origin::Built {
            if let Some(warning) = ppfd_models::limits::small_diameter(cached.model.diameter_mm()) {
                tracing::warn!(path = %path.display(), "{warning}");
            }
        }
        let source = cached.file.unwrap_or_else(|| path.to_path_buf());
        Ok(loaded(cached.model, &source))
    }
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
        } else if let Some(named) = object_id_of_file(path).filter(|&n| n != model.object_id()) {
            // The id a model file holds is its id; a name that says another is kept from a
            // rename or a copy, and loading it takes an id its name does not show.
            tracing::warn!(
                path = %path.display(),
                object_id = model.object_id(),
                name_says = named,
                "the model file holds another object id than its name's digits: loaded under the one it holds"
            );
        }
        Ok(loaded(model, path))
    }

    fn detect(
        &self,
        frame: &FrameView<'_>,
        models: &[Arc<LoadedModel>],
        options: &EngineOptions,
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
        let opts = RunOptions {
            hypotheses_per_object: options.hypotheses_per_object,
            requirements: detector_requirements(&options.requirements)?,
            deadline: options.deadline,
            cancel: Some(options.cancel.clone()),
            hints: options.hints.iter().map(hint_of).collect(),
        };
        let found = self
            .detector
            .detect(&depth_frame, &object_models, &opts)
            .map_err(model_error)?;
        let diagnosis = if options.diagnose.is_empty() {
            Vec::new()
        } else {
            let targets: Vec<Hint> = options.diagnose.iter().map(hint_of).collect();
            diagnose_targets(
                self.detector.params(),
                &depth_frame,
                &object_models,
                &targets,
                &opts,
                Some(&found),
            )
            .map_err(model_error)?
            .objects
            .iter()
            .flat_map(|d| d.lines())
            .collect()
        };

        let mut hypotheses = Vec::new();
        for object in &found.objects {
            for (rank, h) in object
                .hypotheses
                .iter()
                .take(options.hypotheses_per_object)
                .enumerate()
            {
                let (rotation, translation_mm) = ppfd_protocol::detect::wire_pose(&h.pose);
                hypotheses.push(PoseHypothesis {
                    object_id: object.object_id,
                    instance_rank: rank as u32,
                    rotation,
                    translation_mm,
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
            diagnosis,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The daemon's protocol and the detector, which do not depend on each other, hold the
    /// same limits and constants: a frame or request the protocol lets through is not refused
    /// by the detector for another reason.
    #[test]
    fn the_protocol_and_the_detector_share_their_limits() {
        use ppfd_protocol::frame::Intrinsics as Wire;
        assert_eq!(
            (Wire::MIN_FOCAL_PX, Wire::MAX_FOCAL_PX),
            (Intrinsics::MIN_FOCAL_PX, Intrinsics::MAX_FOCAL_PX)
        );
        let (wire, detector) = (Wire::LMO, Intrinsics::LMO);
        assert_eq!(
            [wire.fx, wire.fy, wire.cx, wire.cy],
            [detector.fx, detector.fy, detector.cx, detector.cy]
        );
        assert_eq!(
            ppfd_protocol::detect::MAX_INSTANCE_DISTANCE_FRACTION,
            ppfd_models::detect::requirements::MAX_INSTANCE_DISTANCE_FRACTION
        );
    }

    /// The model list says how symmetric each object is: a client compares poses of a
    /// symmetric part under its symmetries.
    #[test]
    fn the_model_info_counts_the_symmetries() {
        use ppfd_models::model::ModelParams;
        use ppfd_models::synthetic::parts::SymmetricPart;
        let counts = |part: SymmetricPart| {
            let model = ObjectModel::build(
                &part.mesh(),
                part.object_id(),
                part.name(),
                &ModelParams::default(),
            )
            .unwrap();
            let plain = info_of(&model);
            let symmetry = part.symmetry();
            let info = info_of(&model.with_symmetry(&symmetry).unwrap());
            assert_eq!(
                (plain.discrete_symmetries, plain.continuous_symmetry),
                (0, 0)
            );
            assert_eq!(info.discrete_symmetries as usize, symmetry.discrete.len());
            (info.discrete_symmetries > 0, info.continuous_symmetry)
        };
        // The U-channel's half turn; the shaft's axis.
        assert_eq!(counts(SymmetricPart::UChannel), (true, 0));
        assert_eq!(counts(SymmetricPart::SteppedShaft), (false, 1));
    }

    #[test]
    fn object_ids_come_from_trailing_digits() {
        assert_eq!(object_id_of_file(Path::new("/m/obj_000005.ply")), Some(5));
        assert_eq!(object_id_of_file(Path::new("part12.ppfm")), Some(12));
        assert_eq!(object_id_of_file(Path::new("duck.ply")), None);
        assert_eq!(object_id_of_file(Path::new("obj_4294967296.ply")), None);
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

    /// A mesh's model goes through the model cache and names the file it was read from; a
    /// model file beside a mesh, asked for by name, goes through the mesh, so a picking cell
    /// whose mesh was replaced gets a model of the new mesh.
    #[test]
    fn a_meshs_model_comes_through_the_cache_and_its_file_through_the_mesh() {
        let (a, b) = ([60.0, 40.0, 20.0], [90.0, 40.0, 20.0]);
        let root = scratch("through-mesh");
        let (models, cache) = (root.join("models"), root.join("cache"));
        std::fs::create_dir_all(&models).unwrap();
        let ply = models.join("obj_000001.ply");
        let e = PpfEngine::default();

        write_box_ply(&ply, a);
        let cached = e.load(&ply, None, Some(&cache)).unwrap();
        assert_eq!(cached.source, store::cache_file(&cache, &ply));
        assert_eq!(cached.info.object_id, 1);
        assert!((cached.info.diameter_mm - diagonal(a)).abs() < 0.01);
        drop(cached);

        let beside = ply.with_extension(MODEL_EXTENSION);
        let built = e.load(&ply, None, None).unwrap();
        assert_eq!(
            built.source, beside,
            "without a cache, saved beside the mesh"
        );
        drop(built);
        write_box_ply(&ply, b);
        let by_name = e.load(&beside, None, None).unwrap();
        assert!(
            (by_name.info.diameter_mm - diagonal(b)).abs() < 0.01,
            "diameter {} mm is the old mesh's",
            by_name.info.diameter_mm
        );
        drop(by_name);
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// The loader checks the file it opened, not the path again: a mesh path that is a link to
    /// a device (swapped in after the I/O thread looked at it) is refused, never read.
    #[test]
    fn the_loader_refuses_a_special_file_on_the_handle_it_opened() {
        let root = scratch("special");
        let e = PpfEngine::default();
        let ply = root.join("obj_000001.ply");
        std::os::unix::fs::symlink("/dev/null", &ply).unwrap();
        let err = e.load(&ply, None, Some(&root.join("cache"))).unwrap_err();
        assert_eq!(err.status, Status::ModelError);
        assert!(
            err.message.contains("not a regular file"),
            "{}",
            err.message
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A mesh in metres, and a model file whose diameter is not what its mesh measures, are
    /// refused with the reason.
    #[test]
    fn a_mesh_in_metres_and_a_model_file_with_a_false_diameter_are_refused() {
        let root = scratch("units");
        let e = PpfEngine::default();
        let ply = root.join("obj_000001.ply");
        write_box_ply(&ply, [0.06, 0.04, 0.02]);
        let err = e.load(&ply, None, Some(&root.join("cache"))).unwrap_err();
        assert!(
            err.message.contains("metres") && err.message.contains("--scale 1000"),
            "{}",
            err.message
        );
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A model file whose name's digits say another id than the one it holds loads under the
    /// one it holds, and the log says so.
    #[test]
    fn a_model_file_named_for_another_id_is_loaded_with_a_warning() {
        let root = scratch("renamed");
        let e = PpfEngine::default();
        let ply = root.join("obj_000001.ply");
        write_box_ply(&ply, [60.0, 40.0, 20.0]);
        drop(e.load(&ply, None, None).unwrap());
        let renamed = root.join("obj_000007.ppfm");
        std::fs::rename(ply.with_extension(MODEL_EXTENSION), &renamed).unwrap();
        std::fs::remove_file(&ply).unwrap();
        let mut model = None;
        let log = crate::test_log::capture(|| model = Some(e.load(&renamed, None, None)));
        assert_eq!(model.unwrap().unwrap().info.object_id, 1);
        assert!(
            log.contains("holds another object id than its name") && log.contains("name_says=7"),
            "{log}"
        );
        std::fs::remove_dir_all(&root).unwrap();
    }
}
