//! Scoring a results file against a dataset: errors per estimate and ground-truth instance,
//! greedy matching per threshold, recall per object and overall, the BOP 2018 recall and the
//! BOP 2019 average recall.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::csv::EstimateRow;
use super::gt_info::{image_gt_info, model_info_from_mesh, MeshCache};
use super::mspd::mspd;
use super::mssd::mssd;
use super::recall::{bop19_fractions, bop19_mspd_thresholds_px, match_greedy, Tally};
use super::symmetry::{symmetry_transforms, MAX_SYM_DISC_STEP};
use super::vsd::{depth_to_distance, vsd_errors, CostType, VisibilityMode};
use crate::dataset::{BopDataset, GtPose, ModelInfo, TestTarget};
use ppfd_models::geometry::camera::Intrinsics;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::Pose;

use crate::{Error, Result};

/// What to score and with which settings. [`ScoreOptions::default`] is the benchmark's.
#[derive(Clone, Debug)]
pub struct ScoreOptions {
    /// VSD visibility tolerance δ, mm. BOP uses 15 mm for LM-O and every Kinect/Primesense set.
    pub vsd_delta_mm: f32,
    /// BOP 2019 VSD misalignment tolerances τ, fractions of the object diameter: 0.05…0.5.
    pub vsd_taus: Vec<f64>,
    /// BOP 2019 VSD correctness thresholds θ: 0.05…0.5.
    pub vsd_thresholds: Vec<f64>,
    /// BOP 2019 MSSD thresholds, fractions of the object diameter: 0.05…0.5.
    pub mssd_thresholds: Vec<f64>,
    /// BOP 2019 MSPD thresholds, pixels for a 640-pixel-wide image (scaled by width / 640):
    /// 5…50.
    pub mspd_thresholds_px: Vec<f64>,
    /// BOP 2018 VSD misalignment tolerance τ, mm: 20.
    pub bop18_tau_mm: f32,
    /// BOP 2018 VSD correctness thresholds: 0.3 (SIXD/BOP 2018) and 0.35 (Vidal et al. 2018).
    pub bop18_thresholds: Vec<f64>,
    /// Ground truth less visible than this fraction neither counts nor can be matched: 0.1.
    pub visib_gt_min: f32,
    /// Sampling of continuous symmetries, [`MAX_SYM_DISC_STEP`].
    pub max_sym_disc_step: f64,
    /// The targets; `None` takes the dataset's `test_targets_bop19.json`, or when it has none,
    /// every object with a ground-truth instance at least `visib_gt_min` visible in every image
    /// that has depth, with as many instances as are that visible.
    pub targets: Option<Vec<TestTarget>>,
    /// Edges of the visible-fraction bins of the report, ascending.
    pub visib_bin_edges: Vec<f32>,
}

impl Default for ScoreOptions {
    fn default() -> Self {
        ScoreOptions {
            vsd_delta_mm: 15.0,
            vsd_taus: bop19_fractions(),
            vsd_thresholds: bop19_fractions(),
            mssd_thresholds: bop19_fractions(),
            mspd_thresholds_px: bop19_mspd_thresholds_px(),
            bop18_tau_mm: 20.0,
            bop18_thresholds: vec![0.3, 0.35],
            visib_gt_min: 0.1,
            max_sym_disc_step: MAX_SYM_DISC_STEP,
            targets: None,
            visib_bin_edges: vec![0.1, 0.3, 0.5, 0.7, 0.9, 1.0],
        }
    }
}

/// An object as the error functions need it.
#[derive(Clone, Debug)]
pub struct EvalObject {
    /// The object's id.
    pub obj_id: u32,
    /// The evaluation mesh (`models_eval/`): rendered for VSD, its vertices for MSSD and MSPD.
    pub mesh: Mesh,
    /// Diameter from `models_info.json`, mm.
    pub diameter_mm: f32,
    /// From [`symmetry_transforms`].
    pub symmetries: Vec<Isometry3<f64>>,
}

impl EvalObject {
    /// Builds the object from its evaluation mesh and its `models_info.json` entry.
    pub fn new(obj_id: u32, mesh: Mesh, info: &ModelInfo, max_sym_disc_step: f64) -> EvalObject {
        EvalObject {
            obj_id,
            mesh,
            diameter_mm: info.diameter_mm,
            symmetries: symmetry_transforms(info, max_sym_disc_step),
        }
    }
}

/// How far a `models_info.json` diameter may lie from its mesh's own: BOP computes both from
/// the same vertices, so only a wrong entry (another object's, another unit's) is farther off.
pub const DIAMETER_TOLERANCE: f32 = 0.05;

/// Refuses a `models_info.json` entry whose diameter is not that of its object's mesh
/// (`measured_mm`, of the mesh at `mesh_path`): the MSSD and MSPD thresholds and VSD's τ are
/// fractions of it, so a diameter fifty times too large passes a pose half a metre off. A
/// dataset without the file, or without an entry for the object, has nothing to check.
pub fn check_diameter(
    dataset: &BopDataset,
    obj_id: u32,
    measured_mm: f32,
    mesh_path: &std::path::Path,
) -> Result<()> {
    let (Some(info_path), Ok(info)) = (dataset.models_info_path(), dataset.model_info(obj_id))
    else {
        return Ok(());
    };
    if (info.diameter_mm - measured_mm).abs() <= DIAMETER_TOLERANCE * measured_mm {
        return Ok(());
    }
    Err(Error::Dataset {
        path: info_path.to_path_buf(),
        reason: format!(
            "object {obj_id}: diameter {} mm, where its mesh {} measures {measured_mm:.1} mm \
             across; scoring takes its thresholds as fractions of the diameter, so fix the entry",
            info.diameter_mm,
            mesh_path.display()
        ),
    })
}

/// One test image with its ground truth and targets.
#[derive(Clone, Debug)]
pub struct EvalImage {
    /// The scene (6-digit folder of the split).
    pub scene_id: u32,
    /// The image within the scene.
    pub im_id: u32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics of the image's camera, pixels.
    pub intrinsics: Intrinsics,
    /// The test depth (camera z), mm, row-major; 0 = no measurement.
    pub depth_mm: Vec<f32>,
    /// The annotated instances of every object.
    pub gt: Vec<GtPose>,
    /// Visible fraction of each instance of `gt`.
    pub visib_fract: Vec<f32>,
    /// `(obj_id, inst_count)` of each target of the image.
    pub targets: Vec<(u32, u32)>,
}

/// Renders `mesh` at `pose` into a full `width × height` depth image (camera z, mm, 0 = none).
pub type RenderFn<'a> = dyn FnMut(&Mesh, &Pose, &Intrinsics, u32, u32) -> Result<Vec<f32>> + 'a;

/// One ground-truth instance of a target's object.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GtInstance {
    /// Position in the image's `scene_gt.json` list.
    pub gt_index: usize,
    /// Fraction of the instance's projected surface that is visible, 0..1.
    pub visib_fract: f32,
    /// Visible enough to count and to be matched.
    pub valid: bool,
}

