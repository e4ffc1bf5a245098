//! The detector: runs the whole pipeline on one depth frame for a set of object models.
//!
//! ```text
//! frame ─► scene points (once) ─► subsampled cloud + kd-tree (per diameter group)
//!        ─► per object: voting ─► pose clustering ─► re-scoring ─► ICP ─► filters ─► hypotheses
//! ```
//!
//! With hints ([`RunOptions::hints`]), each hinted object first goes through ICP from its hints,
//! re-scoring and the filters alone, on a scene whose normals are fitted only where the hints
//! project; the full preparation and voting run only for the objects left without an answer.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use crate::geometry::camera::DepthFrame;
use rayon::prelude::*;

use crate::detect::clustering::{cluster_poses, ClusteringParams};
use crate::detect::exclusion::{Claim, ExclusionParams};
use crate::detect::filters::{consistency_off_edges, FilterParams};
use crate::detect::icp::{refine, IcpParams};
use crate::detect::plane::{PlaneParams, SupportingPlane};
use crate::detect::requirements::{Order, Requirements};
use crate::detect::rescoring::{
    prescreen, score_poses, score_refined, FitPoints, Outline, RescoringParams,
};
use crate::detect::scene::{prepare, prepare_within, PreparedScene, SceneImage, SceneParams};
use crate::detect::silhouette::{EdgeMap, SilhouetteFilter};
use crate::detect::voting::{vote_from, Selection, VotingParams};
use crate::geometry::mesh::Mesh;
use crate::geometry::render::{bounding_sphere, Renderer, Roi};
use crate::model::subsample::{OrientedPoints, SubsampleParams};
use crate::model::symmetry::Symmetry;
use crate::model::ObjectModel;
use crate::{Error, Pose, Result};
use nalgebra::Point3;

/// Parameters of the whole detection pipeline, one struct per stage; [`DetectParams::new`] (and
/// `default()`) gives the paper's settings with this project's measured departures.
#[derive(Clone, Debug)]
pub struct DetectParams {
    /// Scene preparation: points and normals from depth (METHOD.md §2.1).
    pub scene: SceneParams,
    /// The supporting plane and other large planes, on which no reference points are taken.
    pub plane: PlaneParams,
    /// Reference points, voting and the accumulator's peaks (METHOD.md §2.3–2.5).
    pub voting: VotingParams,
    /// Pose clustering (METHOD.md §3.1).
    pub clustering: ClusteringParams,
    /// View-dependent re-scoring, before and after ICP (METHOD.md §3.2).
    pub rescoring: RescoringParams,
    /// Projective ICP of the best re-scored poses (METHOD.md §3.3).
    pub icp: IcpParams,
    /// The consistency and silhouette filters, and the depth edge map (METHOD.md §3.4).
    pub filters: FilterParams,
    /// Across objects: a pose on another object's surface gives way (METHOD.md §3.5).
    pub exclusion: ExclusionParams,
    /// Multi-instance output: a hypothesis that puts the model's centre (of its bounding
    /// sphere) within this fraction of the diameter of where a better one puts it is the same
    /// instance and suppressed. Two instances cannot overlap, so their centres lie farther
    /// apart than this for any but thin parts stacked flat; 0 returns every hypothesis,
    /// duplicates of one instance included.
    pub nms_distance_fraction: f32,
    /// Objects whose diameters differ by at most this ratio share one subsampled scene cloud
    /// (with the leaf of the smallest). 1.0 gives every object its own. A leaf smaller than the
    /// object's own 0.05 D costs more pairs than the shared subsampling saves (on the LM-O
    /// frame, 1.25 cast 16 % more votes than 1.0), and it changes what an object votes on:
    /// so only near-equal diameters share. On that frame 1.1 (three pairs of objects share)
    /// took as long as 1.0 (6.84 s and 6.79 s, medians of 3) and lost the glue's best pose to
    /// a wrong one on the egg box (re-scored 0.134 against the true pose's 0.131); the
    /// three closest pairs of its diameters differ by 6.3 to 6.8 %, so 1.05 shares nothing there.
    pub shared_cloud_diameter_ratio: f32,
    /// The scene cloud's voxel leaf as a multiple of the model's (0.05 D). Pairs and votes
    /// fall with its square while the model's table keeps its finer points: at 2 (a leaf of
    /// 0.1 D, one scene point per reference cube) the LM-O frame forms 2.89 M pairs and casts
    /// 249 M votes instead of 15.0 M and 1 308 M, with the same 6 of 8 objects found; 1.4 loses
    /// the glue (docs/METHOD.md §2.2).
    pub scene_leaf_ratio: f32,
    /// How many of the best pose clusters (before re-scoring) each object's result keeps in
    /// [`ObjectDetections::clusters`], for diagnostics and the voting stage's own measure.
    pub clusters_kept: usize,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self::new()
    }
}

impl DetectParams {
    /// Two hypotheses of an object of `diameter_mm` whose centres lie closer than this are one
    /// instance: the request's instance distance, or [`DetectParams::nms_distance_fraction`].
    pub fn instance_distance_mm(&self, requirements: &Requirements, diameter_mm: f32) -> f32 {
        requirements
            .instance_distance_fraction
            .unwrap_or(self.nms_distance_fraction)
            * diameter_mm
    }

