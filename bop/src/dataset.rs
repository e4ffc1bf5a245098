//! Reading datasets in the BOP layout (<https://bop.felk.cvut.cz>): object models, their
//! metadata, test scenes with depth images, camera parameters and ground-truth poses.
//!
//! A [`BopDataset`] is opened once on a dataset's root folder; it reads the small dataset-wide
//! files at once (`camera.json`, `models/models_info.json`, `test_targets_bop19.json`) and each
//! scene's JSON files (`scene_camera.json`, `scene_gt.json`, `scene_gt_info.json`) the first
//! time they are asked for, keeping them parsed. Depth images are read on every call.
//!
//! ```text
//! root/
//!   camera.json                  optional: fx, fy, cx, cy, width, height, depth_scale
//!   test_targets_bop19.json      optional
//!   models/obj_000001.ply …      + models_info.json (diameter, bbox, symmetries)
//!   models_eval/obj_000001.ply … optional: BOP's resampled evaluation meshes
//!   test/000002/                 a scene: 6-digit folder in the split folder
//!     scene_camera.json  scene_gt.json  scene_gt_info.json  depth/000003.png
//! ```
//!
//! A folder that is itself one scene (its `scene_camera.json` at the root or in `data/`, as in
//! some single-frame exports) opens as a dataset with the one scene `0`; a lone `*.ply` beside
//! it is then the model of the one object its ground truth names.
//!
//! Units follow BOP: millimetres; `cam_R_m2c` is row-major and, with `cam_t_m2c`, maps model
//! to camera coordinates; depth PNG value × `depth_scale` = millimetres.

use std::collections::BTreeMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nalgebra::{Matrix3, Matrix4, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use serde_json::Value;

use ppfd_models::geometry::camera::{Intrinsics, OwnedDepthFrame};
use ppfd_models::model::symmetry::{Symmetry, SymmetryAxis};
use ppfd_models::Pose;

use crate::{Error, Result};

/// Tolerance on `RᵀR = I` for rotations read from files: LM-O's annotated rotations deviate by
/// up to 0.0094; they are replaced by the nearest rotation.
const ROTATION_TOLERANCE: f64 = 0.05;

/// The dataset-wide camera of `camera.json`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DatasetCamera {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics, pixels.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit.
    pub depth_scale_mm: f32,
}

/// One image's camera, from `scene_camera.json`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneCamera {
    /// Intrinsics from `cam_K` (3×3, row-major), pixels.
    pub intrinsics: Intrinsics,
    /// Millimetres per raw depth unit (`depth_scale`, or `camera.json`'s when absent).
    pub depth_scale_mm: f32,
    /// World-to-camera transform (`cam_R_w2c`, `cam_t_w2c`, mm) where the dataset gives one.
    pub world_to_camera: Option<Pose>,
}

/// One annotated object instance, from `scene_gt.json`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtPose {
    /// The object's id (as in `models/obj_{obj_id:06}.ply`).
    pub obj_id: u32,
    /// Model-to-camera pose, mm (`cam_R_m2c` row-major, `cam_t_m2c`).
    pub pose: Pose,
}

/// Visibility of one annotated instance, from `scene_gt_info.json` (same order as
/// `scene_gt.json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtInfo {
    /// Fraction of the object's projected surface that is visible, 0..1.
    pub visib_fract: f32,
    /// Pixels of the object's silhouette inside the image.
    pub px_count_all: u32,
    /// Of those, pixels with a valid depth measurement.
    pub px_count_valid: u32,
    /// Of those, pixels where the object is visible.
    pub px_count_visib: u32,
    /// Box around the silhouette, `[x, y, width, height]` pixels (−1s when empty).
    pub bbox_obj: [i32; 4],
    /// Box around the visible part, `[x, y, width, height]` pixels (−1s when invisible).
    pub bbox_visib: [i32; 4],
}

/// A continuous rotational symmetry: the model is unchanged by any rotation about `axis`
/// through `offset_mm`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContinuousSymmetry {
    /// Direction of the axis, model coordinates.
    pub axis: Unit<Vector3<f32>>,
    /// A point on the axis, model coordinates, mm.
    pub offset_mm: Point3<f32>,
}

/// An object's metadata, from `models_info.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// Largest distance between two model points, mm.
    pub diameter_mm: f32,
    /// Smallest corner of the model's bounding box, mm.
    pub min_mm: Point3<f32>,
    /// Edge lengths of the bounding box, mm.
    pub size_mm: Vector3<f32>,
    /// Transforms that leave the model's appearance unchanged (model to model, mm); empty for
    /// an object without discrete symmetries.
    pub symmetries_discrete: Vec<Pose>,
    /// Continuous symmetries; empty for most objects.
    pub symmetries_continuous: Vec<ContinuousSymmetry>,
}

impl ModelInfo {
    /// The symmetries as a model holds them (METHOD.md §1.8); refuses more than one continuous
    /// axis (only a sphere has two, and a model supports one).
    pub fn symmetry(&self) -> Result<Symmetry> {
        let continuous = match self.symmetries_continuous.as_slice() {
            [] => None,
            [one] => Some(SymmetryAxis {
                direction: one.axis,
                point_mm: one.offset_mm,
            }),
            more => {
                return Err(Error::InvalidParameter(format!(
                    "{} continuous symmetries, a model supports one",
                    more.len()
                )))
            }
        };
        Ok(Symmetry {
            discrete: self.symmetries_discrete.clone(),
            continuous,
        })
    }
}

/// One entry of `test_targets_bop19.json`: an object to find in an image, and how many times.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TestTarget {
    /// The scene (6-digit folder of the split).
    pub scene_id: u32,
    /// The image within the scene.
    pub im_id: u32,
    /// The object to find.
    pub obj_id: u32,
    /// Number of instances of the object to report.
    pub inst_count: u32,
}

/// One scene folder and its JSON files, parsed on first use.
#[derive(Debug)]
struct Scene {
    dir: PathBuf,
    cameras: OnceLock<BTreeMap<u32, SceneCamera>>,
    gt: OnceLock<BTreeMap<u32, Vec<GtPose>>>,
    gt_info: OnceLock<BTreeMap<u32, Vec<GtInfo>>>,
}

impl Scene {
    fn new(dir: PathBuf) -> Scene {
        Scene {
            dir,
            cameras: OnceLock::new(),
            gt: OnceLock::new(),
            gt_info: OnceLock::new(),
        }
    }
}

/// A dataset in the BOP layout; see the [module documentation](self).
#[derive(Debug)]
pub struct BopDataset {
    root: PathBuf,
    split: Option<String>,
    models_dir: Option<PathBuf>,
    models_eval_dir: Option<PathBuf>,
    /// The model of a single-scene folder, and the one object it belongs to.
    lone_model: Option<(u32, PathBuf)>,
    camera: Option<DatasetCamera>,
    model_infos: BTreeMap<u32, ModelInfo>,
    models_info_path: Option<PathBuf>,
    object_ids: Vec<u32>,
    test_targets: Option<Vec<TestTarget>>,
    scenes: BTreeMap<u32, Scene>,
}

impl BopDataset {
    /// Opens the dataset at `root`, using its `test` split (or, if there is none, the first
    /// `test*` folder, else `val`).
    ///
    /// Reads `camera.json`, `models/models_info.json` (or `models_eval/`'s) and
    /// `test_targets_bop19.json` when present, and refuses malformed ones. A root with neither
    /// a `models/` folder nor any scene is refused.
    pub fn open(root: impl AsRef<Path>) -> Result<BopDataset> {
        Self::open_with_split(root.as_ref(), None)
    }

    /// Opens the dataset at `root` with the scenes of the split folder `split` (e.g. `"val"`,
    /// `"test_primesense"`); the folder must exist.
    pub fn open_split(root: impl AsRef<Path>, split: &str) -> Result<BopDataset> {
        Self::open_with_split(root.as_ref(), Some(split))
    }