/// The errors of one estimate against each ground-truth instance of its target (same order as
/// [`TargetErrors::gt`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct EstimateErrors {
    /// The estimate's confidence, from the results file.
    pub score: f32,
    /// BOP 2018 VSD (τ = `bop18_tau_mm`, 2018 visibility rule).
    pub vsd_bop18: Vec<f64>,
    /// BOP 2019 VSD, one list per instance with one error per τ of `vsd_taus`.
    pub vsd_bop19: Vec<Vec<f64>>,
    /// MSSD, mm.
    pub mssd_mm: Vec<f64>,
    /// MSPD, pixels.
    pub mspd_px: Vec<f64>,
}

/// Everything scoring needs about one target: its instances and the errors of its estimates
/// (in decreasing order of score, at most `inst_count`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TargetErrors {
    /// The scene (6-digit folder of the split).
    pub scene_id: u32,
    /// The image within the scene.
    pub im_id: u32,
    /// The object to find.
    pub obj_id: u32,
    /// Number of instances of the object to report.
    pub inst_count: u32,
    /// The object's diameter, mm: the MSSD thresholds and VSD τ are fractions of it.
    pub diameter_mm: f32,
    /// Width of the image, pixels: the MSPD thresholds scale with it.
    pub image_width: u32,
    /// The annotated instances of the object in the image.
    pub gt: Vec<GtInstance>,
    /// The errors of each estimate scored.
    pub estimates: Vec<EstimateErrors>,
}

/// Scores of one object, or of all of them.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ObjectScore {
    /// The object; `None` for the overall row.
    pub obj_id: Option<u32>,
    /// Targets (image, object) of this object.
    pub targets: usize,
    /// Ground-truth instances that count (visible enough).
    pub gt_count: usize,
    /// Estimates scored (the best `inst_count` of each target).
    pub estimates: usize,
    /// BOP 2018 VSD recall at each of `bop18_thresholds`.
    pub recall_bop18: Vec<f64>,
    /// Mean recall over the BOP 2019 VSD grid (τ × θ).
    pub ar_vsd: f64,
    /// Mean recall over the MSSD thresholds.
    pub ar_mssd: f64,
    /// Mean recall over the MSPD thresholds.
    pub ar_mspd: f64,
    /// `(ar_vsd + ar_mssd + ar_mspd) / 3`.
    pub ar: f64,
}

/// BOP 2018 recall of the ground truth whose visible fraction lies in `[min, max)` (the last bin
/// includes its top edge).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VisibBin {
    /// Lowest visible fraction of the bin, 0..1.
    pub min: f32,
    /// Highest visible fraction of the bin (excluded but for the last bin), 0..1.
    pub max: f32,
    /// Ground-truth instances that count (visible enough) in the bin.
    pub gt_count: usize,
    /// At each of `bop18_thresholds`.
    pub recall_bop18: Vec<f64>,
}

/// The result of scoring a results file.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScoreReport {
    /// One row per object with targets, ascending id.
    pub objects: Vec<ObjectScore>,
    /// All objects together (recall over all instances, not a mean of per-object recalls).
    pub overall: ObjectScore,
    /// BOP 2018 recall by visible fraction, one bin per pair of `visib_bin_edges`.
    pub visib_bins: Vec<VisibBin>,
    /// The BOP 2018 thresholds the `recall_bop18` lists follow.
    pub bop18_thresholds: Vec<f64>,
    /// Images scored.
    pub images: usize,
    /// Targets skipped because their image has no depth in the dataset (a dataset may hold part
    /// of its targets' images).
    pub skipped_targets: usize,
    /// The depth image the first skipped target's image would have (`None` also when its
    /// scene folder is missing too).
    pub first_missing_depth: Option<String>,
    /// Lines of the results file.
    pub estimates_read: usize,
    /// Of those, lines for no target (another image or object) or beyond a target's
    /// `inst_count`: not scored.
    pub estimates_ignored: usize,
    /// What was computed because the dataset lacks it (visibility, model metadata), one line
    /// each; empty for a complete BOP dataset.
    pub notes: Vec<String>,
    /// Mean of the per-image times of the scored images that have one, seconds.
    pub mean_time_per_image_s: Option<f64>,
    /// Those images' total time divided by their number of targets, seconds.
    pub mean_time_per_target_s: Option<f64>,
}

/// The targets of one image, keyed by (scene, image).
type ImageTargets = BTreeMap<(u32, u32), Vec<(u32, u32)>>;

/// Scores `rows` against `dataset` (see the [module documentation](super)), rendering with
/// [`ppfd_models::geometry::render::Renderer`].
pub fn score_results(
    dataset: &BopDataset,
    rows: &[EstimateRow],
    options: &ScoreOptions,
) -> Result<ScoreReport> {
    score_results_with(dataset, rows, options, || {
        let mut renderer = ppfd_models::geometry::render::Renderer::new().cull_back_faces(false);
        move |mesh: &Mesh, pose: &Pose, intrinsics: &Intrinsics, width: u32, height: u32| {
            renderer.render_into(
                mesh,
                pose,
                intrinsics,
                ppfd_models::geometry::render::Roi::full(width, height),
            )?;
            Ok(renderer.depth_mm().to_vec())
        }
    })
}

/// The dataset's own targets: its `test_targets_bop19.json`, or else every annotated instance
/// at least `visib_gt_min` visible ([`targets_from_ground_truth`]).
pub fn dataset_targets(dataset: &BopDataset, visib_gt_min: f32) -> Result<Vec<TestTarget>> {
    match dataset.test_targets() {
        Some(t) => Ok(t.to_vec()),
        None => targets_from_ground_truth(dataset, visib_gt_min),
    }
}

/// The error for results of which no row names an image with targets: results of another
/// dataset, or of another split, would otherwise score as a detector that found nothing.
fn no_estimate_is_for_a_target<E, T>(
    dataset: &BopDataset,
    estimates: &BTreeMap<(u32, u32), E>,
    targets: &BTreeMap<(u32, u32), T>,
) -> Error {
    let some = |keys: Vec<&(u32, u32)>| {
        let shown: Vec<String> = keys
            .iter()
            .take(3)
            .map(|(scene, image)| format!("scene {scene} image {image}"))
            .collect();
        let more = keys.len().saturating_sub(shown.len());
        if more > 0 {
            format!("{} and {more} more", shown.join(", "))
        } else if shown.is_empty() {
            "none".to_string()
        } else {
            shown.join(", ")
        }
    };
    Error::Dataset {
        path: dataset.root().to_path_buf(),
        reason: format!(
            "no estimate is for an image with targets here: the results name {}, the targets {}; \
             were the results made on another dataset or split?",
            some(estimates.keys().collect()),
            some(targets.keys().collect()),
        ),
    }
}