    /// The scene clouds a detection of `models` subsamples and which one each model votes on:
    /// models sorted by diameter share a cloud while their diameter is at most
    /// [`DetectParams::shared_cloud_diameter_ratio`] times the first's, whose leaf, scaled by
    /// [`DetectParams::scene_leaf_ratio`], the cloud is subsampled with.
    pub fn scene_clouds(&self, models: &[&ObjectModel]) -> (Vec<SubsampleParams>, Vec<usize>) {
        let (mut groups, cloud_of) = shared_clouds(models, self.shared_cloud_diameter_ratio);
        for g in &mut groups {
            g.leaf_mm *= self.scene_leaf_ratio;
        }
        (groups, cloud_of)
    }

    /// The subsampled clouds of a detection of `models`, with their kd-trees, and which one
    /// each model votes on ([`DetectParams::scene_clouds`]); built side by side from the
    /// points that `planes` hide from none of the models ([`SupportingPlane::drop_hidden`]).
    /// A cloud keeps only the subsampled points that its widest model may vote with: a point
    /// that a plane excludes for it (on the plane, or behind the supporting one) is excluded
    /// for its narrower models too, and voting would only visit it in the kd-tree to skip it.
    /// On the LM-O frame the clouds hold 21 254 points instead of 30 721, with the same
    /// reference points, pairs and votes.
    pub fn prepare_clouds(
        &self,
        points: &OrientedPoints,
        planes: &[SupportingPlane],
        models: &[&ObjectModel],
    ) -> Result<(Vec<PreparedScene>, Vec<usize>)> {
        let (groups, cloud_of) = self.scene_clouds(models);
        let largest = models.iter().map(|m| m.diameter_mm()).fold(0.0, f32::max);
        let in_front = SupportingPlane::drop_hidden(points, planes, largest);
        let points = in_front.as_ref().unwrap_or(points);
        let clouds = groups
            .par_iter()
            .enumerate()
            .map(|(g, sub)| {
                let widest = models
                    .iter()
                    .zip(&cloud_of)
                    .filter(|(_, &c)| c == g)
                    .map(|(m, _)| m.diameter_mm())
                    .fold(0.0, f32::max);
                let excluding: Vec<&SupportingPlane> =
                    planes.iter().filter(|pl| pl.excludes_for(widest)).collect();
                PreparedScene::keeping(points, sub, |p, n| {
                    !excluding.iter().any(|pl| pl.excludes(p, n))
                })
            })
            .collect::<Result<_>>()?;
        Ok((clouds, cloud_of))
    }

    /// The paper's settings and this project's measured defaults.
    pub fn new() -> Self {
        Self {
            nms_distance_fraction: 0.25,
            shared_cloud_diameter_ratio: 1.05,
            clusters_kept: 10,
            scene_leaf_ratio: 2.0,
            scene: SceneParams::default(),
            plane: PlaneParams::default(),
            voting: VotingParams::default(),
            clustering: ClusteringParams::default(),
            rescoring: RescoringParams::default(),
            icp: IcpParams::default(),
            filters: FilterParams::default(),
            exclusion: ExclusionParams::default(),
        }
    }
}

/// Per-call options of [`Detector::detect`]: how many hypotheses to return, what they must
/// satisfy, and when to give up.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// How many hypotheses to return per object, in [`Requirements::order`].
    pub hypotheses_per_object: usize,
    /// What the hypotheses must satisfy, and their order.
    pub requirements: Requirements,
    /// Give up (with [`Error::DeadlineExceeded`]) once this instant has passed.
    pub deadline: Option<Instant>,
    /// Give up (with [`Error::Cancelled`]) once this is set: another thread's way to stop a
    /// detection nobody waits for any more. Like the deadline, it is looked at between stages:
    /// before each object, and between an object's voting and re-scoring.
    pub cancel: Option<Arc<AtomicBool>>,
    /// Poses the requested objects are expected near, any number per object (one per
    /// instance). An object with hints is first looked for from them alone: each is refined by
    /// ICP, re-scored and filtered as a voted pose is, and kept when it passes both filters and
    /// the [`requirements`](RunOptions::requirements) (minimum score, pose restriction, some
    /// of its surface in the region of interest). Only an object with a hint that is not kept
    /// (or with none) goes through voting, and then its kept hints lead its voted hypotheses
    /// (in score order; in distance order all are sorted together). Two hints of one instance
    /// count as one kept and one not.
    pub hints: Vec<Hint>,
}

impl RunOptions {
    /// [`Error::Cancelled`] once [`RunOptions::cancel`] is set, [`Error::DeadlineExceeded`]
    /// once [`RunOptions::deadline`] has passed, each with the time since `start`.
    pub fn check_stop(&self, start: Instant) -> Result<()> {
        if self
            .cancel
            .as_ref()
            .is_some_and(|c| c.load(Ordering::Relaxed))
        {
            return Err(Error::Cancelled {
                elapsed: start.elapsed(),
            });
        }
        match self.deadline {
            Some(d) if Instant::now() > d => Err(Error::DeadlineExceeded {
                elapsed: start.elapsed(),
            }),
            _ => Ok(()),
        }
    }
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            hypotheses_per_object: 5,
            requirements: Requirements::default(),
            deadline: None,
            cancel: None,
            hints: Vec::new(),
        }
    }
}

/// A pose one requested object is expected near: the previous cycle's answer, or the cell's own
/// bookkeeping (see [`RunOptions::hints`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hint {
    /// The object the hint is for: one of the requested models' ids.
    pub object_id: u32,
    /// Model to camera, mm.
    pub pose: Pose,
}

/// Which checks a hypothesis went through and passed (bit set).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Checks(pub u32);