    fn open_with_split(root: &Path, split: Option<&str>) -> Result<BopDataset> {
        if !root.is_dir() {
            return Err(dataset_error(
                root,
                "not a directory (expected a BOP dataset root)",
            ));
        }
        let root = root.to_path_buf();
        let models_dir = Some(root.join("models")).filter(|p| p.is_dir());
        let models_eval_dir = Some(root.join("models_eval")).filter(|p| p.is_dir());

        let camera = match existing(root.join("camera.json")) {
            Some(path) => Some(parse_file(&path, parse_dataset_camera)?),
            None => None,
        };
        let models_info_path = [&models_dir, &models_eval_dir]
            .into_iter()
            .flatten()
            .map(|dir| dir.join("models_info.json"))
            .find(|p| p.is_file());
        let model_infos = match &models_info_path {
            Some(path) => parse_file(path, parse_models_info)?,
            None => BTreeMap::new(),
        };
        let test_targets = match existing(root.join("test_targets_bop19.json")) {
            Some(path) => Some(parse_file(&path, parse_test_targets)?),
            None => None,
        };

        let single_scene_dir = match split {
            Some(_) => None,
            None => [root.clone(), root.join("data")]
                .into_iter()
                .find(|dir| dir.join("scene_camera.json").is_file()),
        };
        let (split, scenes, lone_model) = match single_scene_dir {
            Some(dir) => {
                let lone_model = lone_model(&dir)?;
                let relative = dir
                    .strip_prefix(&root)
                    .unwrap_or(&dir)
                    .display()
                    .to_string();
                (
                    Some(relative),
                    BTreeMap::from([(0, Scene::new(dir))]),
                    lone_model,
                )
            }
            None => {
                let split = match split {
                    Some(name) => {
                        if !root.join(name).is_dir() {
                            return Err(dataset_error(
                                &root.join(name),
                                format!("split folder '{name}' is missing"),
                            ));
                        }
                        Some(name.to_string())
                    }
                    None => default_split(&root)?,
                };
                let scenes = match &split {
                    Some(name) => list_scenes(&root.join(name))?,
                    None => BTreeMap::new(),
                };
                (split, scenes, None)
            }
        };
        if models_dir.is_none() && scenes.is_empty() {
            return Err(dataset_error(
                &root,
                "no 'models' folder and no scenes: expected a BOP dataset root",
            ));
        }

        let object_ids = if !model_infos.is_empty() {
            model_infos.keys().copied().collect()
        } else if let Some(dir) = &models_dir {
            model_ids_in(dir)?
        } else {
            lone_model.iter().map(|(id, _)| *id).collect()
        };

        Ok(BopDataset {
            root,
            split,
            models_dir,
            models_eval_dir,
            lone_model,
            camera,
            model_infos,
            models_info_path,
            object_ids,
            test_targets,
            scenes,
        })
    }

    /// The dataset's root folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The folder (relative to the root) whose scenes this dataset serves, if any.
    pub fn split(&self) -> Option<&str> {
        self.split.as_deref()
    }

    /// The dataset-wide camera of `camera.json`, when the dataset has one.
    pub fn camera(&self) -> Option<&DatasetCamera> {
        self.camera.as_ref()
    }

    /// Ids of the objects with a model: the keys of `models_info.json`, else the
    /// `obj_XXXXXX.ply` files of `models/`; ascending.
    pub fn object_ids(&self) -> &[u32] {
        &self.object_ids
    }

    /// Path of an object's model (`models/obj_{obj_id:06}.ply`); an error when it is missing.
    pub fn model_path(&self, obj_id: u32) -> Result<PathBuf> {
        if let Some((id, path)) = &self.lone_model {
            if *id == obj_id {
                return Ok(path.clone());
            }
        }
        self.model_file(self.models_dir.as_deref(), "models", obj_id)
    }

    /// Path of an object's evaluation model (`models_eval/obj_{obj_id:06}.ply`), the mesh
    /// BOP's error functions use; an error when it is missing.
    pub fn eval_model_path(&self, obj_id: u32) -> Result<PathBuf> {
        self.model_file(self.models_eval_dir.as_deref(), "models_eval", obj_id)
    }

    fn model_file(&self, dir: Option<&Path>, folder: &str, obj_id: u32) -> Result<PathBuf> {
        let path = self.root.join(folder).join(format!("obj_{obj_id:06}.ply"));
        match dir {
            Some(_) if path.is_file() => Ok(path),
            Some(_) => Err(dataset_error(
                &path,
                format!("no model file for object {obj_id}"),
            )),
            None => Err(dataset_error(
                &self.root.join(folder),
                format!("no '{folder}' folder, so no model for object {obj_id}"),
            )),
        }
    }

    /// Metadata of one object from `models_info.json`.
    pub fn model_info(&self, obj_id: u32) -> Result<&ModelInfo> {
        match (&self.models_info_path, self.model_infos.get(&obj_id)) {
            (_, Some(info)) => Ok(info),
            (Some(path), None) => Err(dataset_error(path, format!("no entry for object {obj_id}"))),
            (None, None) => Err(dataset_error(
                &self.root.join("models").join("models_info.json"),
                "missing, so there is no model info",
            )),
        }
    }

    /// The symmetries `models_info.json` gives object `obj_id` ([`ModelInfo::symmetry`]); none
    /// when the dataset has no `models_info.json` or it has no entry for the object.
    pub fn symmetry(&self, obj_id: u32) -> Result<Symmetry> {
        match (&self.models_info_path, self.model_infos.get(&obj_id)) {
            (Some(path), Some(info)) => info
                .symmetry()
                .map_err(|e| dataset_error(path, format!("object {obj_id}: {e}"))),
            _ => Ok(Symmetry::default()),
        }
    }

    /// The entries of `test_targets_bop19.json`, or `None` when the dataset has no such file.
    pub fn test_targets(&self) -> Option<&[TestTarget]> {
        self.test_targets.as_deref()
    }

    /// Ids of the scenes in the split, ascending.
    pub fn scene_ids(&self) -> Vec<u32> {
        self.scenes.keys().copied().collect()
    }

    /// Ids of a scene's images (the keys of its `scene_camera.json`), ascending. Not every
    /// image need have its depth file: see [`BopDataset::has_depth`].
    pub fn image_ids(&self, scene_id: u32) -> Result<Vec<u32>> {
        Ok(self.scene_cameras(scene_id)?.keys().copied().collect())
    }

    /// One image's camera.
    pub fn scene_camera(&self, scene_id: u32, im_id: u32) -> Result<SceneCamera> {
        let cameras = self.scene_cameras(scene_id)?;
        cameras.get(&im_id).copied().ok_or_else(|| {
            let path = self
                .scene(scene_id)
                .map(|s| s.dir.join("scene_camera.json"));
            dataset_error(&path.unwrap_or_default(), format!("no image {im_id}"))
        })
    }

    /// The annotated object instances of one image.
    pub fn ground_truth(&self, scene_id: u32, im_id: u32) -> Result<&[GtPose]> {
        let scene = self.scene(scene_id)?;
        let path = scene.dir.join("scene_gt.json");
        let all = cached(&scene.gt, || parse_file(&path, parse_scene_gt))?;
        all.get(&im_id)
            .map(Vec::as_slice)
            .ok_or_else(|| dataset_error(&path, format!("no image {im_id}")))
    }

    /// Whether a scene has its `scene_gt_info.json` (BOP's `calc_gt_info` writes it; a
    /// dataset of one's own may have `scene_gt.json` alone).
    pub fn has_ground_truth_info(&self, scene_id: u32) -> bool {
        self.scene(scene_id)
            .is_ok_and(|s| s.dir.join("scene_gt_info.json").is_file())
    }

    /// Whether the dataset has a `models_info.json`.
    pub fn has_models_info(&self) -> bool {
        self.models_info_path.is_some()
    }

    /// The `models_info.json` read, when there is one.
    pub fn models_info_path(&self) -> Option<&Path> {
        self.models_info_path.as_deref()
    }

    /// The visibility of one image's annotated instances, in the order of
    /// [`BopDataset::ground_truth`].
    pub fn ground_truth_info(&self, scene_id: u32, im_id: u32) -> Result<&[GtInfo]> {
        let scene = self.scene(scene_id)?;
        let path = scene.dir.join("scene_gt_info.json");
        let all = cached(&scene.gt_info, || parse_file(&path, parse_scene_gt_info))?;
        all.get(&im_id)
            .map(Vec::as_slice)
            .ok_or_else(|| dataset_error(&path, format!("no image {im_id}")))
    }

    /// Path of one image's depth PNG (`depth/{im_id:06}.png` in the scene folder), whether or
    /// not it exists.
    pub fn depth_path(&self, scene_id: u32, im_id: u32) -> Result<PathBuf> {
        Ok(self
            .scene(scene_id)?
            .dir
            .join("depth")
            .join(format!("{im_id:06}.png")))
    }