/// [`score_results`] with another depth renderer: `make_renderer` makes one per worker thread.
pub fn score_results_with<F, R>(
    dataset: &BopDataset,
    rows: &[EstimateRow],
    options: &ScoreOptions,
    make_renderer: F,
) -> Result<ScoreReport>
where
    F: Fn() -> R + Sync + Send,
    R: FnMut(&Mesh, &Pose, &Intrinsics, u32, u32) -> Result<Vec<f32>>,
{
    let times = image_times(rows)?;
    let meshes = MeshCache::default();
    let targets = match &options.targets {
        Some(t) => t.clone(),
        None => dataset_targets(dataset, options.visib_gt_min)?,
    };
    let mut by_image: ImageTargets = BTreeMap::new();
    let mut skipped_targets = 0;
    let mut first_missing_depth = None;
    for t in &targets {
        // A dataset may hold part of its targets' images (the LM-O frame here: one of 200), so
        // an image without depth is skipped. One with depth must have its ground truth: a
        // malformed or missing scene_gt.json would otherwise score as a detector that found
        // nothing.
        if dataset.has_depth(t.scene_id, t.im_id) {
            dataset.ground_truth(t.scene_id, t.im_id)?;
            by_image
                .entry((t.scene_id, t.im_id))
                .or_default()
                .push((t.obj_id, t.inst_count));
        } else {
            skipped_targets += 1;
            if first_missing_depth.is_none() {
                first_missing_depth = dataset
                    .depth_path(t.scene_id, t.im_id)
                    .ok()
                    .map(|p| p.display().to_string());
            }
        }
    }
    if by_image.is_empty() && !targets.is_empty() {
        let first = first_missing_depth
            .as_deref()
            .map_or(String::new(), |d| format!(" (the first's would be {d})"));
        return Err(Error::Dataset {
            path: dataset.root().to_path_buf(),
            reason: format!(
                "none of the {} targets' images has a depth image{first}",
                targets.len()
            ),
        });
    }

    let object_ids: BTreeSet<u32> = by_image.values().flatten().map(|(o, _)| *o).collect();
    let objects = object_ids
        .iter()
        .map(|&obj_id| {
            let path = dataset
                .eval_model_path(obj_id)
                .or_else(|_| dataset.model_path(obj_id))?;
            let mesh = Mesh::from_ply_file(&path)?;
            let info = if dataset.has_models_info() {
                let measured = ppfd_models::model::sampling::diameter(&mesh.positions);
                check_diameter(dataset, obj_id, measured, &path)?;
                dataset.model_info(obj_id)?.clone()
            } else {
                model_info_from_mesh(&mesh)
            };
            Ok((
                obj_id,
                EvalObject::new(obj_id, mesh, &info, options.max_sym_disc_step),
            ))
        })
        .collect::<Result<BTreeMap<u32, EvalObject>>>()?;

    let mut rows_by_image: BTreeMap<(u32, u32), Vec<&EstimateRow>> = BTreeMap::new();
    for row in rows {
        rows_by_image
            .entry((row.scene_id, row.im_id))
            .or_default()
            .push(row);
    }

    if !rows.is_empty()
        && !by_image.is_empty()
        && !rows_by_image.keys().any(|key| by_image.contains_key(key))
    {
        return Err(no_estimate_is_for_a_target(
            dataset,
            &rows_by_image,
            &by_image,
        ));
    }

    let images: Vec<_> = by_image.iter().collect();
    let per_image: Vec<Vec<TargetErrors>> = images
        .par_iter()
        .map_init(
            &make_renderer,
            |render, (&(scene_id, im_id), image_targets)| {
                let image = load_image(dataset, scene_id, im_id, image_targets, &meshes)?;
                let estimates = rows_by_image
                    .get(&(scene_id, im_id))
                    .map(Vec::as_slice)
                    .unwrap_or(&[]);
                image_errors(&objects, &image, estimates, options, render)
            },
        )
        .collect::<Result<_>>()?;
    let target_errors: Vec<TargetErrors> = per_image.into_iter().flatten().collect();

    let mut report = summarize(&target_errors, options);
    let mut estimated_scenes: Vec<u32> = by_image
        .keys()
        .map(|&(scene_id, _)| scene_id)
        .filter(|&scene_id| !dataset.has_ground_truth_info(scene_id))
        .collect();
    estimated_scenes.dedup();
    if !estimated_scenes.is_empty() {
        report.notes.push(format!(
            "no scene_gt_info.json in scene(s) {estimated_scenes:?}: visibility computed as BOP's \
             calc_gt_info does (δ {} mm)",
            super::gt_info::VISIBILITY_TOLERANCE_MM
        ));
    }
    if !dataset.has_models_info() {
        report.notes.push(
            "no models_info.json: diameters from the meshes, no symmetries (MSSD and MSPD count \
             a pose turned by a symmetry as wrong)"
                .into(),
        );
    }
    report.images = by_image.len();
    report.skipped_targets = skipped_targets;
    report.first_missing_depth = first_missing_depth;
    report.estimates_read = rows.len();
    report.estimates_ignored = rows.len() - report.overall.estimates;
    let timed: Vec<(f64, usize)> = by_image
        .iter()
        .filter_map(|(key, t)| times.get(key).map(|&s| (s, t.len())))
        .collect();
    if !timed.is_empty() {
        let total: f64 = timed.iter().map(|(s, _)| s).sum();
        let target_count: usize = timed.iter().map(|(_, n)| n).sum();
        report.mean_time_per_image_s = Some(total / timed.len() as f64);
        report.mean_time_per_target_s = Some(total / target_count.max(1) as f64);
    }
    Ok(report)
}

/// The time of each image that has one (non-negative); an error when an image's lines disagree.
fn image_times(rows: &[EstimateRow]) -> Result<BTreeMap<(u32, u32), f64>> {
    let mut times: BTreeMap<(u32, u32), f32> = BTreeMap::new();
    for row in rows {
        let key = (row.scene_id, row.im_id);
        match times.get(&key) {
            Some(&t) if t != row.time_s => {
                return Err(Error::InvalidParameter(format!(
                    "scene {} image {}: the estimates give different times ({t} s and {} s); \
                     BOP results carry one time per image",
                    row.scene_id, row.im_id, row.time_s
                )))
            }
            Some(_) => {}
            None => {
                times.insert(key, row.time_s);
            }
        }
    }
    Ok(times
        .into_iter()
        .filter(|(_, t)| *t >= 0.0)
        .map(|(k, t)| (k, t as f64))
        .collect())
}

/// Targets as BOP derives them from the ground truth: in every image with depth, each object
/// with instances at least `visib_gt_min` visible, as many as there are (visibility from
/// [`image_gt_info`]: estimated where a scene has no `scene_gt_info.json`).
pub fn targets_from_ground_truth(
    dataset: &BopDataset,
    visib_gt_min: f32,
) -> Result<Vec<TestTarget>> {
    let meshes = MeshCache::default();
    let mut targets = Vec::new();
    for scene_id in dataset.scene_ids() {
        for im_id in dataset.image_ids(scene_id)? {
            if !dataset.has_depth(scene_id, im_id) {
                continue;
            }
            let gt = dataset.ground_truth(scene_id, im_id)?;
            let info = image_gt_info(dataset, scene_id, im_id, &meshes)?;
            let mut counts: BTreeMap<u32, u32> = BTreeMap::new();
            for (g, i) in gt.iter().zip(info) {
                if i.visib_fract >= visib_gt_min {
                    *counts.entry(g.obj_id).or_default() += 1;
                }
            }
            targets.extend(counts.into_iter().map(|(obj_id, inst_count)| TestTarget {
                scene_id,
                im_id,
                obj_id,
                inst_count,
            }));
        }
    }
    Ok(targets)
}