impl Checks {
    /// Re-scored from the camera's view.
    pub const RESCORED: u32 = 1;
    /// Refined by projective ICP.
    pub const REFINED: u32 = 2;
    /// Passed the non-consistent-points filter.
    pub const CONSISTENT: u32 = 4;
    /// Passed the silhouette vs. scene edges filter.
    pub const SILHOUETTE: u32 = 8;
    /// Refined from one of [`RunOptions::hints`], not found by voting.
    pub const HINT: u32 = 16;

    /// Whether `bit` (one of the constants above) is set.
    pub fn has(&self, bit: u32) -> bool {
        self.0 & bit != 0
    }
}

/// One pose hypothesis for one object.
#[derive(Clone, Copy, Debug)]
pub struct Hypothesis {
    /// Model to camera, mm.
    pub pose: Pose,
    /// The final score (votes until re-scoring runs; then the re-scoring's fit score).
    pub score: f32,
    /// Summed votes of the pose cluster.
    pub votes: u32,
    /// The checks the hypothesis went through and passed.
    pub checks: Checks,
}

/// The hypotheses of one object, best first.
#[derive(Clone, Debug)]
pub struct ObjectDetections {
    /// The object's id, as its model carries it.
    pub object_id: u32,
    /// At most [`RunOptions::hypotheses_per_object`], one per instance; those that pass both
    /// filters come first.
    pub hypotheses: Vec<Hypothesis>,
    /// The best pose clusters out of voting, by summed votes (at most
    /// [`DetectParams::clusters_kept`]), with their votes.
    pub clusters: Vec<(Pose, u32)>,
}

/// Wall time per stage, summed over objects. Objects are detected side by side (each stage
/// also runs in parallel within an object), so an object's stage times include waiting for
/// the cores the other objects hold, and their sum can exceed the detection's wall time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimings {
    /// Back-projecting the frame, fitting its normals and finding its large planes.
    pub scene_preparation: Duration,
    /// Subsampling the scene clouds and building their kd-trees.
    pub kd_tree: Duration,
    /// Choosing reference points and voting.
    pub voting: Duration,
    /// Pose clustering.
    pub clustering: Duration,
    /// Re-scoring, before and after ICP.
    pub rescoring: Duration,
    /// Projective ICP.
    pub icp: Duration,
    /// The filters and what they share (silhouette meshes, the edge map), suppression and
    /// exclusion.
    pub filters: Duration,
}

impl StageTimings {
    /// The sum of the stages' times.
    pub fn total(&self) -> Duration {
        self.scene_preparation
            + self.kd_tree
            + self.voting
            + self.clustering
            + self.rescoring
            + self.icp
            + self.filters
    }

    fn add(&mut self, o: &StageTimings) {
        self.scene_preparation += o.scene_preparation;
        self.kd_tree += o.kd_tree;
        self.voting += o.voting;
        self.clustering += o.clustering;
        self.rescoring += o.rescoring;
        self.icp += o.icp;
        self.filters += o.filters;
    }
}

/// Sizes of the work done.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Oriented points back-projected from the frame.
    pub scene_points: u32,
    /// Reference points, summed over objects.
    pub reference_points: u32,
    /// Point pairs that voted, summed over objects.
    pub pairs: u64,
    /// Votes cast (table entries visited), summed over objects.
    pub votes: u64,
    /// Hypotheses (accumulator peaks) before clustering, summed over objects.
    pub hypotheses: u32,
}

/// The result of one detection.
#[derive(Clone, Debug, Default)]
pub struct Detections {
    /// One entry per requested object, in request order.
    pub objects: Vec<ObjectDetections>,
    /// Wall time of the whole detection. The objects' stages run two or more objects at a
    /// time, so `timings` (summed over objects) may exceed it.
    pub elapsed: Duration,
    /// Wall time per stage, summed over objects.
    pub timings: StageTimings,
    /// Sizes of the work done.
    pub counts: Counts,
    /// Per requested object, its own stage timings (scene preparation is shared and counted once
    /// in `timings`).
    pub per_object_timings: Vec<StageTimings>,
    /// Per requested object, its own counts (`scene_points` is its subsampled cloud's size,
    /// shared with objects of near-equal diameter; `counts.scene_points` is the frame's).
    pub per_object_counts: Vec<Counts>,
}

/// Whether `pose` puts the model's centre (`centre`, model coordinates) within `nms_mm` of where
/// a hypothesis of `list` puts it: the same instance.
fn overlaps(list: &[Hypothesis], pose: &Pose, centre: &Point3<f32>, nms_mm: f32) -> bool {
    let at = pose * centre;
    list.iter().any(|h| (h.pose * centre - at).norm() < nms_mm)
}

/// Refuses hints that are not poses of requested objects.
fn check_hints(models: &[&ObjectModel], opts: &RunOptions) -> Result<()> {
    for (i, h) in opts.hints.iter().enumerate() {
        let id = h.object_id;
        if !models.iter().any(|m| m.object_id() == id) {
            let ids: Vec<u32> = models.iter().map(|m| m.object_id()).collect();
            return Err(Error::InvalidParameter(format!(
                "hint {i} is for object {id}, which the detection does not look for (objects \
                 {ids:?})"
            )));
        }
        let t = h.pose.translation.vector;
        let q = h.pose.rotation.quaternion().coords;
        if !t.iter().chain(q.iter()).all(|c| c.is_finite()) {
            return Err(Error::InvalidParameter(format!(
                "hint {i} for object {id} is not a pose: translation {:?} mm, rotation \
                 quaternion {:?} (every value must be finite)",
                t.as_slice(),
                q.as_slice()
            )));
        }
        if (q.norm() - 1.0).abs() > 1e-3 {
            return Err(Error::InvalidParameter(format!(
                "hint {i} for object {id} is not a rotation: its quaternion has norm {} \
                 (a rotation's is 1)",
                q.norm()
            )));
        }
    }
    Ok(())
}