    /// Path of one image's colour PNG (`rgb/{im_id:06}.png` in the scene folder), when it
    /// exists (BOP datasets may hold JPEG colour images instead, or none).
    pub fn colour_path(&self, scene_id: u32, im_id: u32) -> Option<PathBuf> {
        let path = self
            .scene(scene_id)
            .ok()?
            .dir
            .join("rgb")
            .join(format!("{im_id:06}.png"));
        path.is_file().then_some(path)
    }

    /// Whether one image's depth PNG exists.
    pub fn has_depth(&self, scene_id: u32, im_id: u32) -> bool {
        self.depth_path(scene_id, im_id).is_ok_and(|p| p.is_file())
    }

    /// One image's depth frame: the 16-bit PNG with the image's intrinsics and depth scale.
    /// A PNG of another size than `camera.json` gives is refused.
    pub fn depth_frame(&self, scene_id: u32, im_id: u32) -> Result<OwnedDepthFrame> {
        let camera = self.scene_camera(scene_id, im_id)?;
        let path = self.depth_path(scene_id, im_id)?;
        let (width, height, depth) = read_depth_png(&path)?;
        self.check_depth_size(&path, width, height)?;
        let frame = OwnedDepthFrame {
            width,
            height,
            intrinsics: camera.intrinsics,
            depth_scale_mm: camera.depth_scale_mm,
            depth,
        };
        frame
            .view()
            .validate()
            .map_err(|e| dataset_error(&path, e.to_string()))?;
        Ok(frame)
    }

    /// Refuses a depth image whose size is not the one `camera.json` gives (when it has one).
    fn check_depth_size(&self, path: &Path, width: u32, height: u32) -> Result<()> {
        match self.camera {
            Some(c) if (c.width, c.height) != (width, height) => Err(dataset_error(
                path,
                format!(
                    "depth image is {width}x{height}, camera.json gives {}x{}",
                    c.width, c.height
                ),
            )),
            _ => Ok(()),
        }
    }

    /// The ground truth of one image, or `None` when the scene has no `scene_gt.json` (a test
    /// split without annotations). A file that is there but malformed, or that does not list
    /// the image, is an error: a pose would otherwise be judged against no truth.
    pub fn ground_truth_if_any(&self, scene_id: u32, im_id: u32) -> Result<Option<&[GtPose]>> {
        if !self.scene(scene_id)?.dir.join("scene_gt.json").exists() {
            return Ok(None);
        }
        self.ground_truth(scene_id, im_id).map(Some)
    }

    /// Checks what a detection on one image will read, without decoding its depth: its camera,
    /// its ground truth when the scene has one, and its depth PNG's header (present, a PNG, the
    /// size `camera.json` gives). Commands run it over every image before any work starts, so
    /// that a broken file is reported at once rather than after hours of detections.
    pub fn check_image(&self, scene_id: u32, im_id: u32) -> Result<()> {
        self.scene_camera(scene_id, im_id)?;
        self.ground_truth_if_any(scene_id, im_id)?;
        let path = self.depth_path(scene_id, im_id)?;
        let (width, height) = depth_png_size(&path)?;
        self.check_depth_size(&path, width, height)
    }

    fn scene(&self, scene_id: u32) -> Result<&Scene> {
        self.scenes.get(&scene_id).ok_or_else(|| {
            let split = self.split.as_deref().unwrap_or("");
            dataset_error(
                &self.root.join(split),
                format!("no scene {scene_id} (scenes: {:?})", self.scene_ids()),
            )
        })
    }

    fn scene_cameras(&self, scene_id: u32) -> Result<&BTreeMap<u32, SceneCamera>> {
        let scene = self.scene(scene_id)?;
        let path = scene.dir.join("scene_camera.json");
        let fallback_scale = self.camera.map(|c| c.depth_scale_mm);
        cached(&scene.cameras, || {
            parse_file(&path, |v| parse_scene_camera(v, fallback_scale))
        })
    }
}

/// The value in `cell`, loading it first if needed. Two threads may both load; one result is
/// kept, and both are the same file's content.
fn cached<T>(cell: &OnceLock<T>, load: impl FnOnce() -> Result<T>) -> Result<&T> {
    if let Some(value) = cell.get() {
        return Ok(value);
    }
    let value = load()?;
    Ok(cell.get_or_init(|| value))
}

fn dataset_error(path: &Path, reason: impl Into<String>) -> Error {
    Error::Dataset {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn existing(path: PathBuf) -> Option<PathBuf> {
    path.is_file().then_some(path)
}

/// `test`, else the first `test*` folder, else `val`; `None` when the root has none of them.
fn default_split(root: &Path) -> Result<Option<String>> {
    if root.join("test").is_dir() {
        return Ok(Some("test".into()));
    }
    let mut names: Vec<String> = read_dir_names(root)?
        .into_iter()
        .filter(|name| name.starts_with("test") && root.join(name).is_dir())
        .collect();
    names.sort();
    if let Some(first) = names.into_iter().next() {
        return Ok(Some(first));
    }
    Ok(root.join("val").is_dir().then(|| "val".to_string()))
}

fn read_dir_names(dir: &Path) -> Result<Vec<String>> {
    let entries = std::fs::read_dir(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        if let Some(name) = entry.file_name().to_str() {
            names.push(name.to_string());
        }
    }
    Ok(names)
}

/// The 6-digit scene folders of a split folder.
fn list_scenes(split_dir: &Path) -> Result<BTreeMap<u32, Scene>> {
    let mut scenes = BTreeMap::new();
    for name in read_dir_names(split_dir)? {
        let is_scene = name.len() == 6 && name.bytes().all(|b| b.is_ascii_digit());
        let dir = split_dir.join(&name);
        if is_scene && dir.is_dir() {
            scenes.insert(
                name.parse().expect("six ASCII digits fit in u32"),
                Scene::new(dir),
            );
        }
    }
    Ok(scenes)
}

/// The object id of a mesh file named as BOP names them (`obj_000005.ply`: 5).
pub fn object_id_of_mesh(file_name: &str) -> Option<u32> {
    file_name
        .strip_prefix("obj_")?
        .strip_suffix(".ply")?
        .parse()
        .ok()
}

/// The ids of `obj_XXXXXX.ply` files in a models folder, ascending.
fn model_ids_in(dir: &Path) -> Result<Vec<u32>> {
    let mut ids: Vec<u32> = read_dir_names(dir)?
        .iter()
        .filter_map(|name| object_id_of_mesh(name))
        .collect();
    ids.sort_unstable();
    Ok(ids)
}

/// In a single-scene folder: the one `*.ply` beside the scene files, paired with the one object
/// id of its ground truth; `None` unless both are unambiguous.
fn lone_model(scene_dir: &Path) -> Result<Option<(u32, PathBuf)>> {
    let plys: Vec<String> = read_dir_names(scene_dir)?
        .into_iter()
        .filter(|name| name.to_ascii_lowercase().ends_with(".ply"))
        .collect();
    let gt_path = scene_dir.join("scene_gt.json");
    if plys.len() != 1 || !gt_path.is_file() {
        return Ok(None);
    }
    let gt = parse_file(&gt_path, parse_scene_gt)?;
    let mut ids: Vec<u32> = gt.values().flatten().map(|g| g.obj_id).collect();
    ids.sort_unstable();
    ids.dedup();
    Ok(match ids.as_slice() {
        [id] => Some((*id, scene_dir.join(&plys[0]))),
        _ => None,
    })
}

/// The largest JSON file of a dataset read: the largest `scene_gt.json` of the BOP datasets
/// is a few megabytes.
pub const JSON_FILE: ppfd_models::file::Limit = ppfd_models::file::Limit {
    what: "dataset JSON file",
    max_bytes: 256 << 20,
    raise: "raise ppfd_bop::dataset::JSON_FILE and rebuild",
};

/// Reads and parses one JSON file, then turns it into `T`; any failure names the file.
fn parse_file<T>(
    path: &Path,
    parse: impl FnOnce(&Value) -> std::result::Result<T, String>,
) -> Result<T> {
    let text = ppfd_models::file::read_text_bounded(path, &JSON_FILE).map_err(|e| match e {
        ppfd_models::Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            dataset_error(path, "file is missing")
        }
        ppfd_models::Error::Io { source, .. } => {
            dataset_error(path, format!("cannot be read: {source}"))
        }
        other => other.into(),
    })?;
    let value: Value = serde_json::from_str(&text)
        .map_err(|e| dataset_error(path, format!("not valid JSON: {e}")))?;
    parse(&value).map_err(|reason| dataset_error(path, reason))
}

// Field access with messages that say where: `at` is a prefix such as "image 3, entry 0: ".

fn field<'v>(object: &'v Value, key: &str, at: &str) -> std::result::Result<&'v Value, String> {
    match object {
        Value::Object(map) => map
            .get(key)
            .ok_or_else(|| format!("{at}'{key}' is missing")),
        _ => Err(format!(
            "{at}expected an object with '{key}', found {}",
            kind(object)
        )),
    }
}