fn load_image(
    dataset: &BopDataset,
    scene_id: u32,
    im_id: u32,
    targets: &[(u32, u32)],
    meshes: &MeshCache,
) -> Result<EvalImage> {
    let frame = dataset.depth_frame(scene_id, im_id)?;
    let gt = dataset.ground_truth(scene_id, im_id)?.to_vec();
    let info = image_gt_info(dataset, scene_id, im_id, meshes)?;
    if info.len() != gt.len() {
        return Err(Error::Dataset {
            path: dataset.root().to_path_buf(),
            reason: format!(
                "scene {scene_id} image {im_id}: scene_gt.json has {} instances but \
                 scene_gt_info.json has {}",
                gt.len(),
                info.len()
            ),
        });
    }
    Ok(EvalImage {
        scene_id,
        im_id,
        width: frame.width,
        height: frame.height,
        intrinsics: frame.intrinsics,
        depth_mm: frame
            .depth
            .iter()
            .map(|&d| d as f32 * frame.depth_scale_mm)
            .collect(),
        gt,
        visib_fract: info.iter().map(|i| i.visib_fract).collect(),
        targets: targets.to_vec(),
    })
}

/// BOP's quick test (`misc.overlapping_sphere_projections`): whether the projections of two
/// spheres of `radius` centred at the two translations can overlap. When they cannot, VSD is 1.
fn sphere_projections_overlap(radius: f64, a: &Pose, b: &Pose) -> bool {
    let (p, q) = (
        a.translation.vector.cast::<f64>(),
        b.translation.vector.cast::<f64>(),
    );
    if p.z <= 0.0 || q.z <= 0.0 {
        return false;
    }
    let distance = ((p.x / p.z - q.x / q.z).powi(2) + (p.y / p.z - q.y / q.z).powi(2)).sqrt();
    distance < radius * (1.0 / p.z + 1.0 / q.z)
}

/// The errors of every target of one image. `estimates` are the image's rows (any object);
/// those of each target are ordered by decreasing score (stable) and cut to `inst_count`.
pub fn image_errors(
    objects: &BTreeMap<u32, EvalObject>,
    image: &EvalImage,
    estimates: &[&EstimateRow],
    options: &ScoreOptions,
    render: &mut RenderFn<'_>,
) -> Result<Vec<TargetErrors>> {
    let (width, height, k) = (image.width, image.height, &image.intrinsics);
    let expected = width as usize * height as usize;
    if image.depth_mm.len() != expected || image.visib_fract.len() != image.gt.len() {
        return Err(Error::InvalidParameter(format!(
            "scene {} image {}: {}x{} needs {expected} depth values and one visible fraction per \
             instance, got {} and {} for {} instances",
            image.scene_id,
            image.im_id,
            width,
            height,
            image.depth_mm.len(),
            image.visib_fract.len(),
            image.gt.len()
        )));
    }
    let mut dist_test: Option<Vec<f32>> = None;
    let mut out = Vec::with_capacity(image.targets.len());
    for &(obj_id, inst_count) in &image.targets {
        let object = objects.get(&obj_id).ok_or(Error::UnknownObject(obj_id))?;
        let gt: Vec<GtInstance> = image
            .gt
            .iter()
            .enumerate()
            .filter(|(_, g)| g.obj_id == obj_id)
            .map(|(gt_index, _)| GtInstance {
                gt_index,
                visib_fract: image.visib_fract[gt_index],
                valid: image.visib_fract[gt_index] >= options.visib_gt_min,
            })
            .collect();
        let mut mine: Vec<&EstimateRow> = estimates
            .iter()
            .copied()
            .filter(|e| e.obj_id == obj_id)
            .collect();
        mine.sort_by(|a, b| b.score.total_cmp(&a.score));
        mine.truncate(inst_count as usize);

        let diameter = object.diameter_mm as f64;
        let taus_mm: Vec<f32> = options
            .vsd_taus
            .iter()
            .map(|t| (t * diameter) as f32)
            .collect();
        let mut gt_dist: Vec<Option<Vec<f32>>> = vec![None; gt.len()];
        let mut estimate_errors = Vec::with_capacity(mine.len());
        for estimate in mine {
            let mut est_dist: Option<Vec<f32>> = None;
            let mut errors = EstimateErrors {
                score: estimate.score,
                vsd_bop18: Vec::with_capacity(gt.len()),
                vsd_bop19: Vec::with_capacity(gt.len()),
                mssd_mm: Vec::with_capacity(gt.len()),
                mspd_px: Vec::with_capacity(gt.len()),
            };
            for (slot, instance) in gt.iter().enumerate() {
                let truth = &image.gt[instance.gt_index].pose;
                let points = &object.mesh.positions;
                errors
                    .mssd_mm
                    .push(mssd(&estimate.pose, truth, points, &object.symmetries));
                errors
                    .mspd_px
                    .push(mspd(&estimate.pose, truth, k, points, &object.symmetries));
                if !sphere_projections_overlap(0.5 * diameter, &estimate.pose, truth) {
                    errors.vsd_bop18.push(1.0);
                    errors.vsd_bop19.push(vec![1.0; taus_mm.len()]);
                    continue;
                }
                if dist_test.is_none() {
                    dist_test = Some(depth_to_distance(&image.depth_mm, width, height, k)?);
                }
                if gt_dist[slot].is_none() {
                    let depth = render(&object.mesh, truth, k, width, height)?;
                    gt_dist[slot] = Some(depth_to_distance(&depth, width, height, k)?);
                }
                if est_dist.is_none() {
                    let depth = render(&object.mesh, &estimate.pose, k, width, height)?;
                    est_dist = Some(depth_to_distance(&depth, width, height, k)?);
                }
                let (test, g, e) = (
                    dist_test.as_deref().unwrap_or_default(),
                    gt_dist[slot].as_deref().unwrap_or_default(),
                    est_dist.as_deref().unwrap_or_default(),
                );
                let bop18 = vsd_errors(
                    test,
                    g,
                    e,
                    options.vsd_delta_mm,
                    &[options.bop18_tau_mm],
                    VisibilityMode::Bop18,
                    CostType::Step,
                )?;
                let bop19 = vsd_errors(
                    test,
                    g,
                    e,
                    options.vsd_delta_mm,
                    &taus_mm,
                    VisibilityMode::Bop19,
                    CostType::Step,
                )?;
                errors.vsd_bop18.push(bop18[0] as f64);
                errors
                    .vsd_bop19
                    .push(bop19.into_iter().map(|x| x as f64).collect());
            }
            estimate_errors.push(errors);
        }
        out.push(TargetErrors {
            scene_id: image.scene_id,
            im_id: image.im_id,
            obj_id,
            inst_count,
            diameter_mm: object.diameter_mm,
            image_width: width,
            gt,
            estimates: estimate_errors,
        });
    }
    Ok(out)
}

/// Which error a setting matches on, and its threshold.
#[derive(Clone, Copy)]
enum Setting {
    Bop18 { threshold: f64 },
    Vsd { tau: usize, threshold: f64 },
    Mssd { fraction: f64 },
    Mspd { px_at_640: f64 },
}