/// One object's first answer and the poses that may stand in for it (its further answers that
/// passed the filters, then spares beyond them), with the scene cells each confirms
/// ([`crate::detect::exclusion`]).
struct Contest {
    first: Claim,
    spare: Vec<(Hypothesis, Claim)>,
}

/// Per object (by index) whose first answer another object's first explains away, the first of
/// its spares that no other object's first explains away. Every first is judged against the
/// others' firsts as they came out, so the outcome does not depend on the objects' order.
fn stand_ins(contests: &[(usize, &Contest)], min_shared_fraction: f32) -> Vec<(usize, Hypothesis)> {
    let explained = |i: usize, claim: &Claim| {
        contests
            .iter()
            .any(|(j, other)| *j != i && claim.explained_by(&other.first, min_shared_fraction))
    };
    contests
        .iter()
        .filter(|(i, c)| explained(*i, &c.first))
        .filter_map(|(i, c)| {
            c.spare
                .iter()
                .find(|(_, claim)| !explained(*i, claim))
                .map(|(h, _)| (*i, *h))
        })
        .collect()
}

/// The clusters' poses as they were averaged, each the equivalent of its seed's (a voted pose)
/// that the scene supports: re-scoring, ICP and the filters fit the model there. The canonical
/// pose (METHOD.md §1.8) is only what is reported and what the request's pose restriction
/// judges: a real part is symmetric only nearly, and ICP from an equivalent pose fits it worse.
fn clusters_as_poses(clusters: &[crate::detect::clustering::PoseCluster]) -> Vec<(Pose, u32)> {
    clusters.iter().map(|c| (c.pose, c.votes)).collect()
}

/// Which subsampled scene clouds a detection of `models` builds, and which of them each model
/// votes on: models sorted by diameter, a model whose diameter is at most
/// `diameter_ratio` times the first of the current group's joins it (with that one's leaf),
/// and any other starts a new group (see [`DetectParams::shared_cloud_diameter_ratio`]).
fn shared_clouds(
    models: &[&ObjectModel],
    diameter_ratio: f32,
) -> (Vec<SubsampleParams>, Vec<usize>) {
    let mut order: Vec<usize> = (0..models.len()).collect();
    order.sort_by(|&a, &b| models[a].diameter_mm().total_cmp(&models[b].diameter_mm()));
    let mut cloud_of = vec![0usize; models.len()];
    let mut groups: Vec<SubsampleParams> = Vec::new();
    let mut group_start_diameter = f32::NAN;
    for &i in &order {
        let d = models[i].diameter_mm();
        if groups.is_empty() || d > group_start_diameter * diameter_ratio {
            group_start_diameter = d;
            groups.push(models[i].params().subsample_params(d));
        }
        cloud_of[i] = groups.len() - 1;
    }
    (groups, cloud_of)
}

/// Runs detections; holds only parameters, so one detector serves any set of models.
#[derive(Clone, Debug)]
pub struct Detector {
    params: DetectParams,
}

impl Default for Detector {
    fn default() -> Self {
        Self::new(DetectParams::new())
    }
}

impl Detector {
    /// A detector that runs with `params`.
    pub fn new(params: DetectParams) -> Self {
        Self { params }
    }

    /// The parameters it runs with.
    pub fn params(&self) -> &DetectParams {
        &self.params
    }