fn number(object: &Value, key: &str, at: &str) -> std::result::Result<f64, String> {
    let value = field(object, key, at)?;
    value
        .as_f64()
        .ok_or_else(|| format!("{at}{key} is {}, expected a number", kind(value)))
}

fn unsigned(object: &Value, key: &str, at: &str) -> std::result::Result<u32, String> {
    let value = field(object, key, at)?;
    value
        .as_u64()
        .and_then(|v| u32::try_from(v).ok())
        .ok_or_else(|| format!("{at}{key} is {value}, expected a non-negative integer"))
}

fn numbers(
    object: &Value,
    key: &str,
    expected: usize,
    at: &str,
) -> std::result::Result<Vec<f64>, String> {
    number_list(field(object, key, at)?, key, expected, at)
}

/// `value` as a list of exactly `expected` finite numbers; `label` names it in messages.
fn number_list(
    value: &Value,
    label: &str,
    expected: usize,
    at: &str,
) -> std::result::Result<Vec<f64>, String> {
    let Value::Array(items) = value else {
        return Err(format!(
            "{at}{label} is {}, expected {expected} numbers",
            kind(value)
        ));
    };
    if items.len() != expected {
        return Err(format!(
            "{at}{label} has {} numbers, expected {expected}",
            items.len()
        ));
    }
    items
        .iter()
        .enumerate()
        .map(|(i, item)| {
            item.as_f64()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("{at}{label}[{i}] is {item}, expected a finite number"))
        })
        .collect()
}

fn kind(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "an object",
    }
}

/// The entries of a top-level object keyed by decimal ids ("3": …).
fn by_id<'v>(root: &'v Value, what: &str) -> std::result::Result<BTreeMap<u32, &'v Value>, String> {
    let Value::Object(map) = root else {
        return Err(format!(
            "expected an object keyed by {what} id, found {}",
            kind(root)
        ));
    };
    map.iter()
        .map(|(key, value)| {
            key.parse::<u32>()
                .map(|id| (id, value))
                .map_err(|_| format!("key \"{key}\" is not a {what} id"))
        })
        .collect()
}

/// The rotation nearest to `m`; refuses a matrix that is not close to a rotation.
pub(crate) fn rotation(
    m: Matrix3<f64>,
    key: &str,
    at: &str,
) -> std::result::Result<UnitQuaternion<f32>, String> {
    let error = (m.transpose() * m - Matrix3::identity()).abs().max();
    if !(error < ROTATION_TOLERANCE && m.determinant() > 0.0) {
        return Err(format!(
            "{at}{key} is not a rotation (|RᵀR − I| = {error:.2e}, det = {:.4})",
            m.determinant()
        ));
    }
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let nearest = nalgebra::Rotation3::from_matrix_unchecked(u * v_t);
    Ok(UnitQuaternion::from_rotation_matrix(&nearest).cast::<f32>())
}

fn pose(
    object: &Value,
    rotation_key: &str,
    translation_key: &str,
    at: &str,
) -> std::result::Result<Pose, String> {
    let r = Matrix3::from_row_slice(&numbers(object, rotation_key, 9, at)?);
    let r = rotation(r, rotation_key, at)?;
    let t = numbers(object, translation_key, 3, at)?;
    Ok(Pose::from_parts(
        Translation3::new(t[0] as f32, t[1] as f32, t[2] as f32),
        r,
    ))
}

fn intrinsics(
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    at: &str,
) -> std::result::Result<Intrinsics, String> {
    let intrinsics = Intrinsics {
        fx: fx as f32,
        fy: fy as f32,
        cx: cx as f32,
        cy: cy as f32,
    };
    intrinsics.validate().map_err(|e| format!("{at}{e}"))?;
    Ok(intrinsics)
}

fn depth_scale(value: f64, at: &str) -> std::result::Result<f32, String> {
    if value.is_finite() && value > 0.0 {
        Ok(value as f32)
    } else {
        Err(format!(
            "{at}depth_scale is {value}, expected a positive number"
        ))
    }
}

fn parse_dataset_camera(root: &Value) -> std::result::Result<DatasetCamera, String> {
    let size = |key: &str| {
        unsigned(root, key, "").and_then(|v| {
            if v > 0 {
                Ok(v)
            } else {
                Err(format!("{key} is 0, expected a positive size"))
            }
        })
    };
    Ok(DatasetCamera {
        width: size("width")?,
        height: size("height")?,
        intrinsics: intrinsics(
            number(root, "fx", "")?,
            number(root, "fy", "")?,
            number(root, "cx", "")?,
            number(root, "cy", "")?,
            "",
        )?,
        depth_scale_mm: depth_scale(number(root, "depth_scale", "")?, "")?,
    })
}

fn parse_scene_camera(
    root: &Value,
    fallback_scale: Option<f32>,
) -> std::result::Result<BTreeMap<u32, SceneCamera>, String> {
    let mut cameras = BTreeMap::new();
    for (im_id, entry) in by_id(root, "image")? {
        let at = format!("image {im_id}: ");
        let k = numbers(entry, "cam_K", 9, &at)?;
        // Row-major [fx s cx; 0 fy cy; 0 0 1]: anything else is not a pinhole without skew.
        let skew_free = k[1].abs() <= 1e-6 * k[0].abs();
        if !(skew_free && k[3] == 0.0 && k[6] == 0.0 && k[7] == 0.0 && k[8] == 1.0) {
            return Err(format!(
                "{at}cam_K {k:?} is not [fx 0 cx, 0 fy cy, 0 0 1] (row-major, no skew)"
            ));
        }
        let depth_scale_mm = match entry.get("depth_scale") {
            Some(_) => depth_scale(number(entry, "depth_scale", &at)?, &at)?,
            None => fallback_scale.ok_or_else(|| {
                format!("{at}'depth_scale' is missing and there is no camera.json to take it from")
            })?,
        };
        let world_to_camera = match entry.get("cam_R_w2c") {
            Some(_) => Some(pose(entry, "cam_R_w2c", "cam_t_w2c", &at)?),
            None => None,
        };
        cameras.insert(
            im_id,
            SceneCamera {
                intrinsics: intrinsics(k[0], k[4], k[2], k[5], &at)?,
                depth_scale_mm,
                world_to_camera,
            },
        );
    }
    Ok(cameras)
}

/// The list of one image's entries in `scene_gt.json` / `scene_gt_info.json`.
fn entries(value: &Value, im_id: u32) -> std::result::Result<&[Value], String> {
    match value {
        Value::Array(items) => Ok(items),
        other => Err(format!(
            "image {im_id}: expected a list of objects, found {}",
            kind(other)
        )),
    }
}

fn parse_scene_gt(root: &Value) -> std::result::Result<BTreeMap<u32, Vec<GtPose>>, String> {
    let mut gt = BTreeMap::new();
    for (im_id, value) in by_id(root, "image")? {
        let mut poses = Vec::new();
        for (i, entry) in entries(value, im_id)?.iter().enumerate() {
            let at = format!("image {im_id}, entry {i}: ");
            poses.push(GtPose {
                obj_id: unsigned(entry, "obj_id", &at)?,
                pose: pose(entry, "cam_R_m2c", "cam_t_m2c", &at)?,
            });
        }
        gt.insert(im_id, poses);
    }
    Ok(gt)
}