impl Setting {
    /// Per-instance matched flags of one target.
    fn matched(&self, target: &TargetErrors) -> Vec<bool> {
        let (errors, threshold): (Vec<Vec<f64>>, f64) = match *self {
            Setting::Bop18 { threshold } => (
                target
                    .estimates
                    .iter()
                    .map(|e| e.vsd_bop18.clone())
                    .collect(),
                threshold,
            ),
            Setting::Vsd { tau, threshold } => (
                target
                    .estimates
                    .iter()
                    .map(|e| e.vsd_bop19.iter().map(|per_tau| per_tau[tau]).collect())
                    .collect(),
                threshold,
            ),
            Setting::Mssd { fraction } => (
                target.estimates.iter().map(|e| e.mssd_mm.clone()).collect(),
                fraction * target.diameter_mm as f64,
            ),
            Setting::Mspd { px_at_640 } => (
                target.estimates.iter().map(|e| e.mspd_px.clone()).collect(),
                px_at_640 * target.image_width as f64 / 640.0,
            ),
        };
        let valid: Vec<bool> = target.gt.iter().map(|g| g.valid).collect();
        let mut matched = vec![false; target.gt.len()];
        for g in match_greedy(&errors, &valid, threshold)
            .into_iter()
            .flatten()
        {
            matched[g] = true;
        }
        matched
    }

    fn tally(&self, targets: &[&TargetErrors]) -> Tally {
        let mut tally = Tally::default();
        for target in targets {
            let matched = self.matched(target);
            for (instance, hit) in target.gt.iter().zip(matched) {
                if instance.valid {
                    tally.total += 1;
                    tally.matched += hit as usize;
                }
            }
        }
        tally
    }
}

fn mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        0.0
    } else {
        values.iter().sum::<f64>() / values.len() as f64
    }
}

fn object_score(
    obj_id: Option<u32>,
    targets: &[&TargetErrors],
    options: &ScoreOptions,
) -> ObjectScore {
    let recall = |s: Setting| s.tally(targets).recall();
    let recall_bop18 = options
        .bop18_thresholds
        .iter()
        .map(|&threshold| recall(Setting::Bop18 { threshold }))
        .collect();
    let vsd: Vec<f64> = (0..options.vsd_taus.len())
        .flat_map(|tau| {
            options
                .vsd_thresholds
                .iter()
                .map(move |&threshold| Setting::Vsd { tau, threshold })
        })
        .map(recall)
        .collect();
    let mssd: Vec<f64> = options
        .mssd_thresholds
        .iter()
        .map(|&fraction| recall(Setting::Mssd { fraction }))
        .collect();
    let mspd: Vec<f64> = options
        .mspd_thresholds_px
        .iter()
        .map(|&px_at_640| recall(Setting::Mspd { px_at_640 }))
        .collect();
    let (ar_vsd, ar_mssd, ar_mspd) = (mean(&vsd), mean(&mssd), mean(&mspd));
    ObjectScore {
        obj_id,
        targets: targets.len(),
        gt_count: targets
            .iter()
            .map(|t| t.gt.iter().filter(|g| g.valid).count())
            .sum(),
        estimates: targets.iter().map(|t| t.estimates.len()).sum(),
        recall_bop18,
        ar_vsd,
        ar_mssd,
        ar_mspd,
        ar: (ar_vsd + ar_mssd + ar_mspd) / 3.0,
    }
}