    /// Detects each of `models` in `frame`; objects with [`RunOptions::hints`] from those first.
    pub fn detect(
        &self,
        frame: &DepthFrame,
        models: &[&ObjectModel],
        opts: &RunOptions,
    ) -> Result<Detections> {
        if models.is_empty() {
            return Err(Error::InvalidParameter("no objects requested".into()));
        }
        if opts.hypotheses_per_object == 0 {
            return Err(Error::InvalidParameter(
                "hypotheses_per_object must be at least 1".into(),
            ));
        }
        frame.validate()?;
        opts.requirements.check(frame.width, frame.height)?;
        check_hints(models, opts)?;
        let start = Instant::now();
        let n = models.len();
        let mut out = Detections {
            per_object_timings: vec![StageTimings::default(); n],
            per_object_counts: vec![Counts::default(); n],
            ..Default::default()
        };
        let mut objects: Vec<Option<ObjectDetections>> = vec![None; n];
        // Per object, the hints it kept when some were not: they lead its voted hypotheses.
        let mut kept_hints: Vec<Vec<Hypothesis>> = vec![Vec::new(); n];

        if !opts.hints.is_empty() {
            let t = Instant::now();
            let rois = self.hint_rois(frame, models, &opts.hints);
            let image = prepare_within(frame, &self.params.scene, &rois)?;
            out.timings.scene_preparation += t.elapsed();
            out.counts.scene_points =
                image.normals.iter().filter(|n| n.x.is_finite()).count() as u32;
            let edges = OnceLock::new();
            for (i, model) in models.iter().enumerate() {
                let hints: Vec<(Pose, u32)> = opts
                    .hints
                    .iter()
                    .filter(|h| h.object_id == model.object_id())
                    .map(|h| (h.pose, 0))
                    .collect();
                if hints.is_empty() {
                    continue;
                }
                opts.check_stop(start)?;
                let timings = &mut out.per_object_timings[i];
                let kept = self.refine_hints(model, &hints, &image, &edges, opts, timings);
                if kept.len() >= hints.len().min(opts.hypotheses_per_object) {
                    objects[i] = Some(ObjectDetections {
                        object_id: model.object_id(),
                        hypotheses: kept,
                        clusters: Vec::new(),
                    });
                } else {
                    kept_hints[i] = kept;
                }
            }
        }

        let voters: Vec<usize> = (0..n).filter(|&i| objects[i].is_none()).collect();
        if !voters.is_empty() {
            opts.check_stop(start)?;
            let t = Instant::now();
            let scene_image = prepare(frame, &self.params.scene)?;
            let points = scene_image.oriented_points();
            let planes = SupportingPlane::find_all(&points, &self.params.plane);
            out.timings.scene_preparation += t.elapsed();
            out.counts.scene_points = points.len() as u32;

            let voting_models: Vec<&ObjectModel> = voters.iter().map(|&i| models[i]).collect();
            opts.check_stop(start)?;
            let t = Instant::now();
            let (clouds, cloud_of) =
                self.params
                    .prepare_clouds(&points, &planes, &voting_models)?;
            out.timings.kd_tree += t.elapsed();

            let edges = OnceLock::new();
            #[allow(clippy::type_complexity)]
            let done: Vec<(
                usize,
                ObjectDetections,
                StageTimings,
                Counts,
                Option<Contest>,
            )> = voters
                .par_iter()
                .enumerate()
                .map(|(j, &i)| {
                    let model = models[i];
                    opts.check_stop(start)?;
                    let scene = &clouds[cloud_of[j]];
                    let mut timings = out.per_object_timings[i];
                    let t = Instant::now();
                    let region = opts
                        .requirements
                        .region
                        .as_ref()
                        .map(|r| (r, &frame.intrinsics));
                    let selection = Selection::within(
                        scene,
                        &self.params.voting,
                        &planes,
                        model.diameter_mm(),
                        region,
                    );
                    let (raw, counts) = vote_from(model, scene, &selection, &self.params.voting);
                    timings.voting += t.elapsed();
                    let t = Instant::now();
                    let symmetry = model.symmetry();
                    let clusters = cluster_poses(
                        &raw,
                        model.diameter_mm(),
                        &symmetry,
                        &self.params.clustering,
                    );
                    timings.clustering += t.elapsed();
                    let own = Counts {
                        scene_points: scene.points.len() as u32,
                        reference_points: counts.reference_points,
                        pairs: counts.pairs,
                        votes: counts.votes,
                        hypotheses: raw.len() as u32,
                    };
                    let clusters = clusters_as_poses(&clusters);
                    opts.check_stop(start)?;
                    let kept = kept_hints[i].clone();
                    let (hypotheses, contest) = self.after_voting(
                        model,
                        &clusters,
                        kept,
                        &scene_image,
                        &edges,
                        opts,
                        voters.len() > 1,
                        &mut timings,
                    );
                    let detections = ObjectDetections {
                        object_id: model.object_id(),
                        hypotheses,
                        clusters: clusters
                            .iter()
                            .take(self.params.clusters_kept)
                            .map(|&(pose, votes)| (symmetry.canonical(&pose), votes))
                            .collect(),
                    };
                    Ok((i, detections, timings, own, contest))
                })
                .collect::<Result<_>>()?;
            let contests: Vec<(usize, &Contest)> = done
                .iter()
                .filter_map(|(i, _, _, _, c)| c.as_ref().map(|c| (*i, c)))
                .collect();
            let stand_ins = stand_ins(&contests, self.params.exclusion.min_shared_fraction);
            for (i, mut detections, timings, own, _) in done {
                if let Some(h) = stand_ins.iter().find(|(j, _)| *j == i).map(|(_, h)| *h) {
                    // The stand-in leads; the pose that gave way stays next, as the others do.
                    let list = &mut detections.hypotheses;
                    list.retain(|o| o.pose != h.pose);
                    list.insert(0, h);
                    list.truncate(opts.hypotheses_per_object);
                }
                out.counts.reference_points += own.reference_points;
                out.counts.pairs += own.pairs;
                out.counts.votes += own.votes;
                out.counts.hypotheses += own.hypotheses;
                out.per_object_counts[i] = own;
                out.per_object_timings[i] = timings;
                objects[i] = Some(detections);
            }
        }
        for t in &out.per_object_timings {
            out.timings.add(t);
        }
        out.objects = objects.into_iter().flatten().collect();
        out.elapsed = start.elapsed();
        Ok(out)
    }

    /// The pixels the hints' objects can cover once ICP has moved them: each model's bounding
    /// sphere at its hint, widened by the farthest ICP moves a surface point
    /// ([`IcpParams::max_travel_mm`]). ICP and re-scoring look normals up nowhere else.
    fn hint_rois(&self, frame: &DepthFrame, models: &[&ObjectModel], hints: &[Hint]) -> Vec<Roi> {
        hints
            .iter()
            .filter_map(|h| {
                let model = models.iter().find(|m| m.object_id() == h.object_id)?;
                let (centre, radius) = bounding_sphere(&self.silhouette_mesh(model));
                let reach = radius + self.params.icp.max_travel_mm(model.diameter_mm());
                Roi::around_sphere(
                    &(h.pose * centre),
                    reach,
                    &frame.intrinsics,
                    frame.width,
                    frame.height,
                )
            })
            .collect()
    }