fn parse_scene_gt_info(root: &Value) -> std::result::Result<BTreeMap<u32, Vec<GtInfo>>, String> {
    let bbox = |entry: &Value, key: &str, at: &str| -> std::result::Result<[i32; 4], String> {
        let v = numbers(entry, key, 4, at)?;
        let mut out = [0i32; 4];
        for (o, x) in out.iter_mut().zip(&v) {
            if x.fract() != 0.0 || x.abs() > i32::MAX as f64 {
                return Err(format!(
                    "{at}{key} holds {x}, expected integer pixel coordinates"
                ));
            }
            *o = *x as i32;
        }
        Ok(out)
    };
    let mut info = BTreeMap::new();
    for (im_id, value) in by_id(root, "image")? {
        let mut list = Vec::new();
        for (i, entry) in entries(value, im_id)?.iter().enumerate() {
            let at = format!("image {im_id}, entry {i}: ");
            let visib_fract = number(entry, "visib_fract", &at)?;
            if !(0.0..=1.0).contains(&visib_fract) {
                return Err(format!("{at}visib_fract is {visib_fract}, expected 0..1"));
            }
            list.push(GtInfo {
                visib_fract: visib_fract as f32,
                px_count_all: unsigned(entry, "px_count_all", &at)?,
                px_count_valid: unsigned(entry, "px_count_valid", &at)?,
                px_count_visib: unsigned(entry, "px_count_visib", &at)?,
                bbox_obj: bbox(entry, "bbox_obj", &at)?,
                bbox_visib: bbox(entry, "bbox_visib", &at)?,
            });
        }
        info.insert(im_id, list);
    }
    Ok(info)
}

fn parse_models_info(root: &Value) -> std::result::Result<BTreeMap<u32, ModelInfo>, String> {
    let mut infos = BTreeMap::new();
    for (obj_id, entry) in by_id(root, "object")? {
        let at = format!("object {obj_id}: ");
        let diameter = number(entry, "diameter", &at)?;
        if !(diameter.is_finite() && diameter > 0.0) {
            return Err(format!(
                "{at}diameter is {diameter}, expected a positive length"
            ));
        }
        let get = |key: &str| number(entry, key, &at).map(|v| v as f32);
        let mut symmetries_discrete = Vec::new();
        if let Some(list) = entry.get("symmetries_discrete") {
            let Value::Array(items) = list else {
                return Err(format!(
                    "{at}symmetries_discrete is {}, expected a list",
                    kind(list)
                ));
            };
            for (i, item) in items.iter().enumerate() {
                let key = format!("symmetries_discrete[{i}]");
                let m = Matrix4::from_row_slice(&number_list(item, &key, 16, &at)?);
                if (m.row(3) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0))
                    .abs()
                    .max()
                    > 1e-9
                {
                    return Err(format!("{at}{key}: the last row is not 0 0 0 1"));
                }
                let r = rotation(m.fixed_view::<3, 3>(0, 0).into_owned(), &key, &at)?;
                let t: Vector3<f32> = m.fixed_view::<3, 1>(0, 3).into_owned().cast();
                symmetries_discrete.push(Pose::from_parts(Translation3::from(t), r));
            }
        }
        let mut symmetries_continuous = Vec::new();
        if let Some(list) = entry.get("symmetries_continuous") {
            let Value::Array(items) = list else {
                return Err(format!(
                    "{at}symmetries_continuous is {}, expected a list",
                    kind(list)
                ));
            };
            for (i, item) in items.iter().enumerate() {
                let at = format!("{at}symmetries_continuous[{i}]: ");
                let axis = numbers(item, "axis", 3, &at)?;
                let offset = numbers(item, "offset", 3, &at)?;
                let axis = Vector3::new(axis[0], axis[1], axis[2]).cast::<f32>();
                let axis =
                    Unit::try_new(axis, 1e-6).ok_or_else(|| format!("{at}axis has zero length"))?;
                symmetries_continuous.push(ContinuousSymmetry {
                    axis,
                    offset_mm: Point3::new(offset[0], offset[1], offset[2]).cast::<f32>(),
                });
            }
        }
        infos.insert(
            obj_id,
            ModelInfo {
                diameter_mm: diameter as f32,
                min_mm: Point3::new(get("min_x")?, get("min_y")?, get("min_z")?),
                size_mm: Vector3::new(get("size_x")?, get("size_y")?, get("size_z")?),
                symmetries_discrete,
                symmetries_continuous,
            },
        );
    }
    Ok(infos)
}

fn parse_test_targets(root: &Value) -> std::result::Result<Vec<TestTarget>, String> {
    let Value::Array(items) = root else {
        return Err(format!("expected a list of targets, found {}", kind(root)));
    };
    items
        .iter()
        .enumerate()
        .map(|(i, item)| {
            let at = format!("target {i}: ");
            Ok(TestTarget {
                scene_id: unsigned(item, "scene_id", &at)?,
                im_id: unsigned(item, "im_id", &at)?,
                obj_id: unsigned(item, "obj_id", &at)?,
                inst_count: unsigned(item, "inst_count", &at)?,
            })
        })
        .collect()
}

/// Reads a test-target file in the layout of `test_targets_bop19.json` (a list of `scene_id`,
/// `im_id`, `obj_id`, `inst_count`); errors name the file and the entry.
pub fn read_test_targets(path: impl AsRef<Path>) -> Result<Vec<TestTarget>> {
    parse_file(path.as_ref(), parse_test_targets)
}

/// Reads a `models_info.json` (diameters, bounding boxes and symmetries by object id); errors
/// name the file and the entry.
pub fn read_models_info(path: impl AsRef<Path>) -> Result<BTreeMap<u32, ModelInfo>> {
    parse_file(path.as_ref(), parse_models_info)
}

/// The symmetries the `models_info.json` beside the mesh file `mesh` gives object `obj_id`
/// ([`ModelInfo::symmetry`]), with that file's path: `None` when there is no such file or it
/// has no entry for the object. The rule `ppf model build`, the daemon and the offline commands
/// share for a mesh's model (METHOD.md §1.8); errors name the file and the object.
pub fn symmetry_beside(mesh: &Path, obj_id: u32) -> Result<Option<(Symmetry, PathBuf)>> {
    let Some(info) = mesh
        .parent()
        .map(|dir| dir.join("models_info.json"))
        .filter(|p| p.is_file())
    else {
        return Ok(None);
    };
    let Some(entry) = read_models_info(&info)?.remove(&obj_id) else {
        return Ok(None);
    };
    let symmetry = entry
        .symmetry()
        .map_err(|e| dataset_error(&info, format!("object {obj_id}: {e}")))?;
    Ok(Some((symmetry, info)))
}

/// Opens a depth PNG, checked on the open file (a regular file).
fn open_depth_png(path: &Path) -> Result<std::fs::File> {
    ppfd_models::file::open_regular(path)
        .map(|(file, _)| file)
        .map_err(|e| match e {
            ppfd_models::Error::Io { source, .. }
                if source.kind() == std::io::ErrorKind::NotFound =>
            {
                dataset_error(path, "depth image is missing")
            }
            ppfd_models::Error::Io { source, .. } => {
                dataset_error(path, format!("cannot be read: {source}"))
            }
            other => other.into(),
        })
}

/// The most pixels a depth image may have: 4096 × 4096, the daemon's default frame limit
/// (`ppfd --max-frame-pixels`). No depth sensor comes near it, and a larger image would take
/// gigabytes to prepare before any error could be said.
pub const MAX_DEPTH_PIXELS: u64 = 4096 * 4096;

/// Refuses a depth PNG whose header gives another format than 16-bit grayscale, or more than
/// [`MAX_DEPTH_PIXELS`]: said from the header, before anything is decoded.
fn check_depth_header(path: &Path, info: &png::Info<'_>) -> Result<()> {
    let (color, bit_depth) = (info.color_type, info.bit_depth);
    if color != png::ColorType::Grayscale || bit_depth != png::BitDepth::Sixteen {
        return Err(dataset_error(
            path,
            format!("depth PNG is {color:?} {bit_depth:?}, expected 16-bit grayscale"),
        ));
    }
    let pixels = u64::from(info.width) * u64::from(info.height);
    if pixels > MAX_DEPTH_PIXELS {
        return Err(dataset_error(
            path,
            format!(
                "depth PNG is {}x{}, {pixels} pixels, more than the {MAX_DEPTH_PIXELS} \
                 (4096x4096) a frame may have",
                info.width, info.height
            ),
        ));
    }
    Ok(())
}