/// Matches and counts: the report's scores from the targets' errors (times and file counts are
/// left empty for the caller).
pub fn summarize(targets: &[TargetErrors], options: &ScoreOptions) -> ScoreReport {
    let all: Vec<&TargetErrors> = targets.iter().collect();
    let object_ids: BTreeSet<u32> = targets.iter().map(|t| t.obj_id).collect();
    let objects = object_ids
        .iter()
        .map(|&id| {
            let mine: Vec<&TargetErrors> = all.iter().copied().filter(|t| t.obj_id == id).collect();
            object_score(Some(id), &mine, options)
        })
        .collect();

    let edges = &options.visib_bin_edges;
    let mut visib_bins: Vec<VisibBin> = edges
        .windows(2)
        .map(|w| VisibBin {
            min: w[0],
            max: w[1],
            gt_count: 0,
            recall_bop18: Vec::new(),
        })
        .collect();
    let bin_of = |v: f32| {
        let last = visib_bins.len().checked_sub(1)?;
        (0..visib_bins.len())
            .find(|&b| v >= edges[b] && (v < edges[b + 1] || (b == last && v <= edges[b + 1])))
    };
    let mut hits = vec![vec![0usize; options.bop18_thresholds.len()]; visib_bins.len()];
    let mut counts = vec![0usize; visib_bins.len()];
    for (t, &threshold) in options.bop18_thresholds.iter().enumerate() {
        for target in &all {
            let matched = Setting::Bop18 { threshold }.matched(target);
            for (instance, hit) in target.gt.iter().zip(matched) {
                if !instance.valid {
                    continue;
                }
                if let Some(b) = bin_of(instance.visib_fract) {
                    if t == 0 {
                        counts[b] += 1;
                    }
                    hits[b][t] += hit as usize;
                }
            }
        }
    }
    for (b, bin) in visib_bins.iter_mut().enumerate() {
        bin.gt_count = counts[b];
        bin.recall_bop18 = hits[b]
            .iter()
            .map(|&h| {
                Tally {
                    matched: h,
                    total: counts[b],
                }
                .recall()
            })
            .collect();
    }

    ScoreReport {
        objects,
        overall: object_score(None, &all, options),
        visib_bins,
        bop18_thresholds: options.bop18_thresholds.clone(),
        images: 0,
        skipped_targets: 0,
        first_missing_depth: None,
        notes: Vec::new(),
        estimates_read: 0,
        estimates_ignored: 0,
        mean_time_per_image_s: None,
        mean_time_per_target_s: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate(score: f32, vsd: &[f64], mssd_mm: &[f64], mspd_px: &[f64]) -> EstimateErrors {
        EstimateErrors {
            score,
            vsd_bop18: vsd.to_vec(),
            vsd_bop19: vsd.iter().map(|&e| vec![e; 10]).collect(),
            mssd_mm: mssd_mm.to_vec(),
            mspd_px: mspd_px.to_vec(),
        }
    }

    fn instance(gt_index: usize, visib_fract: f32) -> GtInstance {
        GtInstance {
            gt_index,
            visib_fract,
            valid: visib_fract >= 0.1,
        }
    }

    /// Two instances of object 1 (one barely visible, so it does not count) and one of object 2.
    fn targets() -> Vec<TargetErrors> {
        vec![
            TargetErrors {
                scene_id: 1,
                im_id: 0,
                obj_id: 1,
                inst_count: 1,
                diameter_mm: 100.0,
                image_width: 640,
                gt: vec![instance(0, 0.05), instance(1, 0.8)],
                // Good for instance 1 at every threshold: VSD 0.02, MSSD 1 mm, MSPD 1 px.
                estimates: vec![estimate(0.9, &[0.0, 0.02], &[0.0, 1.0], &[0.0, 1.0])],
            },
            TargetErrors {
                scene_id: 1,
                im_id: 0,
                obj_id: 2,
                inst_count: 1,
                diameter_mm: 200.0,
                image_width: 640,
                gt: vec![instance(2, 0.5)],
                // VSD 0.32: correct at θ 0.35 only; MSSD 25 mm = 0.125 D: correct from 0.15 D
                // (8 of 10 thresholds); MSPD 12 px: correct from 15 px (8 of 10).
                estimates: vec![estimate(0.5, &[0.32], &[25.0], &[12.0])],
            },
        ]
    }

    #[test]
    fn per_object_and_overall_recall() {
        let report = summarize(&targets(), &ScoreOptions::default());
        assert_eq!(report.objects.len(), 2);
        let (one, two) = (&report.objects[0], &report.objects[1]);
        assert_eq!((one.gt_count, one.estimates), (1, 1));
        assert_eq!(one.recall_bop18, vec![1.0, 1.0]);
        assert!((one.ar - 1.0).abs() < 1e-12);
        assert_eq!(two.recall_bop18, vec![0.0, 1.0]);
        // VSD 0.32 passes θ 0.35…0.5: 4 of 10 thresholds, for every τ.
        assert!((two.ar_vsd - 0.4).abs() < 1e-12, "{}", two.ar_vsd);
        assert!((two.ar_mssd - 0.8).abs() < 1e-12, "{}", two.ar_mssd);
        assert!((two.ar_mspd - 0.8).abs() < 1e-12, "{}", two.ar_mspd);
        let all = &report.overall;
        assert_eq!(all.gt_count, 2);
        assert_eq!(all.recall_bop18, vec![0.5, 1.0]);
        assert!((all.ar_vsd - 0.7).abs() < 1e-12);
        assert!((all.ar - (0.7 + 0.9 + 0.9) / 3.0).abs() < 1e-12);
        // Visible-fraction bins: 0.5 falls in [0.5, 0.7), 0.8 in [0.7, 0.9).
        let counts: Vec<usize> = report.visib_bins.iter().map(|b| b.gt_count).collect();
        assert_eq!(counts, vec![0, 0, 1, 1, 0]);
        assert_eq!(report.visib_bins[2].recall_bop18, vec![0.0, 1.0]);
    }

    #[test]
    fn mspd_thresholds_scale_with_image_width() {
        let mut t = targets();
        // Twice as wide: thresholds 10, 20, …, 100 px, and 12 px passes from 20 px: 9 of 10.
        t[1].image_width = 1280;
        let report = summarize(&t, &ScoreOptions::default());
        assert!((report.objects[1].ar_mspd - 0.9).abs() < 1e-12);
    }

    #[test]
    fn an_estimate_matched_to_nothing_counts_nothing() {
        let mut t = targets();
        t[0].estimates = vec![estimate(0.9, &[0.0, 0.9], &[0.0, 90.0], &[0.0, 90.0])];
        let report = summarize(&t, &ScoreOptions::default());
        // It is perfect for the barely visible instance, which cannot be matched.
        assert_eq!(report.objects[0].recall_bop18, vec![0.0, 0.0]);
        assert_eq!(report.objects[0].ar, 0.0);
    }

    #[test]
    fn times_must_agree_within_an_image() {
        let row = |time_s| EstimateRow {
            scene_id: 1,
            im_id: 2,
            obj_id: 3,
            score: 1.0,
            pose: Pose::identity(),
            time_s,
        };
        let times = image_times(&[row(0.5), row(0.5)]).unwrap();
        assert_eq!(times.get(&(1, 2)), Some(&0.5));
        assert!(image_times(&[row(-1.0)]).unwrap().is_empty());
        let e = image_times(&[row(0.5), row(0.6)]).unwrap_err().to_string();
        assert!(e.contains("scene 1 image 2"), "{e}");
    }
}

/// Scoring on images the project's renderer makes: the test depth is a rendering of the ground
/// truth, so perfect estimates must score exactly.
#[cfg(test)]
mod rendered_tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use ppfd_models::geometry::render::{render_scene, Renderer, Roi};
    use ppfd_models::synthetic::parts::Part;

    const W: u32 = 640;
    const H: u32 = 480;

    fn diameter(mesh: &Mesh) -> f32 {
        let p = &mesh.positions;
        let mut best = 0.0f32;
        for (i, a) in p.iter().enumerate() {
            for b in &p[i + 1..] {
                best = best.max((a - b).norm_squared());
            }
        }
        best.sqrt()
    }

    fn object(part: Part) -> EvalObject {
        let mesh = part.mesh();
        let bbox = mesh.bounding_box().unwrap();
        let info = ModelInfo {
            diameter_mm: diameter(&mesh),
            min_mm: bbox.min,
            size_mm: bbox.size(),
            symmetries_discrete: vec![],
            symmetries_continuous: vec![],
        };
        EvalObject::new(part.object_id(), mesh, &info, MAX_SYM_DISC_STEP)
    }

    fn scene() -> (BTreeMap<u32, EvalObject>, EvalImage) {
        let parts = [Part::LBracket, Part::ToothedDisc];
        let objects: BTreeMap<u32, EvalObject> =
            parts.iter().map(|&p| (p.object_id(), object(p))).collect();
        let poses = [
            Pose::from_parts(
                Translation3::new(-90.0, 10.0, 750.0),
                UnitQuaternion::from_euler_angles(0.4, -0.6, 0.3),
            ),
            Pose::from_parts(
                Translation3::new(95.0, -20.0, 800.0),
                UnitQuaternion::from_euler_angles(-0.9, 0.2, 1.0),
            ),
        ];
        let meshes: Vec<(&Mesh, Pose)> = parts
            .iter()
            .zip(&poses)
            .map(|(p, pose)| (&objects[&p.object_id()].mesh, *pose))
            .collect();
        let rendered = render_scene(&meshes, &Intrinsics::LMO, W, H).unwrap();
        let image = EvalImage {
            scene_id: 1,
            im_id: 0,
            width: W,
            height: H,
            intrinsics: Intrinsics::LMO,
            depth_mm: rendered.depth.depth_mm,
            gt: parts
                .iter()
                .zip(&poses)
                .map(|(p, pose)| GtPose {
                    obj_id: p.object_id(),
                    pose: *pose,
                })
                .collect(),
            visib_fract: vec![1.0, 1.0],
            targets: parts.iter().map(|p| (p.object_id(), 1)).collect(),
        };
        (objects, image)
    }

    fn errors_of(estimates: &[EstimateRow]) -> Vec<TargetErrors> {
        let (objects, image) = scene();
        let mut renderer = Renderer::new().cull_back_faces(false);
        let mut render = |mesh: &Mesh, pose: &Pose, k: &Intrinsics, w: u32, h: u32| {
            renderer.render_into(mesh, pose, k, Roi::full(w, h))?;
            Ok(renderer.depth_mm().to_vec())
        };
        let rows: Vec<&EstimateRow> = estimates.iter().collect();
        image_errors(
            &objects,
            &image,
            &rows,
            &ScoreOptions::default(),
            &mut render,
        )
        .unwrap()
    }

    fn estimates(change: impl Fn(&Pose, f32) -> Pose) -> Vec<EstimateRow> {
        let (objects, image) = scene();
        image
            .gt
            .iter()
            .map(|g| EstimateRow {
                scene_id: 1,
                im_id: 0,
                obj_id: g.obj_id,
                score: 1.0,
                pose: change(&g.pose, objects[&g.obj_id].diameter_mm),
                time_s: 0.5,
            })
            .collect()
    }

    #[test]
    fn ground_truth_as_estimate_is_perfect() {
        let targets = errors_of(&estimates(|pose, _| *pose));
        assert_eq!(targets.len(), 2);
        for t in &targets {
            let e = &t.estimates[0];
            assert!(e.vsd_bop18[0].abs() <= 1e-6, "{t:?}");
            assert!(e.vsd_bop19[0].iter().all(|v| v.abs() <= 1e-6), "{t:?}");
            assert!(e.mssd_mm[0] < 1e-9 && e.mspd_px[0] < 1e-9, "{t:?}");
        }
        let report = summarize(&targets, &ScoreOptions::default());
        assert_eq!(report.overall.gt_count, 2);
        assert_eq!(report.overall.recall_bop18, vec![1.0, 1.0]);
        assert_eq!(report.overall.ar, 1.0);
    }

    /// Strictest setting of each BOP 2019 error: VSD τ 0.05 D θ 0.05, MSSD 0.05 D, MSPD 5 px.
    fn correct_at_strictest(t: &TargetErrors) -> [bool; 3] {
        let e = &t.estimates[0];
        let d = t.diameter_mm as f64;
        [
            e.vsd_bop19[0][0] < 0.05,
            e.mssd_mm[0] < 0.05 * d,
            e.mspd_px[0] < 5.0,
        ]
    }

    #[test]
    fn a_pose_shifted_by_a_tenth_of_the_diameter_fails() {
        for (axis, direction) in [("x", Vector3::x()), ("z", Vector3::z())] {
            let targets = errors_of(&estimates(|p, d| {
                Translation3::from(direction * 0.1 * d) * p
            }));
            for t in &targets {
                let mssd = t.estimates[0].mssd_mm[0] / t.diameter_mm as f64;
                assert!(
                    (mssd - 0.1).abs() < 1e-4,
                    "shift along {axis}: MSSD {mssd} D"
                );
                // Along z the projection hardly moves (MSPD ~2 px): only VSD and MSSD see it.
                let expected = [false, false, axis == "z"];
                assert_eq!(
                    correct_at_strictest(t),
                    expected,
                    "shift along {axis}: {t:?}"
                );
            }
            let report = summarize(&targets, &ScoreOptions::default());
            assert!(report.overall.ar < 0.9, "shift along {axis}: {report:?}");
            assert!(
                report.overall.ar_vsd < 0.75,
                "shift along {axis}: {report:?}"
            );
        }
    }

    #[test]
    fn a_pose_turned_by_30_degrees_fails() {
        for axis in [Vector3::x_axis(), Vector3::y_axis()] {
            let turn = UnitQuaternion::from_axis_angle(&axis, 30f32.to_radians());
            let targets = errors_of(&estimates(|p, _| p * turn));
            for t in &targets {
                assert!(t.estimates[0].vsd_bop18[0] > 0.3, "{t:?}");
                assert_eq!(correct_at_strictest(t), [false; 3], "{t:?}");
            }
            let report = summarize(&targets, &ScoreOptions::default());
            assert_eq!(report.overall.recall_bop18[0], 0.0);
            assert!(report.overall.ar < 0.5, "{report:?}");
        }
    }
}