    /// The simplified mesh whose outline re-scoring and the silhouette filter measure.
    fn silhouette_mesh(&self, model: &ObjectModel) -> Arc<Mesh> {
        model.silhouette_mesh(
            self.params.rescoring.silhouette_mesh_cell_fraction * model.diameter_mm(),
        )
    }

    /// The hints of one object that pass ICP, re-scoring, the filters and the requirements, in
    /// the order asked for, one per instance, marked [`Checks::HINT`].
    fn refine_hints(
        &self,
        model: &ObjectModel,
        hints: &[(Pose, u32)],
        scene: &SceneImage,
        edges: &OnceLock<EdgeMap>,
        opts: &RunOptions,
        timings: &mut StageTimings,
    ) -> Vec<Hypothesis> {
        let v = self.verification(model, scene, edges, timings);
        let (kept, _) = self.refine_and_filter(&v, hints, Vec::new(), scene, opts, timings, 0);
        let t = Instant::now();
        let mut kept = self.answer(kept, Vec::new(), &v, opts);
        timings.filters += t.elapsed();
        for h in &mut kept {
            h.checks.0 |= Checks::HINT;
        }
        kept
    }

    /// What the stages after voting need of one object, made once per object: its surface
    /// points, its silhouette mesh and that mesh's bounding sphere, and the scene's depth edges
    /// (made at the first object's call).
    fn verification<'a>(
        &self,
        model: &ObjectModel,
        scene: &SceneImage,
        edges: &'a OnceLock<EdgeMap>,
        timings: &mut StageTimings,
    ) -> Verification<'a> {
        let t = Instant::now();
        let mesh = self.silhouette_mesh(model);
        let sphere = bounding_sphere(&mesh);
        let edges = edges.get_or_init(|| EdgeMap::new(scene, &self.params.filters));
        timings.filters += t.elapsed();
        let d = model.diameter_mm();
        let symmetry = model.symmetry();
        let surface = model.surface_points();
        Verification {
            fit_points: FitPoints::new(&surface, &self.params.rescoring, d),
            surface,
            mesh,
            centre: symmetry.fixed_point(&sphere.0),
            sphere,
            symmetry,
            edges,
            diameter_mm: d,
            conflict_mm: self.params.rescoring.conflict_mm(d),
        }
    }

    /// Re-scoring of the best clusters, then ICP on the best of those, scoring again, the
    /// filters and non-maximum suppression (METHOD.md §3.2–3.5). `leading` (hints the object
    /// kept) come first, and the voted poses of their instances are suppressed. With
    /// `contested` (other objects voted too), the answer comes with its contest for the
    /// exclusion across objects.
    #[allow(clippy::too_many_arguments)]
    fn after_voting(
        &self,
        model: &ObjectModel,
        clusters: &[(Pose, u32)],
        leading: Vec<Hypothesis>,
        scene: &SceneImage,
        edges: &OnceLock<EdgeMap>,
        opts: &RunOptions,
        contested: bool,
        timings: &mut StageTimings,
    ) -> (Vec<Hypothesis>, Option<Contest>) {
        let p = &self.params;
        let v = self.verification(model, scene, edges, timings);
        let d = v.diameter_mm;
        let coarse_outline = Outline {
            max_outline_px: p.rescoring.coarse_outline(p.filters.max_outline_px),
            ..v.outline(p.filters.max_outline_px)
        };
        let t = Instant::now();
        let wanted = &opts.requirements;
        // Poses a gripper cannot take leave before re-scoring, so that its budget goes to
        // those it can; ICP moves a pose a little, so the final ones are checked again below.
        let allowed: Vec<(Pose, u32)>;
        let clusters = if wanted.pose_restriction.is_some() {
            allowed = clusters
                .iter()
                .filter(|(pose, _)| wanted.allows(&v.symmetry.canonical(pose)))
                .copied()
                .collect();
            &allowed[..]
        } else {
            clusters
        };
        let top = &clusters[..clusters.len().min(p.rescoring.top_clusters)];
        let (top, sparse_fits) = prescreen(
            top,
            &v.fit_points,
            scene,
            p.rescoring.tolerance_mm(d),
            v.conflict_mm,
            &p.rescoring,
        );
        // Only the best `top_poses` go on to ICP.
        let scored = score_poses(
            &top,
            &v.fit_points,
            sparse_fits.as_deref(),
            scene,
            p.rescoring.tolerance_mm(d),
            v.conflict_mm,
            &p.rescoring,
            &coarse_outline,
            p.icp.top_poses,
        );
        timings.rescoring += t.elapsed();
        let candidates: Vec<(Pose, u32)> = scored[..scored.len().min(p.icp.top_poses)]
            .iter()
            .map(|s| (s.pose, s.votes))
            .collect();
        // Spare poses that passed, to stand in for the first should it give way to another
        // object's (exclusion, among several objects and in score order only).
        let exclusion =
            contested && p.exclusion.enabled() && opts.requirements.order == Order::Score;
        let spares = if exclusion { p.exclusion.alternates } else { 0 };
        let (mut passed, failed) =
            self.refine_and_filter(&v, &candidates, leading, scene, opts, timings, spares);
        let t = Instant::now();
        // Nearest first sorts every pose that passed before it keeps the number asked for.
        let spare = if exclusion {
            passed.split_off(passed.len().min(opts.hypotheses_per_object))
        } else {
            Vec::new()
        };
        let out = self.answer(passed, failed, &v, opts);
        let all = Checks::CONSISTENT | Checks::SILHOUETTE;
        let contest = out
            .first()
            .filter(|h| exclusion && h.checks.0 & all == all && h.checks.0 & Checks::HINT == 0)
            .map(|h| {
                let claim = |pose: &Pose| {
                    Claim::new(
                        &v.surface,
                        pose,
                        scene,
                        p.rescoring.refined_tolerance_mm(d),
                        v.conflict_mm,
                        p.rescoring.max_normal_angle_deg,
                    )
                };
                Contest {
                    first: claim(&h.pose),
                    spare: out[1..]
                        .iter()
                        .filter(|s| s.checks.0 & all == all)
                        .chain(&spare)
                        .map(|s| (*s, claim(&s.pose)))
                        .collect(),
                }
            });
        timings.filters += t.elapsed();
        (out, contest)
    }

    fn instance_distance_mm(&self, opts: &RunOptions, diameter_mm: f32) -> f32 {
        self.params
            .instance_distance_mm(&opts.requirements, diameter_mm)
    }

    /// One object's answer from the hypotheses that passed both filters and those that did
    /// not, in the order asked for, at most [`RunOptions::hypotheses_per_object`]. Poses that
    /// failed a filter still fill the list, after those that passed, with their checks saying
    /// so: those that passed one filter before those that passed none, each group in the order
    /// asked for (the sorts are stable).
    fn answer(
        &self,
        mut passed: Vec<Hypothesis>,
        mut failed: Vec<Hypothesis>,
        v: &Verification,
        opts: &RunOptions,
    ) -> Vec<Hypothesis> {
        let n = opts.hypotheses_per_object;
        if opts.requirements.order == Order::Distance {
            let distance = |h: &Hypothesis| (h.pose * v.centre).coords.norm();
            passed.sort_by(|a, b| distance(a).total_cmp(&distance(b)));
            failed.sort_by(|a, b| distance(a).total_cmp(&distance(b)));
        }
        passed.truncate(n);
        let all = Checks::CONSISTENT | Checks::SILHOUETTE;
        failed.sort_by_key(|h| std::cmp::Reverse((h.checks.0 & all).count_ones()));
        let nms = self.instance_distance_mm(opts, v.diameter_mm);
        let mut out = passed;
        for h in failed {
            if out.len() == n {
                break;
            }
            if !overlaps(&out, &h.pose, &v.centre, nms) {
                out.push(h);
            }
        }
        out
    }

    /// ICP from each of `poses` (with their votes), re-scoring, and the filters in score order
    /// with non-maximum suppression after `passed` (hypotheses already kept), leaving out poses
    /// the requirements refuse (below the minimum score, outside the pose restriction, or with
    /// none of the model's surface in the region of interest): the hypotheses that pass both
    /// filters, appended to `passed` (in score order up to
    /// [`RunOptions::hypotheses_per_object`]), and those that do not. The stages a voted pose
    /// goes through after its first re-scoring, and all a hint goes through. Poses are fitted as
    /// given, and each hypothesis holds the canonical one of its refined pose (METHOD.md §1.8).
    #[allow(clippy::too_many_arguments)]
    fn refine_and_filter(
        &self,
        v: &Verification,
        poses: &[(Pose, u32)],
        mut passed: Vec<Hypothesis>,
        scene: &SceneImage,
        opts: &RunOptions,
        timings: &mut StageTimings,
        spares: usize,
    ) -> (Vec<Hypothesis>, Vec<Hypothesis>) {
        let p = &self.params;
        let d = v.diameter_mm;
        let t = Instant::now();
        let refined: Vec<(Pose, u32, f32)> = poses
            .par_iter()
            .map(|&(pose, votes)| {
                let r = refine(&v.surface, &pose, scene, d, &p.icp);
                (r.pose, votes, r.residual_mm(&p.icp, d))
            })
            .collect();
        timings.icp += t.elapsed();

        let t = Instant::now();
        let rescored = score_refined(
            &refined,
            &v.fit_points,
            scene,
            p.rescoring.refined_tolerance_mm(d),
            v.conflict_mm,
            &p.rescoring,
            &v.outline(p.filters.max_outline_px),
        );
        timings.rescoring += t.elapsed();

        let t = Instant::now();
        let mut renderer = Renderer::new();
        let silhouette = SilhouetteFilter {
            mesh: &v.mesh,
            sphere: &v.sphere,
            surface: &v.surface,
            scene,
            edges: v.edges,
            occlusion_tolerance_mm: v.conflict_mm,
            surface_tolerance_mm: p.rescoring.refined_tolerance_mm(d),
            min_visible: p.rescoring.min_visible_outline,
            min_fraction: p.filters.min_silhouette_fraction,
        };
        let wanted = &opts.requirements;
        let nms = self.instance_distance_mm(opts, d);
        let mut failed: Vec<Hypothesis> = Vec::new();
        let all = Checks::CONSISTENT | Checks::SILHOUETTE;
        for s in rescored.iter().take(p.filters.max_candidates) {
            // Nearest first needs every instance that passes, not the first `n`.
            if passed.len() >= opts.hypotheses_per_object + spares && wanted.order == Order::Score {
                break;
            }
            // Fitted where the scene supports it, reported canonical (METHOD.md §1.8); the
            // equivalents are one instance, at one distance (`v.centre`).
            let reported = v.symmetry.canonical(&s.pose);
            let refused = wanted.refusal(
                s.score,
                &s.pose,
                &reported,
                &scene.intrinsics,
                &v.surface.positions,
            );
            if refused.is_some() || overlaps(&passed, &s.pose, &v.centre, nms) {
                continue;
            }
            let mut checks = Checks(Checks::RESCORED | Checks::REFINED);
            let (consistent, _) = consistency_off_edges(
                &s.fit,
                &v.surface,
                &s.pose,
                scene,
                v.edges,
                v.conflict_mm,
                &p.filters,
            );
            if consistent {
                checks.0 |= Checks::CONSISTENT;
            }
            if silhouette.passes(silhouette.fraction(s.outline, &mut renderer, &s.pose)) {
                checks.0 |= Checks::SILHOUETTE;
            }
            let h = Hypothesis {
                pose: reported,
                score: s.score,
                votes: s.votes,
                checks,
            };
            if checks.0 & all == all {
                passed.push(h);
            } else {
                failed.push(h);
            }
        }
        timings.filters += t.elapsed();
        (passed, failed)
    }
}