/// The width and height a depth PNG's header gives, without decoding it; its format and size
/// checked ([`check_depth_header`]).
fn depth_png_size(path: &Path) -> Result<(u32, u32)> {
    let file = open_depth_png(path)?;
    let info = png::Decoder::new(BufReader::new(file))
        .read_info()
        .map_err(|e| dataset_error(path, format!("not a readable PNG: {e}")))?;
    let info = info.info();
    check_depth_header(path, info)?;
    Ok((info.width, info.height))
}

/// Reads a 16-bit grayscale PNG into row-major samples. PNG stores 16-bit samples big-endian,
/// and the decoder (with no transformations) hands them over as stored.
fn read_depth_png(path: &Path) -> Result<(u32, u32, Vec<u16>)> {
    let file = open_depth_png(path)?;
    let bad = |e: png::DecodingError| dataset_error(path, format!("not a readable PNG: {e}"));
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(bad)?;
    // With no transformations, the output is as the header says.
    check_depth_header(path, reader.info())?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| dataset_error(path, "PNG too large"))?;
    let mut bytes = vec![0u8; size];
    let info = reader.next_frame(&mut bytes).map_err(bad)?;
    bytes.truncate(info.buffer_size());
    let expected = info.width as usize * info.height as usize * 2;
    if bytes.len() != expected {
        return Err(dataset_error(
            path,
            format!(
                "depth PNG {}x{} decoded to {} bytes, expected {expected}",
                info.width,
                info.height,
                bytes.len()
            ),
        ));
    }
    let depth = bytes
        .chunks_exact(2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .collect();
    Ok((info.width, info.height, depth))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ppfd_models::geometry::mesh::Mesh;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A folder under the system temp dir, removed when dropped.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(tag: &str) -> TempDir {
            static COUNTER: AtomicUsize = AtomicUsize::new(0);
            let n = COUNTER.fetch_add(1, Ordering::Relaxed);
            let dir =
                std::env::temp_dir().join(format!("ppfd-bop-{tag}-{}-{n}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            TempDir(dir)
        }

        fn write(&self, relative: &str, content: &str) {
            let path = self.0.join(relative);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, content).unwrap();
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    fn write_png(path: &Path, width: u32, height: u32, depth: png::BitDepth, bytes: &[u8]) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut encoder = png::Encoder::new(file, width, height);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(depth);
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(bytes).unwrap();
    }

    const TINY_DEPTH: [u16; 12] = [0, 1, 0x1234, 0xABCD, 800, 801, 802, 803, 65535, 0, 7, 256];

    const TINY_GT: &str = r#"{"0": [
        {"obj_id": 1, "cam_R_m2c": [0, -1, 0, 1, 0, 0, 0, 0, 1], "cam_t_m2c": [10, 20, 900]},
        {"obj_id": 2, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 1000]}
    ]}"#;

    /// A two-object, one-scene dataset: image 0 has depth and ground truth, image 1 only a
    /// camera (without depth_scale, so camera.json's applies).
    fn tiny_dataset() -> TempDir {
        let dir = TempDir::new("tiny");
        dir.write(
            "camera.json",
            r#"{"cx": 1.5, "cy": 1.0, "depth_scale": 0.1, "fx": 500.0, "fy": 501.0,
                "height": 3, "width": 4}"#,
        );
        dir.write(
            "models/models_info.json",
            r#"{"1": {"diameter": 50.5, "min_x": -10, "min_y": -20, "min_z": -30,
                      "size_x": 20, "size_y": 40, "size_z": 60,
                      "symmetries_continuous": [{"axis": [0, 0, 2], "offset": [0, 0, 5]}]},
                "2": {"diameter": 80, "min_x": 0, "min_y": 0, "min_z": 0,
                      "size_x": 1, "size_y": 1, "size_z": 1,
                      "symmetries_discrete": [[-1, 0, 0, 4, 0, -1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]}}"#,
        );
        dir.write("models/obj_000001.ply", "not read by these tests");
        dir.write("models/obj_000002.ply", "not read by these tests");
        dir.write(
            "test/000001/scene_camera.json",
            r#"{"0": {"cam_K": [500, 0, 1.5, 0, 501, 1.0, 0, 0, 1], "depth_scale": 1.0},
                "1": {"cam_K": [500, 0, 1.5, 0, 501, 1.0, 0, 0, 1]}}"#,
        );
        dir.write("test/000001/scene_gt.json", TINY_GT);
        dir.write(
            "test/000001/scene_gt_info.json",
            r#"{"0": [
                {"bbox_obj": [1, 2, 3, 4], "bbox_visib": [-1, -1, -1, -1], "px_count_all": 10,
                 "px_count_valid": 9, "px_count_visib": 0, "visib_fract": 0.0},
                {"bbox_obj": [0, 0, 4, 3], "bbox_visib": [0, 0, 4, 3], "px_count_all": 12,
                 "px_count_valid": 10, "px_count_visib": 12, "visib_fract": 1.0}]}"#,
        );
        dir.write(
            "test_targets_bop19.json",
            r#"[{"im_id": 0, "inst_count": 1, "obj_id": 2, "scene_id": 1}]"#,
        );
        let bytes: Vec<u8> = TINY_DEPTH.iter().flat_map(|v| v.to_be_bytes()).collect();
        write_png(
            &dir.0.join("test/000001/depth/000000.png"),
            4,
            3,
            png::BitDepth::Sixteen,
            &bytes,
        );
        // Not scenes: the wrong number of digits, or not a folder.
        dir.write("test/00001/scene_camera.json", "{}");
        dir.write("test/000003", "a file");
        dir
    }

    /// Asserts a dataset error about a file named `file`, whose reason holds every needle.
    fn expect_dataset_error<T: std::fmt::Debug>(result: Result<T>, file: &str, needles: &[&str]) {
        match result {
            Err(Error::Dataset { path, reason }) => {
                assert!(
                    path.ends_with(file),
                    "error names {}, expected {file}",
                    path.display()
                );
                for needle in needles {
                    assert!(
                        reason.contains(needle),
                        "reason {reason:?} lacks {needle:?}"
                    );
                }
            }
            other => panic!("expected a dataset error about {file}, got {other:?}"),
        }
    }

    #[test]
    fn tiny_dataset_reads_back() {
        let dir = tiny_dataset();
        let data = BopDataset::open(&dir.0).unwrap();
        assert_eq!(data.split(), Some("test"));
        assert_eq!(data.scene_ids(), vec![1]);
        assert_eq!(data.image_ids(1).unwrap(), vec![0, 1]);
        assert_eq!(data.object_ids(), &[1, 2]);
        let camera = data.camera().unwrap();
        assert_eq!(
            (camera.width, camera.height, camera.depth_scale_mm),
            (4, 3, 0.1)
        );

        let cam0 = data.scene_camera(1, 0).unwrap();
        assert_eq!(
            cam0.intrinsics,
            Intrinsics {
                fx: 500.0,
                fy: 501.0,
                cx: 1.5,
                cy: 1.0
            }
        );
        assert_eq!(cam0.depth_scale_mm, 1.0);
        assert!(cam0.world_to_camera.is_none());
        assert_eq!(
            data.scene_camera(1, 1).unwrap().depth_scale_mm,
            0.1,
            "camera.json's scale"
        );

        let gt = data.ground_truth(1, 0).unwrap();
        assert_eq!(gt.iter().map(|g| g.obj_id).collect::<Vec<_>>(), vec![1, 2]);
        // Row-major [0 -1 0; 1 0 0; 0 0 1] turns x into y.
        let p = gt[0].pose * Point3::new(1.0, 0.0, 0.0);
        assert!((p - Point3::new(10.0, 21.0, 900.0)).norm() < 1e-4, "{p:?}");
        let info = data.ground_truth_info(1, 0).unwrap();
        assert_eq!(info[0].bbox_visib, [-1; 4]);
        assert_eq!((info[1].visib_fract, info[1].px_count_valid), (1.0, 10));

        let frame = data.depth_frame(1, 0).unwrap();
        assert_eq!((frame.width, frame.height), (4, 3));
        assert_eq!(
            frame.depth, TINY_DEPTH,
            "16-bit samples are big-endian in the PNG"
        );
        assert_eq!(frame.intrinsics, cam0.intrinsics);
        assert!(data.has_depth(1, 0) && !data.has_depth(1, 1));

        let sym = &data.model_info(1).unwrap().symmetries_continuous[0];
        assert_eq!(sym.axis.into_inner(), Vector3::z());
        assert_eq!(sym.offset_mm, Point3::new(0.0, 0.0, 5.0));
        let info2 = data.model_info(2).unwrap();
        assert_eq!(info2.diameter_mm, 80.0);
        let flipped = info2.symmetries_discrete[0] * Point3::new(1.0, 2.0, 3.0);
        assert!(
            (flipped - Point3::new(3.0, -2.0, 3.0)).norm() < 1e-5,
            "{flipped:?}"
        );
        // As a model holds them.
        let axis = data.symmetry(1).unwrap().continuous.unwrap();
        assert_eq!(axis.direction.into_inner(), Vector3::z());
        assert_eq!(axis.point_mm, Point3::new(0.0, 0.0, 5.0));
        assert_eq!(
            data.symmetry(2).unwrap().discrete,
            info2.symmetries_discrete
        );
        assert!(data.symmetry(7).unwrap().is_none(), "no entry, no symmetry");
        // Beside a mesh: the same, with the file it came from.
        let mesh = dir.0.join("models/obj_000002.ply");
        let (beside, from) = symmetry_beside(&mesh, 2).unwrap().unwrap();
        assert_eq!(beside, data.symmetry(2).unwrap());
        assert_eq!(from, dir.0.join("models/models_info.json"));
        assert!(symmetry_beside(&mesh, 7).unwrap().is_none(), "no entry");
        let elsewhere = dir.0.join("test/obj_000002.ply");
        assert!(symmetry_beside(&elsewhere, 2).unwrap().is_none(), "no file");
        assert_eq!(
            data.model_info(1).unwrap().min_mm,
            Point3::new(-10.0, -20.0, -30.0)
        );

        let targets = data.test_targets().unwrap();
        assert_eq!(
            targets,
            &[TestTarget {
                scene_id: 1,
                im_id: 0,
                obj_id: 2,
                inst_count: 1
            }]
        );
        assert!(data
            .model_path(2)
            .unwrap()
            .ends_with("models/obj_000002.ply"));
    }

    #[test]
    fn malformed_field_names_file_image_entry_and_field() {
        let dir = tiny_dataset();
        dir.write(
            "test/000001/scene_gt.json",
            &TINY_GT.replace("0, 1, 0, 0, 0, 1]", "1, 0, 0, 0, 1]"),
        );
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.ground_truth(1, 0),
            "scene_gt.json",
            &["image 0, entry 1: cam_R_m2c has 8 numbers, expected 9"],
        );
        dir.write(
            "test/000001/scene_gt.json",
            &TINY_GT.replace("[10, 20, 900]", "[10, \"20\", 900]"),
        );
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.ground_truth(1, 0),
            "scene_gt.json",
            &["image 0, entry 0: cam_t_m2c[1]"],
        );
        dir.write(
            "test/000001/scene_gt.json",
            &TINY_GT.replace("[1, 0, 0, 0, 1, 0", "[2, 0, 0, 0, 1, 0"),
        );
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.ground_truth(1, 0),
            "scene_gt.json",
            &["entry 1: cam_R_m2c is not a rotation"],
        );
        dir.write(
            "test/000001/scene_gt.json",
            &TINY_GT.replace("\"obj_id\": 2,", ""),
        );
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.ground_truth(1, 0),
            "scene_gt.json",
            &["entry 1: 'obj_id' is missing"],
        );
    }

    #[test]
    fn malformed_dataset_files_are_refused_at_open() {
        let dir = tiny_dataset();
        dir.write("camera.json", r#"{"cx": 1.5, "cy": 1.0, "fx": 500.0"#);
        expect_dataset_error(BopDataset::open(&dir.0), "camera.json", &["not valid JSON"]);
        dir.write("camera.json", r#"{"cx": 1.5, "cy": 1.0, "depth_scale": 1, "fx": -5, "fy": 5, "height": 3, "width": 4}"#);
        expect_dataset_error(BopDataset::open(&dir.0), "camera.json", &["focal lengths"]);

        let dir = tiny_dataset();
        let info = std::fs::read_to_string(dir.0.join("models/models_info.json")).unwrap();
        dir.write(
            "models/models_info.json",
            &info.replace("0, 0, 0, 1]]", "0, 0, 1]]"),
        );
        expect_dataset_error(
            BopDataset::open(&dir.0),
            "models_info.json",
            &["object 2: symmetries_discrete[0] has 15 numbers, expected 16"],
        );
        dir.write(
            "models/models_info.json",
            &info.replace("\"diameter\": 80,", ""),
        );
        expect_dataset_error(
            BopDataset::open(&dir.0),
            "models_info.json",
            &["object 2: 'diameter' is missing"],
        );
        dir.write(
            "models/models_info.json",
            &info.replace("[0, 0, 2]", "[0, 0, 0]"),
        );
        expect_dataset_error(
            BopDataset::open(&dir.0),
            "models_info.json",
            &["object 1: symmetries_continuous[0]: axis has zero length"],
        );

        let dir = tiny_dataset();
        dir.write(
            "test_targets_bop19.json",
            r#"[{"im_id": 0, "inst_count": -1, "obj_id": 2, "scene_id": 1}]"#,
        );
        expect_dataset_error(
            BopDataset::open(&dir.0),
            "test_targets_bop19.json",
            &["target 0: inst_count"],
        );
    }

    #[test]
    fn missing_files_are_named() {
        let dir = tiny_dataset();
        std::fs::remove_file(dir.0.join("test/000001/scene_gt_info.json")).unwrap();
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.ground_truth_info(1, 0),
            "test/000001/scene_gt_info.json",
            &["missing"],
        );
        expect_dataset_error(data.depth_frame(1, 1), "depth/000001.png", &["missing"]);
        expect_dataset_error(data.ground_truth(1, 5), "scene_gt.json", &["no image 5"]);
        expect_dataset_error(
            data.scene_camera(1, 5),
            "scene_camera.json",
            &["no image 5"],
        );
        expect_dataset_error(data.ground_truth(4, 0), "test", &["no scene 4"]);
        expect_dataset_error(data.model_path(7), "models/obj_000007.ply", &["object 7"]);
        expect_dataset_error(
            data.eval_model_path(1),
            "models_eval",
            &["no 'models_eval' folder"],
        );
        expect_dataset_error(
            data.model_info(7),
            "models_info.json",
            &["no entry for object 7"],
        );

        expect_dataset_error(
            BopDataset::open(dir.0.join("nowhere")),
            "nowhere",
            &["not a directory"],
        );
        expect_dataset_error(
            BopDataset::open_split(&dir.0, "val"),
            "val",
            &["split folder 'val' is missing"],
        );
        let empty = TempDir::new("empty");
        expect_dataset_error(
            BopDataset::open(&empty.0),
            "",
            &["no 'models' folder and no scenes"],
        );
    }

    #[test]
    fn depth_png_must_be_16_bit_grayscale() {
        let dir = tiny_dataset();
        write_png(
            &dir.0.join("test/000001/depth/000000.png"),
            4,
            3,
            png::BitDepth::Eight,
            &[9; 12],
        );
        let data = BopDataset::open(&dir.0).unwrap();
        expect_dataset_error(
            data.depth_frame(1, 0),
            "000000.png",
            &["expected 16-bit grayscale"],
        );
        // Said by the check before any work too, from the header.
        expect_dataset_error(
            data.check_image(1, 0),
            "000000.png",
            &["Grayscale Eight", "expected 16-bit grayscale"],
        );
        std::fs::write(
            dir.0.join("test/000001/depth/000000.png"),
            b"\x89PNG\r\n\x1a\ntruncated",
        )
        .unwrap();
        expect_dataset_error(
            data.depth_frame(1, 0),
            "000000.png",
            &["not a readable PNG"],
        );
    }

    /// A depth image larger than any frame may be is refused from its header, before its
    /// gigabytes would be decoded and prepared.
    #[test]
    fn depth_png_beyond_the_pixel_limit_is_refused_from_its_header() {
        let dir = tiny_dataset();
        let (width, height) = (4097u32, 4097u32);
        let zeros = vec![0u8; (width * height * 2) as usize];
        write_png(
            &dir.0.join("test/000001/depth/000000.png"),
            width,
            height,
            png::BitDepth::Sixteen,
            &zeros,
        );
        let data = BopDataset::open(&dir.0).unwrap();
        for refused in [
            data.check_image(1, 0).map(|_| ()),
            data.depth_frame(1, 0).map(|_| ()),
        ] {
            expect_dataset_error(
                refused,
                "000000.png",
                &["4097x4097", "16785409 pixels", "4096x4096"],
            );
        }
    }

    #[test]
    fn lmo_scene_2_image_3() {
        let Some(dir) = crate::shared_test_data("lmo") else {
            return;
        };
        let data = BopDataset::open(dir).unwrap();
        assert_eq!(data.scene_ids(), vec![2]);
        assert_eq!(data.object_ids(), &[1, 5, 6, 8, 9, 10, 11, 12]);
        assert!(data.image_ids(2).unwrap().contains(&3));

        let gt = data.ground_truth(2, 3).unwrap();
        assert_eq!(gt.len(), 8);
        let mut ids: Vec<u32> = gt.iter().map(|g| g.obj_id).collect();
        ids.sort_unstable();
        assert_eq!(ids, data.object_ids());
        let info = data.ground_truth_info(2, 3).unwrap();
        assert_eq!(info.len(), 8);
        assert!(
            (info[0].visib_fract - 0.1996).abs() < 1e-3,
            "ape is 20 % visible"
        );

        let camera = data.camera().unwrap();
        let scene_camera = data.scene_camera(2, 3).unwrap();
        assert_eq!(scene_camera.intrinsics, camera.intrinsics);
        assert_eq!(scene_camera.intrinsics, Intrinsics::LMO);
        assert_eq!(scene_camera.depth_scale_mm, 1.0);

        let frame = data.depth_frame(2, 3).unwrap();
        assert_eq!((frame.width, frame.height), (camera.width, camera.height));
        assert_eq!((frame.width, frame.height), (640, 480));
        let valid: Vec<u16> = frame.depth.iter().copied().filter(|&d| d != 0).collect();
        let plausible = valid.iter().filter(|&&d| (300..=2000).contains(&d)).count();
        assert!(
            valid.len() > frame.depth.len() * 9 / 10,
            "{} valid pixels",
            valid.len()
        );
        assert!(
            plausible > valid.len() * 99 / 100,
            "{plausible} of {} in 300..2000 mm",
            valid.len()
        );

        for obj in [10, 11] {
            let info = data.model_info(obj).unwrap();
            assert_eq!(info.symmetries_discrete.len(), 1, "object {obj}");
            // Both are half turns about (nearly) the model's z axis.
            let angle = info.symmetries_discrete[0].rotation.angle();
            assert!(
                (angle - std::f32::consts::PI).abs() < 0.05,
                "object {obj}: {angle}"
            );
        }
        assert!(data.model_info(1).unwrap().symmetries_discrete.is_empty());
        assert!((data.model_info(1).unwrap().diameter_mm - 102.099).abs() < 1e-3);

        let targets = data.test_targets().unwrap();
        assert_eq!(targets.len(), 1445);
        assert_eq!(
            targets
                .iter()
                .filter(|t| t.scene_id == 2 && t.im_id == 3)
                .count(),
            8
        );
        assert!(data.model_path(12).unwrap().is_file());
        assert!(data.eval_model_path(12).unwrap().is_file());
    }

    /// For an object's camera-facing evaluation-mesh vertices placed by a pose: the fraction
    /// whose image depth agrees within 10 mm, and the fraction the sensor sees through (image
    /// depth more than 15 mm behind the model), among those with a depth measurement.
    fn depth_agreement(data: &BopDataset, scene: u32, im: u32, gt: &GtPose) -> (f32, f32) {
        let frame = data.depth_frame(scene, im).unwrap();
        let mesh = Mesh::from_ply_file(data.eval_model_path(gt.obj_id).unwrap()).unwrap();
        let view = frame.view();
        let (mut measured, mut agreeing, mut behind) = (0, 0, 0);
        for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
            let p = gt.pose * p;
            if (gt.pose.rotation * n).dot(&p.coords) >= 0.0 {
                continue;
            }
            let uv = frame.intrinsics.project(&p);
            let (u, v) = (uv.x.round(), uv.y.round());
            if u < 0.0 || v < 0.0 || u >= frame.width as f32 || v >= frame.height as f32 {
                continue;
            }
            if let Some(d) = view.depth_mm(u as u32, v as u32) {
                measured += 1;
                agreeing += usize::from((d - p.z).abs() < 10.0);
                behind += usize::from(d - p.z > 15.0);
            }
        }
        let n = measured.max(1) as f32;
        (agreeing as f32 / n, behind as f32 / n)
    }

    /// The ground truth read as row-major rotations fits the real depth image; the transposed
    /// reading would not.
    #[test]
    fn lmo_ground_truth_matches_the_depth_image() {
        let Some(dir) = crate::shared_test_data("lmo") else {
            return;
        };
        let data = BopDataset::open(dir).unwrap();
        let gt = data.ground_truth(2, 3).unwrap();
        let info = data.ground_truth_info(2, 3).unwrap();
        let (mut checked, mut seen_through, mut seen_through_wrong) = (0, 0.0, 0.0);
        for (g, i) in gt.iter().zip(info).filter(|(_, i)| i.visib_fract > 0.9) {
            let (agreement, behind) = depth_agreement(&data, 2, 3, g);
            let inverse = Pose::from_parts(g.pose.translation, g.pose.rotation.inverse());
            let (_, wrong_behind) = depth_agreement(
                &data,
                2,
                3,
                &GtPose {
                    pose: inverse,
                    ..*g
                },
            );
            println!(
                "object {}: visible {:.2}, agree {agreement:.2}, seen through {behind:.2}, \
                 transposed R seen through {wrong_behind:.2}",
                g.obj_id, i.visib_fract
            );
            assert!(agreement > 0.4, "object {}: {agreement}", g.obj_id);
            // Silhouette pixels and self-occluded vertices keep this above zero.
            assert!(behind < 0.2, "object {}: {behind}", g.obj_id);
            assert!(behind < wrong_behind, "object {}", g.obj_id);
            (seen_through, seen_through_wrong) =
                (seen_through + behind, seen_through_wrong + wrong_behind);
            checked += 1;
        }
        assert_eq!(checked, 5, "five objects are more than 90 % visible");
        assert!(
            seen_through < 0.5 * seen_through_wrong,
            "{seen_through} vs {seen_through_wrong}"
        );
    }

    #[test]
    fn synthetic_set_opens() {
        let Some(dir) = crate::shared_test_data("synth-lmo-dev") else {
            return;
        };
        let data = BopDataset::open(dir).unwrap();
        assert_eq!(data.scene_ids(), vec![1]);
        let images = data.image_ids(1).unwrap();
        assert_eq!(images, (0..40).collect::<Vec<_>>());
        assert!(images.iter().all(|&im| data.has_depth(1, im)));
        let camera = data.scene_camera(1, 0).unwrap();
        assert!(camera.world_to_camera.is_some());
        assert_eq!(data.depth_frame(1, 39).unwrap().depth.len(), 640 * 480);
        let gt = data.ground_truth(1, 0).unwrap();
        assert_eq!(gt.len(), data.ground_truth_info(1, 0).unwrap().len());
        assert!(!data.test_targets().unwrap().is_empty());
    }

    #[test]
    fn single_scene_folder_opens_as_scene_0() {
        let Some(dir) = crate::shared_test_data("mpabst_bop_obj19") else {
            return;
        };
        let data = BopDataset::open(dir).unwrap();
        assert_eq!(data.split(), Some("data"));
        assert_eq!(data.scene_ids(), vec![0]);
        assert_eq!(data.object_ids(), &[19]);
        assert!(data.model_path(19).unwrap().ends_with("data/obj.ply"));
        assert!(data.model_path(18).is_err());
        assert_eq!(data.image_ids(0).unwrap().len(), 75);
        assert!(data.has_depth(0, 10) && !data.has_depth(0, 11));
        let frame = data.depth_frame(0, 10).unwrap();
        assert_eq!((frame.width, frame.height), (640, 480));
        assert!((frame.intrinsics.fx - 542.0634).abs() < 1e-3);
        assert_eq!(data.ground_truth(0, 10).unwrap()[0].obj_id, 19);
        assert!(data.model_info(19).is_err() && data.test_targets().is_none());
    }
}