/// Scoring on the real LM-O frame of the shared test data.
#[cfg(test)]
mod lmo_tests {
    use super::*;
    use nalgebra::Translation3;

    fn lmo() -> Option<BopDataset> {
        let dir = crate::shared_test_data("lmo")?;
        Some(BopDataset::open(dir).unwrap())
    }

    fn rows_from(gt: &[GtPose], change: impl Fn(&GtPose) -> Pose) -> Vec<EstimateRow> {
        gt.iter()
            .map(|g| EstimateRow {
                scene_id: 2,
                im_id: 3,
                obj_id: g.obj_id,
                score: 1.0,
                pose: change(g),
                time_s: 2.5,
            })
            .collect()
    }

    #[test]
    fn ground_truth_as_estimates_scores_one() {
        let Some(data) = lmo() else { return };
        let rows = rows_from(data.ground_truth(2, 3).unwrap(), |g| g.pose);
        let report = score_results(&data, &rows, &ScoreOptions::default()).unwrap();
        assert_eq!(report.images, 1);
        assert_eq!(report.overall.targets, 8);
        // The targets file lists 200 images; only image 3 has its depth here.
        assert_eq!(
            report.skipped_targets,
            data.test_targets().unwrap().len() - 8
        );
        let first = report.first_missing_depth.as_deref().unwrap_or_default();
        assert!(first.ends_with("test/000002/depth/000008.png"), "{first}");
        assert_eq!(
            report.overall.gt_count, 8,
            "all eight are at least 20 % visible"
        );
        assert_eq!((report.estimates_read, report.estimates_ignored), (8, 0));
        assert_eq!(report.overall.recall_bop18, vec![1.0, 1.0]);
        assert_eq!(report.overall.ar, 1.0);
        assert!(report.objects.iter().all(|o| o.ar == 1.0));
        assert_eq!(report.mean_time_per_image_s, Some(2.5));
        assert_eq!(report.mean_time_per_target_s, Some(2.5 / 8.0));
    }

    /// A capture of one's own: the LM-O frame with `scene_gt.json` but neither
    /// `scene_gt_info.json` nor `models_info.json`. The ground truth still scores one, the
    /// same eight targets are found from the computed visibility, and the report says what it
    /// computed.
    #[test]
    fn a_dataset_without_visibility_or_model_info_is_scored_with_them_computed() {
        let Some(source) = crate::shared_test_data("lmo") else {
            return;
        };
        let root = std::env::temp_dir().join(format!("ppfd-score-bare-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let scene = root.join("test/000002");
        std::fs::create_dir_all(scene.join("depth")).unwrap();
        std::fs::create_dir_all(root.join("models")).unwrap();
        let link = |from: std::path::PathBuf, to: std::path::PathBuf| {
            std::os::unix::fs::symlink(from, to).unwrap()
        };
        for f in ["scene_camera.json", "scene_gt.json"] {
            link(source.join("test/000002").join(f), scene.join(f));
        }
        link(
            source.join("test/000002/depth/000003.png"),
            scene.join("depth/000003.png"),
        );
        for entry in std::fs::read_dir(source.join("models")).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "ply") {
                link(
                    path.clone(),
                    root.join("models").join(path.file_name().unwrap()),
                );
            }
        }
        let bare = BopDataset::open(&root).unwrap();
        assert!(!bare.has_ground_truth_info(2) && !bare.has_models_info());

        let targets = targets_from_ground_truth(&bare, 0.1).unwrap();
        assert_eq!(
            targets.len(),
            8,
            "all eight are at least 10 % visible: {targets:?}"
        );
        let rows = rows_from(bare.ground_truth(2, 3).unwrap(), |g| g.pose);
        let report = score_results(&bare, &rows, &ScoreOptions::default()).unwrap();
        let _ = std::fs::remove_dir_all(&root);
        assert_eq!(report.overall.targets, 8);
        assert_eq!(report.overall.recall_bop18, vec![1.0, 1.0]);
        assert_eq!(report.overall.ar, 1.0);
        assert_eq!(report.notes.len(), 2, "{:?}", report.notes);
        assert!(
            report.notes[0].contains("scene_gt_info.json"),
            "{:?}",
            report.notes
        );
        assert!(
            report.notes[1].contains("models_info.json"),
            "{:?}",
            report.notes
        );
        // A complete dataset needs no note.
        let data = lmo().unwrap();
        let rows = rows_from(data.ground_truth(2, 3).unwrap(), |g| g.pose);
        let report = score_results(&data, &rows, &ScoreOptions::default()).unwrap();
        assert!(report.notes.is_empty(), "{:?}", report.notes);
    }