/// One object's share of the stages after voting ([`Detector::verification`]).
struct Verification<'a> {
    /// The surface points in the model's order: what ICP fits and the region test reads.
    surface: OrientedPoints,
    /// The same points as re-scoring counts them.
    fit_points: FitPoints,
    mesh: Arc<Mesh>,
    sphere: (Point3<f32>, f32),
    /// The bounding sphere's centre moved onto what the object's symmetries leave in place
    /// ([`Symmetry::fixed_point`]): equivalent poses put it at one place, so they are one
    /// instance, at one distance from the camera.
    centre: Point3<f32>,
    symmetry: Symmetry,
    edges: &'a EdgeMap,
    diameter_mm: f32,
    conflict_mm: f32,
}

impl Verification<'_> {
    fn outline(&self, max_outline_px: u32) -> Outline<'_> {
        Outline {
            mesh: self.mesh.as_ref(),
            sphere: &self.sphere,
            edges: self.edges,
            max_outline_px,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ModelParams;
    use crate::synthetic::parts::Part;

    /// A cancel flag set before the call (as the daemon sets it when the client is gone) stops
    /// the detection at its first look, with `Cancelled`; unset, the same call detects.
    #[test]
    fn a_cancelled_detection_stops_with_cancelled() {
        let part = Part::LBracket;
        let model =
            ObjectModel::build(&part.mesh(), 1, part.name(), &ModelParams::default()).unwrap();
        let pose = Pose::from_parts(
            nalgebra::Translation3::new(0.0, 0.0, 700.0),
            nalgebra::UnitQuaternion::identity(),
        );
        let scene = crate::synthetic::scene::SyntheticScene::single(&part.mesh(), 1, pose, None, 1)
            .unwrap();
        let detector = Detector::new(DetectParams::new());
        let cancel = Arc::new(AtomicBool::new(true));
        let opts = RunOptions {
            cancel: Some(cancel.clone()),
            ..Default::default()
        };
        let frame = scene.frame.view();
        match detector.detect(&frame, &[&model], &opts) {
            Err(Error::Cancelled { .. }) => {}
            other => panic!("expected Cancelled, got {other:?}"),
        }
        cancel.store(false, Ordering::Relaxed);
        let found = detector.detect(&frame, &[&model], &opts).unwrap();
        assert_eq!(found.objects.len(), 1);
    }

    #[test]
    fn objects_share_a_cloud_only_within_the_diameter_ratio() {
        let build = |part: Part, id: u32| {
            ObjectModel::build(&part.mesh(), id, part.name(), &ModelParams::default()).unwrap()
        };
        let models = [
            build(Part::LBracket, 1),
            build(Part::ToothedDisc, 2),
            build(Part::LBracket, 3),
            build(Part::TPipe, 4),
        ];
        let refs: Vec<&ObjectModel> = models.iter().collect();
        let d: Vec<f32> = models.iter().map(|m| m.diameter_mm()).collect();
        let leaf = |m: &ObjectModel| m.params().leaf_fraction * m.diameter_mm();

        // Equal diameters share even at 1.0; different ones do not.
        let (groups, cloud_of) = shared_clouds(&refs, 1.0);
        let distinct = {
            let mut v = d.clone();
            v.sort_by(f32::total_cmp);
            v.dedup();
            v.len()
        };
        assert_eq!(groups.len(), distinct, "{d:?}");
        assert_eq!(cloud_of[0], cloud_of[2]);
        for (i, m) in models.iter().enumerate() {
            assert_eq!(groups[cloud_of[i]].leaf_mm, leaf(m), "{i}");
        }

        // A ratio above every pair's: one cloud, with the smallest object's leaf.
        let (groups, cloud_of) = shared_clouds(&refs, 100.0);
        assert_eq!(groups.len(), 1);
        assert!(cloud_of.iter().all(|&g| g == 0));
        let smallest = models
            .iter()
            .min_by(|a, b| a.diameter_mm().total_cmp(&b.diameter_mm()))
            .unwrap();
        assert_eq!(groups[0].leaf_mm, leaf(smallest));

        // Just below the ratio of the two closest distinct diameters: they stay apart.
        let mut sorted = d.clone();
        sorted.sort_by(f32::total_cmp);
        sorted.dedup();
        let closest = sorted
            .windows(2)
            .map(|w| w[1] / w[0])
            .fold(f32::INFINITY, f32::min);
        let (apart, _) = shared_clouds(&refs, closest * 0.999);
        let (together, _) = shared_clouds(&refs, closest * 1.001);
        assert_eq!(apart.len(), distinct);
        assert_eq!(together.len(), distinct - 1);
    }
}