    #[test]
    fn wrong_poses_score_nothing_and_extra_estimates_are_ignored() {
        let Some(data) = lmo() else { return };
        let gt = data.ground_truth(2, 3).unwrap();
        // Every object placed 300 mm away from where it is, plus a second, lower-scored,
        // correct estimate that inst_count = 1 leaves out.
        let mut rows = rows_from(gt, |g| Translation3::new(300.0, 0.0, 0.0) * g.pose);
        let mut correct = rows_from(gt, |g| g.pose);
        correct.iter_mut().for_each(|r| r.score = 0.5);
        rows.extend(correct);
        let report = score_results(&data, &rows, &ScoreOptions::default()).unwrap();
        assert_eq!((report.estimates_read, report.estimates_ignored), (16, 8));
        assert_eq!(report.overall.recall_bop18, vec![0.0, 0.0]);
        assert_eq!(report.overall.ar, 0.0);
    }

    /// Results of another dataset name none of this one's images: refused with both sides'
    /// images, where they would score as a detector that found nothing. No results at all
    /// still score zero.
    #[test]
    fn results_for_no_image_with_targets_are_refused_and_none_score_zero() {
        let Some(data) = lmo() else { return };
        let mut rows = rows_from(data.ground_truth(2, 3).unwrap(), |g| g.pose);
        for (i, r) in rows.iter_mut().enumerate() {
            (r.scene_id, r.im_id) = (1, i as u32);
        }
        let e = score_results(&data, &rows, &ScoreOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no estimate is for an image with targets here")
                && e.contains("scene 1 image 0, scene 1 image 1, scene 1 image 2 and 5 more")
                && e.contains("the targets scene 2 image 3;"),
            "{e}"
        );
        let report = score_results(&data, &[], &ScoreOptions::default()).unwrap();
        assert_eq!((report.overall.targets, report.overall.ar), (8, 0.0));
    }

    /// The LM-O frame's files linked into a scratch dataset, with `scene_gt.json` as given (a
    /// link to the real one when `None`) and the depth image only when `depth`.
    fn lmo_copy(name: &str, scene_gt: Option<&str>, depth: bool) -> std::path::PathBuf {
        let source = crate::shared_test_data("lmo").unwrap();
        let root = std::env::temp_dir().join(format!("ppfd-score-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let scene = root.join("test/000002");
        std::fs::create_dir_all(scene.join("depth")).unwrap();
        let link = |from: &str, to: std::path::PathBuf| {
            std::os::unix::fs::symlink(source.join(from), to).unwrap()
        };
        for f in [
            "camera.json",
            "models",
            "models_eval",
            "test_targets_bop19.json",
        ] {
            link(f, root.join(f));
        }
        for f in ["scene_camera.json", "scene_gt_info.json"] {
            link(&format!("test/000002/{f}"), scene.join(f));
        }
        match scene_gt {
            Some(text) => std::fs::write(scene.join("scene_gt.json"), text).unwrap(),
            None => link("test/000002/scene_gt.json", scene.join("scene_gt.json")),
        }
        if depth {
            link(
                "test/000002/depth/000003.png",
                scene.join("depth/000003.png"),
            );
        }
        root
    }

    /// An image with depth must have its ground truth, and some target must have depth: a
    /// malformed `scene_gt.json` or a dataset without depth images is refused by name instead
    /// of scoring as a detector that found nothing.
    #[test]
    fn a_malformed_ground_truth_or_no_depth_at_all_is_refused() {
        let Some(data) = lmo() else { return };
        let rows = rows_from(data.ground_truth(2, 3).unwrap(), |g| g.pose);
        let whole = std::fs::read_to_string(
            crate::shared_test_data("lmo")
                .unwrap()
                .join("test/000002/scene_gt.json"),
        )
        .unwrap();
        let cases = [
            ("cut", Some(&whole[..500]), true, "scene_gt.json"),
            ("other", Some("{\"4\": []}"), true, "no image 3"),
            (
                "nodepth",
                None,
                false,
                "none of the 1445 targets' images has a depth image",
            ),
        ];
        for (name, scene_gt, depth, expected) in cases {
            let root = lmo_copy(name, scene_gt, depth);
            let result = BopDataset::open(&root)
                .and_then(|d| score_results(&d, &rows, &ScoreOptions::default()));
            let _ = std::fs::remove_dir_all(&root);
            let e = result.expect_err(name).to_string();
            assert!(e.contains(expected), "{name}: {e}");
        }
        // The same copy, whole, scores the ground truth as one.
        let root = lmo_copy("whole", None, true);
        let report = score_results(
            &BopDataset::open(&root).unwrap(),
            &rows,
            &ScoreOptions::default(),
        );
        let _ = std::fs::remove_dir_all(&root);
        assert_eq!(report.unwrap().overall.ar, 1.0);
    }

    #[test]
    fn symmetric_objects_turned_by_their_symmetry_pass() {
        let Some(data) = lmo() else { return };
        let gt = data.ground_truth(2, 3).unwrap();
        for obj_id in [10, 11] {
            let info = data.model_info(obj_id).unwrap();
            assert_eq!(info.symmetries_discrete.len(), 1, "object {obj_id}");
            let symmetry = info.symmetries_discrete[0];
            let truth = gt.iter().find(|g| g.obj_id == obj_id).unwrap();
            let turned = truth.pose * symmetry;
            // A half turn: without the symmetry this estimate is far off.
            let mesh = Mesh::from_ply_file(data.eval_model_path(obj_id).unwrap()).unwrap();
            let plain = mssd(
                &turned,
                &truth.pose,
                &mesh.positions,
                &[Isometry3::identity()],
            );
            assert!(
                plain > 0.3 * info.diameter_mm as f64,
                "object {obj_id}: {plain}"
            );

            let rows = rows_from(&[*truth], |_| turned);
            let options = ScoreOptions {
                targets: Some(vec![TestTarget {
                    scene_id: 2,
                    im_id: 3,
                    obj_id,
                    inst_count: 1,
                }]),
                ..ScoreOptions::default()
            };
            let report = score_results(&data, &rows, &options).unwrap();
            let o = &report.overall;
            assert_eq!(o.gt_count, 1);
            assert_eq!((o.ar_mssd, o.ar_mspd), (1.0, 1.0), "object {obj_id}: {o:?}");
            // The symmetry is not exact in the mesh, but the renderings nearly agree.
            assert_eq!(o.recall_bop18, vec![1.0, 1.0], "object {obj_id}: {o:?}");
        }
    }
}
