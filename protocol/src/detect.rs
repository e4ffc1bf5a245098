//! The detect request/response on `ppfd/detect`: a request names a camera (or carries a frame
//! inline) and the objects wanted; the response carries pose hypotheses, a status, and where the
//! time went.

use iceoryx2::prelude::ZeroCopySend;

use crate::frame::FrameHeader;
use crate::{
    text, ProtocolError, CAMERA_NAME_BYTES, DIAGNOSIS_BYTES, MAX_HINTS_PER_REQUEST,
    MAX_HYPOTHESES_PER_OBJECT, MAX_OBJECTS_PER_REQUEST, MESSAGE_BYTES, PROTOCOL_VERSION,
};

/// Bits of [`DetectRequestHeader::flags`].
pub mod flags {
    /// The depth frame travels in the request's `[u16]` payload, described by
    /// [`super::DetectRequestHeader::inline_frame`]; the camera name is ignored.
    pub const INLINE_FRAME: u32 = 1 << 0;
    /// Diagnose: the entries of [`super::DetectRequestHeader::hints`] are not hints but the
    /// poses the objects are believed at. The detection runs from scratch, and for each object
    /// with such a pose (the first given for it) the response's
    /// [`super::DetectResponseHeader::diagnosis`] says after each stage where the best candidate
    /// near that pose stands, and at which stage it was lost. The stages run a second time,
    /// one by one, for this: a diagnosing request takes about twice as long.
    pub const DIAGNOSE: u32 = 1 << 1;
    /// Every bit this protocol version knows; a request with any other bit set is refused.
    pub const KNOWN: u32 = INLINE_FRAME | DIAGNOSE;
}

/// Bits of [`PoseHypothesis::checks`]: which verification stages a hypothesis passed.
pub mod checks {
    /// Re-scored against the scene from the camera's view.
    pub const RESCORED: u32 = 1;
    /// Refined by ICP.
    pub const REFINED: u32 = 2;
    /// Passed the geometric consistency filter.
    pub const CONSISTENT: u32 = 4;
    /// Passed the silhouette (occlusion/boundary) filter.
    pub const SILHOUETTE: u32 = 8;
    /// Refined from one of the request's hints ([`super::PoseHint`]), not found by voting.
    pub const HINT: u32 = 16;
}

/// The user header of a detect request. The payload is a `[u16]` slice: empty when the request
/// names a camera, the depth frame when [`flags::INLINE_FRAME`] is set.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::DetectRequestHeader")]
#[repr(C)]
pub struct DetectRequestHeader {
    /// [`PROTOCOL_VERSION`] of the client.
    pub protocol_version: u32,
    /// [`flags`] bits.
    pub flags: u32,
    /// Chosen by the client; echoed in the response.
    pub request_id: u64,
    /// Names the client's listener on `ppfd/responses`, which the daemon wakes when the answer
    /// is sent ([`crate::services::reply_listener_name`]); 0 for a client that polls.
    pub reply_token: u64,
    /// When the client sent the request: `CLOCK_MONOTONIC`, nanoseconds.
    pub send_time_ns: u64,
    /// Absolute deadline, `CLOCK_MONOTONIC` nanoseconds; 0 for none. A request still queued at
    /// its deadline is answered [`Status::DeadlineExceeded`]; a detection running past it stops
    /// before its next object (or between an object's voting and re-scoring) and is answered
    /// [`Status::DeadlineExceeded`] too, without the objects it had finished.
    /// The client library stops waiting at the deadline.
    pub deadline_ns: u64,
    /// Oldest acceptable camera frame, nanoseconds of age at the start of detection; 0 for the
    /// daemon's default. An older frame is refused with [`Status::CameraStale`].
    pub max_frame_age_ns: u64,
    /// Camera to read the newest frame of, NUL-padded UTF-8.
    pub camera_name: [u8; CAMERA_NAME_BYTES],
    /// Geometry of the inline frame when [`flags::INLINE_FRAME`] is set (its camera name and
    /// sequence are informative only).
    pub inline_frame: FrameHeader,
    /// Number of valid entries of `object_ids`, 1 to [`MAX_OBJECTS_PER_REQUEST`].
    pub object_count: u32,
    /// Best hypotheses wanted per object, 1 to [`MAX_HYPOTHESES_PER_OBJECT`].
    pub hypotheses_per_object: u32,
    /// Object ids wanted (the ids of the loaded models); only the first `object_count` count.
    pub object_ids: [u32; MAX_OBJECTS_PER_REQUEST],
    /// What the hypotheses must satisfy, and their order.
    pub requirements: Requirements,
    /// Number of valid entries of `hints`, 0 to [`MAX_HINTS_PER_REQUEST`].
    pub hint_count: u32,
    /// Zero.
    pub reserved: u32,
    /// Poses the requested objects are expected near (only the first `hint_count` count). An
    /// object with hints is first looked for from them alone: ICP from each, re-scoring, the
    /// filters and the `requirements`, as a voted pose goes through. Only an object with a hint
    /// that fails (or with none) goes through voting.
    pub hints: [PoseHint; MAX_HINTS_PER_REQUEST],
}

/// Values of [`Requirements::order`].
pub mod order {
    /// Best score first.
    pub const SCORE: u32 = 0;
    /// Nearest to the camera first (the distance of the model's centre from the camera).
    pub const DISTANCE: u32 = 1;
}

/// Largest [`Requirements::instance_distance_fraction`], diameters.
pub const MAX_INSTANCE_DISTANCE_FRACTION: f32 = 2.0;

/// A pixel rectangle of the frame: columns `x .. x + width`, rows `y .. y + height`, pixels.
/// A width and height of 0 is the whole frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("ppfd::RegionOfInterest")]
#[repr(C)]
pub struct RegionOfInterest {
    /// First column, pixels.
    pub x: u32,
    /// First row, pixels.
    pub y: u32,
    /// Columns, pixels; 0 with `height` 0 for the whole frame.
    pub width: u32,
    /// Rows, pixels.
    pub height: u32,
}

impl RegionOfInterest {
    /// Whether this is the whole frame (no region).
    pub fn is_whole_frame(&self) -> bool {
        *self == RegionOfInterest::default()
    }
}

/// Bin picking's pose restriction: the angle between `model_axis` turned by the pose and
/// `camera_direction` is at most `max_angle_deg`. 180° allows every pose.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::PoseRestriction")]
#[repr(C)]
pub struct PoseRestriction {
    /// A direction in model coordinates (any non-zero length), unitless.
    pub model_axis: [f32; 3],
    /// A direction in camera coordinates (any non-zero length), unitless; `-z` points from
    /// the scene towards the camera.
    pub camera_direction: [f32; 3],
    /// Largest angle between the two, degrees, 0 to 180.
    pub max_angle_deg: f32,
}

impl Default for PoseRestriction {
    fn default() -> Self {
        PoseRestriction {
            model_axis: [0.0, 0.0, 1.0],
            camera_direction: [0.0, 0.0, -1.0],
            max_angle_deg: 180.0,
        }
    }
}

/// A pose one requested object is expected near (the previous cycle's answer, or the cell's own
/// bookkeeping), an element of [`DetectRequestHeader::hints`]. Maps model coordinates to camera
/// coordinates as [`PoseHypothesis`] does: `p_cam = R p_model + t`.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("ppfd::PoseHint")]
#[repr(C)]
pub struct PoseHint {
    /// Object id of the model; one of the request's objects.
    pub object_id: u32,
    /// Rotation `R`, row-major (`r[3 * row + col]`), unitless: orthonormal with determinant 1
    /// (to 1e-2; a unit rotation close to it is used).
    pub rotation: [f32; 9],
    /// Translation `t`, millimetres.
    pub translation_mm: [f32; 3],
}

impl From<&PoseHypothesis> for PoseHint {
    /// A previous answer as a hint for the next frame.
    fn from(h: &PoseHypothesis) -> Self {
        PoseHint {
            object_id: h.object_id,
            rotation: h.rotation,
            translation_mm: h.translation_mm,
        }
    }
}

/// How far a hint's rotation may be from orthonormal, per entry of `R Rᵀ − I` and for the
/// determinant: what a matrix written with a few decimals keeps (the ground truth of BOP's LM-O
/// frame is off by up to 2e-3). The daemon uses a unit rotation close to it; a scaled matrix, a shear
/// or a reflection is off by far more.
const ROTATION_TOLERANCE: f32 = 1e-2;

impl PoseHint {
    /// A hint of object `object_id` at `pose` (model → camera, millimetres), as
    /// [`wire_pose`] writes it.
    pub fn from_isometry(object_id: u32, pose: &nalgebra::Isometry3<f32>) -> PoseHint {
        let (rotation, translation_mm) = wire_pose(pose);
        PoseHint {
            object_id,
            rotation,
            translation_mm,
        }
    }

    /// The hint's pose as a nalgebra isometry, with a unit rotation close to its matrix
    /// ([`PoseHypothesis::isometry`]).
    pub fn isometry(&self) -> nalgebra::Isometry3<f32> {
        isometry_of(&self.rotation, &self.translation_mm)
    }

    /// Why this is not a pose, if it is not: a value that is not finite, or a matrix that is
    /// not a rotation (a reflection, a scaled or sheared matrix).
    pub fn problem(&self) -> Option<String> {
        let r = &self.rotation;
        let t = &self.translation_mm;
        if !r.iter().chain(t).all(|v| v.is_finite()) {
            return Some(format!(
                "is not a pose: rotation {r:?} and translation {t:?} mm must be finite"
            ));
        }
        let mut worst = 0f32;
        for i in 0..3 {
            for j in 0..3 {
                let dot: f32 = (0..3).map(|k| r[3 * i + k] * r[3 * j + k]).sum();
                let expected = if i == j { 1.0 } else { 0.0 };
                worst = worst.max((dot - expected).abs());
            }
        }
        let det = r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
            + r[2] * (r[3] * r[7] - r[4] * r[6]);
        if worst > ROTATION_TOLERANCE || (det - 1.0).abs() > ROTATION_TOLERANCE {
            return Some(format!(
                "has a rotation matrix that is not a rotation: R Rᵀ is off the identity by up \
                 to {worst:.2e} and det R is {det:.4} (a rotation has 0 and 1, to \
                 {ROTATION_TOLERANCE:e})"
            ));
        }
        None
    }
}

impl PoseRestriction {
    /// Whether this allows every pose.
    pub fn is_unrestricted(&self) -> bool {
        self.max_angle_deg >= 180.0
    }
}

/// What the hypotheses of a detect request must satisfy, and their order. The default asks
/// for nothing: every pose, the daemon's instance distance, best score first.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("ppfd::Requirements")]
#[repr(C)]
pub struct Requirements {
    /// Hypotheses scoring below this are left out, 0 to 1 (HALCON's `MinScore`).
    pub min_score: f32,
    /// Two hypotheses whose model centres lie closer than this many diameters are one
    /// instance, above 0 to [`MAX_INSTANCE_DISTANCE_FRACTION`]; 0 for the daemon's setting
    /// (HALCON's `max_overlap_dist_rel`).
    pub instance_distance_fraction: f32,
    /// An [`order`] value.
    pub order: u32,
    /// Reference points are taken only from scene points seen in this rectangle.
    pub region_of_interest: RegionOfInterest,
    /// Only poses this allows.
    pub pose_restriction: PoseRestriction,
}

impl Requirements {
    /// Checks each value against its range (a region against the frame is checked where the
    /// frame is known).
    pub fn validate(&self) -> Result<(), ProtocolError> {
        let bad = |field: &'static str, value: String, expected: String| {
            Err(ProtocolError::Requirement {
                field,
                value,
                expected,
            })
        };
        if !(0.0..=1.0).contains(&self.min_score) {
            return bad("minimum score", self.min_score.to_string(), "0 to 1".into());
        }
        let f = self.instance_distance_fraction;
        if f != 0.0 && !(f > 0.0 && f <= MAX_INSTANCE_DISTANCE_FRACTION) {
            return bad(
                "instance distance",
                format!("{f} diameters"),
                format!(
                    "above 0 and at most {MAX_INSTANCE_DISTANCE_FRACTION} diameters, \
                     or 0 for the daemon's setting"
                ),
            );
        }
        if self.order != order::SCORE && self.order != order::DISTANCE {
            return bad(
                "order",
                self.order.to_string(),
                format!("{} (score) or {} (distance)", order::SCORE, order::DISTANCE),
            );
        }
        let r = &self.region_of_interest;
        if !r.is_whole_frame() && (r.width == 0 || r.height == 0) {
            return bad(
                "region of interest",
                format!("{}x{} at ({}, {})", r.width, r.height, r.x, r.y),
                "a width and height of at least 1 pixel, or 0x0 for the whole frame".into(),
            );
        }
        let p = &self.pose_restriction;
        if !(0.0..=180.0).contains(&p.max_angle_deg) {
            return bad(
                "pose restriction angle",
                format!("{} degrees", p.max_angle_deg),
                "0 to 180 degrees".into(),
            );
        }
        for (field, v) in [
            ("pose restriction model axis", p.model_axis),
            ("pose restriction camera direction", p.camera_direction),
        ] {
            let norm = v.iter().map(|c| c * c).sum::<f32>().sqrt();
            if !(norm.is_finite() && norm > 1e-6) {
                return bad(field, format!("{v:?}"), "a finite, non-zero vector".into());
            }
        }
        Ok(())
    }
}

impl Default for DetectRequestHeader {
    fn default() -> Self {
        DetectRequestHeader {
            protocol_version: PROTOCOL_VERSION,
            flags: 0,
            request_id: 0,
            reply_token: 0,
            send_time_ns: 0,
            deadline_ns: 0,
            max_frame_age_ns: 0,
            camera_name: [0; CAMERA_NAME_BYTES],
            inline_frame: FrameHeader::default(),
            object_count: 0,
            hypotheses_per_object: 1,
            object_ids: [0; MAX_OBJECTS_PER_REQUEST],
            requirements: Requirements::default(),
            hint_count: 0,
            reserved: 0,
            hints: [PoseHint::default(); MAX_HINTS_PER_REQUEST],
        }
    }
}

/// Where the frame of a valid request comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameSource {
    /// The newest frame of this camera.
    Camera(String),
    /// The request's own payload.
    Inline,
}

impl DetectRequestHeader {
    /// The valid object ids.
    pub fn objects(&self) -> &[u32] {
        &self.object_ids[..(self.object_count as usize).min(MAX_OBJECTS_PER_REQUEST)]
    }

    /// Sets the object ids, refusing an empty list, too many ids or duplicates.
    pub fn set_objects(&mut self, ids: &[u32]) -> Result<(), ProtocolError> {
        check_object_list(ids)?;
        self.object_ids = [0; MAX_OBJECTS_PER_REQUEST];
        self.object_ids[..ids.len()].copy_from_slice(ids);
        self.object_count = ids.len() as u32;
        Ok(())
    }

    /// The valid hints.
    pub fn hints(&self) -> &[PoseHint] {
        &self.hints[..(self.hint_count as usize).min(MAX_HINTS_PER_REQUEST)]
    }

    /// Sets the hints (after the objects: each must be for one of them), refusing too many and
    /// any that is not a pose.
    pub fn set_hints(&mut self, hints: &[PoseHint]) -> Result<(), ProtocolError> {
        self.store_poses(hints, false)
    }

    /// The hints field's poses, checked as hints or (with `diagnosis`) as poses to diagnose
    /// against.
    fn store_poses(&mut self, hints: &[PoseHint], diagnosis: bool) -> Result<(), ProtocolError> {
        if hints.len() > MAX_HINTS_PER_REQUEST {
            return Err(ProtocolError::TooManyHints(hints.len()));
        }
        self.check_hints(hints, diagnosis)?;
        self.hints = [PoseHint::default(); MAX_HINTS_PER_REQUEST];
        self.hints[..hints.len()].copy_from_slice(hints);
        self.hint_count = hints.len() as u32;
        Ok(())
    }

    /// Asks for a diagnosis against `poses` ([`flags::DIAGNOSE`]; after the objects: each a
    /// pose of one of them), refusing none, too many and any that is not a pose.
    pub fn set_diagnosis_poses(&mut self, poses: &[PoseHint]) -> Result<(), ProtocolError> {
        if poses.is_empty() {
            return Err(ProtocolError::DiagnoseWithoutPoses);
        }
        self.store_poses(poses, true)?;
        self.flags |= flags::DIAGNOSE;
        Ok(())
    }

    fn check_hints(&self, hints: &[PoseHint], diagnosis: bool) -> Result<(), ProtocolError> {
        for (index, h) in hints.iter().enumerate() {
            if !self.objects().contains(&h.object_id) {
                return Err(ProtocolError::HintForUnrequestedObject {
                    index,
                    object_id: h.object_id,
                    diagnosis,
                });
            }
            if let Some(reason) = h.problem() {
                return Err(ProtocolError::InvalidHint {
                    index,
                    object_id: h.object_id,
                    reason,
                    diagnosis,
                });
            }
        }
        Ok(())
    }

    /// Checks everything that can be checked without the daemon's state: version, flags, the
    /// object list, the hypothesis count, the hints, the camera name or the inline frame
    /// against the payload length. Returns where the frame comes from.
    pub fn validate(&self, payload_len: usize) -> Result<FrameSource, ProtocolError> {
        crate::check_version(self.protocol_version)?;
        if self.flags & !flags::KNOWN != 0 {
            return Err(ProtocolError::UnknownFlags(self.flags & !flags::KNOWN));
        }
        if self.object_count as usize > MAX_OBJECTS_PER_REQUEST {
            return Err(ProtocolError::TooManyObjects(self.object_count as usize));
        }
        check_object_list(self.objects())?;
        if self.hypotheses_per_object == 0 || self.hypotheses_per_object > MAX_HYPOTHESES_PER_OBJECT
        {
            return Err(ProtocolError::HypothesesPerObject(
                self.hypotheses_per_object,
            ));
        }
        self.requirements.validate()?;
        if self.hint_count as usize > MAX_HINTS_PER_REQUEST {
            return Err(ProtocolError::TooManyHints(self.hint_count as usize));
        }
        self.check_hints(self.hints(), self.flags & flags::DIAGNOSE != 0)?;
        if self.flags & flags::DIAGNOSE != 0 && self.hint_count == 0 {
            return Err(ProtocolError::DiagnoseWithoutPoses);
        }
        if self.flags & flags::INLINE_FRAME != 0 {
            self.inline_frame.validate(payload_len)?;
            Ok(FrameSource::Inline)
        } else {
            if payload_len != 0 {
                return Err(ProtocolError::UnexpectedPayload(payload_len));
            }
            let name = text::decode(&self.camera_name);
            crate::services::check_camera_name(&name)?;
            Ok(FrameSource::Camera(name.into_owned()))
        }
    }
}

fn check_object_list(ids: &[u32]) -> Result<(), ProtocolError> {
    if ids.is_empty() {
        return Err(ProtocolError::EmptyObjectList);
    }
    if ids.len() > MAX_OBJECTS_PER_REQUEST {
        return Err(ProtocolError::TooManyObjects(ids.len()));
    }
    for (i, id) in ids.iter().enumerate() {
        if ids[..i].contains(id) {
            return Err(ProtocolError::DuplicateObject(*id));
        }
    }
    Ok(())
}

/// One pose hypothesis, an element of the response's `[PoseHypothesis]` payload. The pose maps
/// model coordinates to camera coordinates: `p_cam = R p_model + t`.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("ppfd::PoseHypothesis")]
#[repr(C)]
pub struct PoseHypothesis {
    /// Object id of the model.
    pub object_id: u32,
    /// 0 for the first hypothesis of this object in the request's order (the best scored, or
    /// with [`order::DISTANCE`] the nearest), 1 for the next, ...
    pub instance_rank: u32,
    /// Rotation `R`, row-major (`r[3 * row + col]`), unitless.
    pub rotation: [f32; 9],
    /// Translation `t`, millimetres.
    pub translation_mm: [f32; 3],
    /// Score of the hypothesis after the last stage it passed (0 to 1); the PPF engine's is
    /// the fraction of the model's surface the scene confirms, times the support (confirmed
    /// over visible points) and the silhouette agreement, each to its weight's power.
    pub score: f32,
    /// Votes of the pose cluster the hypothesis came from.
    pub votes: u32,
    /// [`checks`] bits.
    pub checks: u32,
}

impl PoseHypothesis {
    /// The pose as a nalgebra isometry (model → camera, millimetres), made as
    /// [`PoseHint::isometry`] makes it.
    pub fn isometry(&self) -> nalgebra::Isometry3<f32> {
        isometry_of(&self.rotation, &self.translation_mm)
    }
}

/// A nalgebra isometry (model → camera, millimetres) as the wire carries a pose: `R` row-major
/// and `t` in millimetres; the inverse of [`PoseHint::isometry`] to f32's rounding.
pub fn wire_pose(pose: &nalgebra::Isometry3<f32>) -> ([f32; 9], [f32; 3]) {
    let r = pose.rotation.to_rotation_matrix();
    let m = r.matrix();
    let mut rotation = [0f32; 9];
    for (i, value) in rotation.iter_mut().enumerate() {
        *value = m[(i / 3, i % 3)];
    }
    let t = pose.translation.vector;
    (rotation, [t.x, t.y, t.z])
}

/// A wire pose, `R` row-major and `t` in millimetres, as a nalgebra isometry. The daemon's
/// rotations are rotations to f32's rounding and a hint's within [`PoseHint::problem`]'s
/// tolerance, so the quaternion is normalised. The conversion is closed-form: a matrix that is
/// no rotation (all zeros, a NaN), which only a pose made otherwise can hold, gives a
/// meaningless rotation at once, with no iteration that such a matrix could keep from ending.
fn isometry_of(rotation: &[f32; 9], translation_mm: &[f32; 3]) -> nalgebra::Isometry3<f32> {
    let r = nalgebra::Matrix3::from_row_slice(rotation);
    let rotation = nalgebra::UnitQuaternion::new_normalize(
        *nalgebra::UnitQuaternion::from_rotation_matrix(
            &nalgebra::Rotation3::from_matrix_unchecked(r),
        )
        .quaternion(),
    );
    let [x, y, z] = *translation_mm;
    nalgebra::Isometry3::from_parts(nalgebra::Translation3::new(x, y, z), rotation)
}

/// Where the time of one request went, in nanoseconds. All instants are `CLOCK_MONOTONIC` of the
/// same machine, so client and daemon timestamps compare directly. The stages from voting to
/// the filters are summed over the requested objects, which the daemon detects side by side:
/// together they can exceed `detection_ns`, the wall time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("ppfd::LatencyBreakdown")]
#[repr(C)]
pub struct LatencyBreakdown {
    /// Client send → daemon takes the request off the port, ns.
    pub transport_ns: u64,
    /// Daemon takes the request → detection starts on a worker, ns.
    pub queue_wait_ns: u64,
    /// Depth → oriented scene points (a normal per pixel) and the large planes, ns.
    pub scene_preparation_ns: u64,
    /// Subsampling the scene clouds (one per group of objects of similar size) and building
    /// their kd-trees, side by side, ns.
    pub kd_tree_ns: u64,
    /// Point pair voting, ns.
    pub voting_ns: u64,
    /// Pose clustering, ns.
    pub clustering_ns: u64,
    /// Re-scoring from the camera's view, ns.
    pub rescoring_ns: u64,
    /// ICP refinement, ns.
    pub icp_ns: u64,
    /// Verification filters, ns.
    pub filters_ns: u64,
    /// Wall time of the whole detection on the worker (the stages plus glue), ns.
    pub detection_ns: u64,
    /// Client send → daemon sends the response, ns (the client adds the way back).
    pub total_ns: u64,
}

impl LatencyBreakdown {
    /// The stages in pipeline order, each by its field's name without `_ns` (the keys of
    /// `ppf bench --json`; Python's `latency` and `ppf detect --json` add `_ns`), with its time
    /// in ns.
    pub fn stages(&self) -> [(&'static str, u64); 9] {
        [
            ("transport", self.transport_ns),
            ("queue_wait", self.queue_wait_ns),
            ("scene_preparation", self.scene_preparation_ns),
            ("kd_tree", self.kd_tree_ns),
            ("voting", self.voting_ns),
            ("clustering", self.clustering_ns),
            ("rescoring", self.rescoring_ns),
            ("icp", self.icp_ns),
            ("filters", self.filters_ns),
        ]
    }
}

/// Sizes of the work done for one request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("ppfd::DetectCounts")]
#[repr(C)]
pub struct DetectCounts {
    /// Oriented points back-projected from the depth frame (pixels with depth and a normal),
    /// before each object's subsampling.
    pub scene_points: u32,
    /// Scene reference points that voted, summed over the requested objects.
    pub reference_points: u32,
    /// Point pairs that voted, summed over the requested objects.
    pub pairs: u64,
    /// Pose hypotheses out of voting (accumulator peaks, before clustering), summed over the
    /// requested objects.
    pub hypotheses: u32,
    /// Hypotheses in this response's payload.
    pub returned: u32,
}

/// Outcome of a request: [`DetectResponseHeader::status`] and
/// [`crate::control::ControlResponseHeader::status`] hold one of these codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum Status {
    /// Served; the payload holds the hypotheses.
    Ok = 0,
    /// The request's protocol version is not the daemon's.
    ProtocolVersion = 1,
    /// Malformed request (bad flags, hypothesis count, duplicate object, bad camera name, ...).
    InvalidRequest = 2,
    /// The request asked for no object.
    EmptyObjectList = 3,
    /// No loaded model has the object id given in `error_value`.
    UnknownObject = 4,
    /// The frame does not match its own header (size, depth scale).
    InvalidFrame = 5,
    /// The frame's intrinsics are zero, negative or not finite.
    InvalidIntrinsics = 6,
    /// No camera of that name with a driver publishing on it (none ever, or forgotten after
    /// its driver was gone long enough).
    UnknownCamera = 7,
    /// The camera exists but no frame has arrived yet.
    NoFrame = 8,
    /// The camera's newest frame is older than allowed; `error_value` is its age in ns.
    CameraStale = 9,
    /// The deadline passed before the detection started, or while it ran.
    DeadlineExceeded = 10,
    /// The daemon's queue is full; retry later.
    Busy = 11,
    /// The daemon failed in a way that is not the request's fault.
    Internal = 12,
    /// The daemon is shutting down.
    ShuttingDown = 13,
    /// A model could not be loaded or built (control).
    ModelError = 14,
}

impl Status {
    /// The status of a wire code, `None` for a code this version does not know.
    pub fn from_code(code: u32) -> Option<Status> {
        use Status::*;
        Some(match code {
            0 => Ok,
            1 => ProtocolVersion,
            2 => InvalidRequest,
            3 => EmptyObjectList,
            4 => UnknownObject,
            5 => InvalidFrame,
            6 => InvalidIntrinsics,
            7 => UnknownCamera,
            8 => NoFrame,
            9 => CameraStale,
            10 => DeadlineExceeded,
            11 => Busy,
            12 => Internal,
            13 => ShuttingDown,
            14 => ModelError,
            _ => return None,
        })
    }

    /// The wire code.
    pub fn code(self) -> u32 {
        self as u32
    }

    /// A short lowercase name (for logs and tables).
    pub fn name(self) -> &'static str {
        use Status::*;
        match self {
            Ok => "ok",
            ProtocolVersion => "protocol version mismatch",
            InvalidRequest => "invalid request",
            EmptyObjectList => "empty object list",
            UnknownObject => "unknown object",
            InvalidFrame => "invalid frame",
            InvalidIntrinsics => "invalid intrinsics",
            UnknownCamera => "unknown camera",
            NoFrame => "no frame yet",
            CameraStale => "camera stale",
            DeadlineExceeded => "deadline exceeded",
            Busy => "busy",
            Internal => "internal error",
            ShuttingDown => "shutting down",
            ModelError => "model error",
        }
    }
}

impl std::fmt::Display for Status {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The user header of a detect response; the payload is a `[PoseHypothesis]` slice, grouped by
/// object in request order and by rank within an object (empty unless the status is `Ok`).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("ppfd::DetectResponseHeader")]
#[repr(C)]
pub struct DetectResponseHeader {
    /// [`PROTOCOL_VERSION`] of the daemon.
    pub protocol_version: u32,
    /// A [`Status`] code.
    pub status: u32,
    /// The request's id.
    pub request_id: u64,
    /// What the status refers to: the unknown object id, the stale frame's age in ns, the
    /// daemon's protocol version; 0 otherwise.
    pub error_value: u64,
    /// Sequence number of the frame that was used (0 for an inline frame without one).
    pub frame_sequence: u64,
    /// Age of that frame when the detection started, ns.
    pub frame_age_ns: u64,
    /// When the daemon sent this response: `CLOCK_MONOTONIC`, ns.
    pub response_send_ns: u64,
    /// Where the time went.
    pub latency: LatencyBreakdown,
    /// Sizes of the work done.
    pub counts: DetectCounts,
    /// Number of hypotheses in the payload.
    pub hypothesis_count: u32,
    /// Zero.
    pub reserved: u32,
    /// Human-readable detail of a refusal, NUL-padded UTF-8.
    pub message: [u8; MESSAGE_BYTES],
    /// With [`flags::DIAGNOSE`]: per object diagnosed, a heading line and one line per stage,
    /// NUL-padded UTF-8 (cut at a line's end when longer, with a last line that says so);
    /// empty otherwise.
    pub diagnosis: [u8; DIAGNOSIS_BYTES],
}

impl Default for DetectResponseHeader {
    fn default() -> Self {
        DetectResponseHeader {
            protocol_version: PROTOCOL_VERSION,
            status: Status::Ok.code(),
            request_id: 0,
            error_value: 0,
            frame_sequence: 0,
            frame_age_ns: 0,
            response_send_ns: 0,
            latency: LatencyBreakdown::default(),
            counts: DetectCounts::default(),
            hypothesis_count: 0,
            reserved: 0,
            message: [0; MESSAGE_BYTES],
            diagnosis: [0; DIAGNOSIS_BYTES],
        }
    }
}

impl DetectResponseHeader {
    /// The message as text.
    pub fn message(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.message)
    }

    /// The diagnosis as text (empty when none was asked for).
    pub fn diagnosis(&self) -> std::borrow::Cow<'_, str> {
        text::decode(&self.diagnosis)
    }

    /// Writes `lines` into [`Self::diagnosis`], whole lines only: when they do not all fit, as
    /// many as fit and a last line that says how many were left out.
    pub fn set_diagnosis(&mut self, lines: &[String]) {
        let note = |left: usize| format!("({left} more lines left out: diagnose fewer objects)");
        // The last byte stays NUL; a line that is not the last leaves room for the note.
        let capacity = DIAGNOSIS_BYTES - 1;
        let reserve = note(lines.len()).len() + 1;
        let mut text = String::new();
        for (i, line) in lines.iter().enumerate() {
            let after = if i + 1 == lines.len() { 0 } else { reserve };
            if text.len() + line.len() + 1 + after > capacity {
                text.push_str(&note(lines.len() - i));
                text.push('\n');
                break;
            }
            text.push_str(line);
            text.push('\n');
        }
        self.diagnosis = text::encode_truncated(&text);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Intrinsics;
    use std::mem::{align_of, offset_of, size_of};

    #[test]
    fn layouts_are_fixed() {
        assert_eq!(size_of::<DetectRequestHeader>(), 3696);
        assert_eq!(offset_of!(DetectRequestHeader, requirements), 304);
        assert_eq!(size_of::<Requirements>(), 56);
        assert_eq!(offset_of!(DetectRequestHeader, hint_count), 360);
        assert_eq!(offset_of!(DetectRequestHeader, protocol_version), 0);
        assert_eq!(offset_of!(DetectRequestHeader, inline_frame), 80);
        assert_eq!(offset_of!(DetectRequestHeader, hints), 368);
        assert_eq!(size_of::<PoseHint>(), 52);
        assert_eq!(align_of::<PoseHint>(), 4);
        assert_eq!(size_of::<PoseHypothesis>(), 68);
        assert_eq!(align_of::<PoseHypothesis>(), 4);
        assert_eq!(size_of::<LatencyBreakdown>(), 88);
        assert_eq!(size_of::<DetectCounts>(), 24);
        assert_eq!(size_of::<DetectResponseHeader>(), 680 + DIAGNOSIS_BYTES);
        assert_eq!(offset_of!(DetectResponseHeader, protocol_version), 0);
    }

    fn camera_request(objects: &[u32]) -> DetectRequestHeader {
        let mut r = DetectRequestHeader {
            camera_name: text::encode_name("camera", "kinect").unwrap(),
            ..Default::default()
        };
        r.object_ids[..objects.len()].copy_from_slice(objects);
        r.object_count = objects.len() as u32;
        r
    }

    #[test]
    fn a_camera_request_names_its_camera() {
        let r = camera_request(&[1, 5]);
        assert_eq!(r.validate(0).unwrap(), FrameSource::Camera("kinect".into()));
        assert_eq!(r.objects(), &[1, 5]);
    }

    #[test]
    fn malformed_requests_are_refused_each_with_its_reason() {
        let e = camera_request(&[]).validate(0).unwrap_err();
        assert!(matches!(e, ProtocolError::EmptyObjectList));
        assert_eq!(e.status(), Status::EmptyObjectList);

        assert!(matches!(
            camera_request(&[3, 3]).validate(0),
            Err(ProtocolError::DuplicateObject(3))
        ));

        let mut r = camera_request(&[1]);
        r.object_count = MAX_OBJECTS_PER_REQUEST as u32 + 1;
        assert!(matches!(
            r.validate(0),
            Err(ProtocolError::TooManyObjects(_))
        ));

        let mut r = camera_request(&[1]);
        r.protocol_version = 99;
        let e = r.validate(0).unwrap_err();
        assert_eq!(e.status(), Status::ProtocolVersion);
        assert!(e.to_string().contains("99"), "{e}");

        let mut r = camera_request(&[1]);
        r.flags = 1 << 7;
        assert!(matches!(
            r.validate(0),
            Err(ProtocolError::UnknownFlags(128))
        ));

        let mut r = camera_request(&[1]);
        r.hypotheses_per_object = 0;
        assert!(matches!(
            r.validate(0),
            Err(ProtocolError::HypothesesPerObject(0))
        ));

        assert!(matches!(
            camera_request(&[1]).validate(10),
            Err(ProtocolError::UnexpectedPayload(10))
        ));

        let mut r = camera_request(&[1]);
        r.camera_name = [0; CAMERA_NAME_BYTES];
        assert_eq!(r.validate(0).unwrap_err().status(), Status::InvalidRequest);
    }

    #[test]
    fn requirements_out_of_range_are_refused_naming_the_range() {
        assert!(camera_request(&[1]).validate(0).is_ok());
        let with = |change: fn(&mut Requirements)| {
            let mut r = camera_request(&[1]);
            change(&mut r.requirements);
            let e = r.validate(0).unwrap_err();
            assert_eq!(e.status(), Status::InvalidRequest);
            e.to_string()
        };
        let m = with(|q| q.min_score = 1.5);
        assert!(
            m.contains("minimum score 1.5") && m.contains("0 to 1"),
            "{m}"
        );
        let m = with(|q| q.min_score = f32::NAN);
        assert!(m.contains("minimum score NaN"), "{m}");
        let m = with(|q| q.instance_distance_fraction = 3.0);
        assert!(
            m.contains("instance distance 3") && m.contains("at most 2"),
            "{m}"
        );
        let m = with(|q| q.instance_distance_fraction = -0.5);
        assert!(m.contains("instance distance -0.5"), "{m}");
        let m = with(|q| q.order = 7);
        assert!(m.contains("order 7"), "{m}");
        let m = with(|q| q.region_of_interest.width = 20);
        assert!(m.contains("region of interest 20x0"), "{m}");
        let m = with(|q| q.pose_restriction.max_angle_deg = 200.0);
        assert!(m.contains("200 degrees") && m.contains("0 to 180"), "{m}");
        let m = with(|q| q.pose_restriction.model_axis = [0.0; 3]);
        assert!(m.contains("model axis"), "{m}");

        let mut r = camera_request(&[1]);
        r.requirements = Requirements {
            min_score: 0.3,
            instance_distance_fraction: 0.5,
            order: order::DISTANCE,
            region_of_interest: RegionOfInterest {
                x: 10,
                y: 10,
                width: 100,
                height: 50,
            },
            pose_restriction: PoseRestriction {
                max_angle_deg: 30.0,
                ..Default::default()
            },
        };
        assert!(r.validate(0).is_ok());
    }

    #[test]
    fn an_inline_request_is_checked_against_its_payload() {
        let mut r = camera_request(&[1]);
        r.flags = flags::INLINE_FRAME;
        r.inline_frame.width = 4;
        r.inline_frame.height = 2;
        r.inline_frame.intrinsics = Intrinsics {
            fx: 4.0,
            fy: 4.0,
            cx: 1.5,
            cy: 0.5,
        };
        assert_eq!(r.validate(8).unwrap(), FrameSource::Inline);
        let e = r.validate(7).unwrap_err();
        assert_eq!(e.status(), Status::InvalidFrame);
        r.inline_frame.intrinsics.fy = f32::NAN;
        assert_eq!(
            r.validate(8).unwrap_err().status(),
            Status::InvalidIntrinsics
        );
    }

    #[test]
    fn set_objects_refuses_what_validate_refuses() {
        let mut r = DetectRequestHeader::default();
        assert!(r.set_objects(&[]).is_err());
        assert!(r.set_objects(&[1, 1]).is_err());
        assert!(r.set_objects(&[1; MAX_OBJECTS_PER_REQUEST + 1]).is_err());
        r.set_objects(&[7, 8, 9]).unwrap();
        assert_eq!(r.objects(), &[7, 8, 9]);
    }

    /// A diagnosing request needs a pose to diagnose against; with one it passes.
    #[test]
    fn a_diagnosis_is_asked_for_with_the_poses_to_diagnose_against() {
        let mut r = camera_request(&[1, 5]);
        r.flags = flags::DIAGNOSE;
        let e = r.validate(0).unwrap_err();
        assert!(matches!(e, ProtocolError::DiagnoseWithoutPoses), "{e}");
        assert_eq!(e.status(), Status::InvalidRequest);
        r.set_hints(&[hint(5)]).unwrap();
        assert!(r.validate(0).is_ok());

        let mut r = camera_request(&[1, 5]);
        assert!(matches!(
            r.set_diagnosis_poses(&[]),
            Err(ProtocolError::DiagnoseWithoutPoses)
        ));
        assert!(matches!(
            r.set_diagnosis_poses(&[hint(2)]),
            Err(ProtocolError::HintForUnrequestedObject { object_id: 2, .. })
        ));
        r.set_diagnosis_poses(&[hint(1)]).unwrap();
        assert_eq!(r.flags, flags::DIAGNOSE);
        assert!(r.validate(0).is_ok());
    }

    /// A bad pose is named as what it is for: a hint, or a pose to diagnose against, whether
    /// the client or the daemon finds it.
    #[test]
    fn a_bad_pose_is_named_as_a_hint_or_a_pose_to_diagnose_against() {
        let mut nan = hint(1);
        nan.translation_mm[0] = f32::NAN;
        let mut r = camera_request(&[1, 5]);
        let e = r.set_diagnosis_poses(&[hint(5), nan]).unwrap_err();
        assert!(matches!(
            e,
            ProtocolError::InvalidHint {
                index: 1,
                diagnosis: true,
                ..
            }
        ));
        assert!(
            e.to_string()
                .starts_with("pose 1 to diagnose against for object 1 "),
            "{e}"
        );
        let e = r.set_diagnosis_poses(&[hint(2)]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("pose 0 to diagnose against is for object 2"),
            "{e}"
        );
        let e = r.set_hints(&[nan]).unwrap_err();
        assert!(e.to_string().starts_with("hint 0 for object 1 "), "{e}");

        // The daemon's check of a request put together by hand.
        r.hints[0] = nan;
        r.hint_count = 1;
        r.flags = flags::DIAGNOSE;
        let e = r.validate(0).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("pose 0 to diagnose against for object 1 "),
            "{e}"
        );
        r.flags = 0;
        let e = r.validate(0).unwrap_err();
        assert!(e.to_string().starts_with("hint 0 for object 1 "), "{e}");
    }

    /// The diagnosis keeps whole lines: what fits, then a line that says how many were left
    /// out; short diagnoses come back as they went in.
    #[test]
    fn a_diagnosis_too_long_for_its_field_is_cut_at_a_line() {
        let mut h = DetectResponseHeader::default();
        assert_eq!(h.diagnosis(), "");
        let short = vec!["object 5: found".to_string(), "  voting  ok".to_string()];
        h.set_diagnosis(&short);
        assert_eq!(h.diagnosis(), "object 5: found\n  voting  ok\n");

        let long: Vec<String> = (0..400)
            .map(|i| format!("{i:>3} {}", "x".repeat(60)))
            .collect();
        h.set_diagnosis(&long);
        let text = h.diagnosis().into_owned();
        assert!(text.len() < DIAGNOSIS_BYTES);
        let lines: Vec<&str> = text.lines().collect();
        let kept = lines.len() - 1;
        assert!(kept > 100, "{kept} lines kept");
        assert_eq!(&lines[..kept], &long[..kept]);
        assert_eq!(
            lines[kept],
            format!(
                "({} more lines left out: diagnose fewer objects)",
                400 - kept
            )
        );
    }

    fn hint(object_id: u32) -> PoseHint {
        PoseHint {
            object_id,
            rotation: [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            translation_mm: [10.0, -20.0, 800.0],
        }
    }

    /// Hints for requested objects pass; too many, one for an object not asked for, one with a
    /// NaN, a scaled matrix or a reflection are refused, each naming the hint and what is
    /// wrong; `validate` refuses what `set_hints` refuses.
    #[test]
    fn hints_are_poses_of_requested_objects_within_the_limit() {
        let mut r = camera_request(&[1, 5]);
        r.set_hints(&[hint(1), hint(5), hint(5)]).unwrap();
        assert_eq!(r.hints().len(), 3);
        assert!(r.validate(0).is_ok());
        let from_answer = PoseHint::from(&PoseHypothesis {
            object_id: 5,
            rotation: hint(5).rotation,
            translation_mm: hint(5).translation_mm,
            ..Default::default()
        });
        assert_eq!(from_answer, hint(5));

        let e = r
            .set_hints(&[hint(1); MAX_HINTS_PER_REQUEST + 1])
            .unwrap_err();
        assert_eq!(e, ProtocolError::TooManyHints(MAX_HINTS_PER_REQUEST + 1));
        assert!(
            e.to_string().contains(&MAX_HINTS_PER_REQUEST.to_string()),
            "{e}"
        );
        let mut over = r;
        over.hint_count = MAX_HINTS_PER_REQUEST as u32 + 1;
        assert!(matches!(
            over.validate(0),
            Err(ProtocolError::TooManyHints(_))
        ));

        let e = r.set_hints(&[hint(1), hint(7)]).unwrap_err();
        assert_eq!(e.status(), Status::InvalidRequest);
        assert_eq!(
            e.to_string(),
            "hint 1 is for object 7, which the request does not ask for"
        );

        let mut nan = hint(1);
        nan.translation_mm[2] = f32::NAN;
        let e = r.set_hints(&[nan]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("hint 0 for object 1 is not a pose"),
            "{e}"
        );

        let mut scaled = hint(5);
        scaled.rotation.iter_mut().for_each(|v| *v *= 1.1);
        let mut mirrored = hint(5);
        mirrored.rotation[8] = -1.0;
        for bad in [scaled, mirrored] {
            let e = r.set_hints(&[hint(1), bad]).unwrap_err();
            assert!(
                e.to_string().starts_with(
                    "hint 1 for object 5 has a rotation matrix that is not a rotation"
                ),
                "{e}"
            );
            let mut sent = r;
            sent.hints[1] = bad;
            sent.hint_count = 2;
            assert_eq!(sent.validate(0).unwrap_err(), e);
        }
        // Rounded to three decimals, as annotations are written, a rotation is still one.
        let mut rounded = hint(1);
        let (s, c) = (0.5f32.sin(), 0.5f32.cos());
        rounded.rotation = [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0].map(|v| (v * 1e3).round() / 1e3);
        assert!(rounded.problem().is_none());
    }

    #[test]
    fn status_codes_round_trip() {
        for code in 0..32 {
            if let Some(s) = Status::from_code(code) {
                assert_eq!(s.code(), code);
            }
        }
        assert_eq!(Status::from_code(9), Some(Status::CameraStale));
        assert_eq!(Status::from_code(1000), None);
    }

    /// Every stage field, each once, in pipeline order.
    #[test]
    fn the_stages_are_the_stage_fields_in_order() {
        let l = LatencyBreakdown {
            transport_ns: 1,
            queue_wait_ns: 2,
            scene_preparation_ns: 3,
            kd_tree_ns: 4,
            voting_ns: 5,
            clustering_ns: 6,
            rescoring_ns: 7,
            icp_ns: 8,
            filters_ns: 9,
            detection_ns: 10,
            total_ns: 11,
        };
        assert_eq!(l.stages().map(|(_, ns)| ns), [1, 2, 3, 4, 5, 6, 7, 8, 9]);
        assert_eq!(l.stages()[6].0, "rescoring");
    }

    #[test]
    fn isometry_of_a_matrix_that_is_no_rotation_returns() {
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for rotation in [[f32::NAN; 9], [0.0; 9]] {
                let h = PoseHypothesis {
                    rotation,
                    ..Default::default()
                };
                let _ = h.isometry();
            }
            done.send(()).unwrap();
        });
        assert!(
            finished
                .recv_timeout(std::time::Duration::from_secs(10))
                .is_ok(),
            "isometry did not return"
        );
    }

    /// A rotation off by rounding (as a hint within the contract's tolerance is) still gives
    /// a unit rotation, near it, for an answer's pose and a hint's alike.
    #[test]
    fn isometry_of_a_rounded_rotation_is_a_unit_rotation() {
        let exact = nalgebra::Rotation3::<f32>::from_euler_angles(0.3, -1.1, 2.0);
        let rounded = exact.matrix().map(|v: f32| (v * 1000.0).round() / 1000.0);
        let mut rotation = [0.0; 9];
        for (i, v) in rotation.iter_mut().enumerate() {
            *v = rounded[(i / 3, i % 3)];
        }
        let h = PoseHypothesis {
            rotation,
            ..Default::default()
        };
        let hint = PoseHint::from(&h);
        assert_eq!(hint.problem(), None);
        for q in [h.isometry().rotation, hint.isometry().rotation] {
            assert!((q.quaternion().norm() - 1.0).abs() < 1e-6, "{q:?}");
            assert!(q.angle_to(&exact.into()) < 0.01, "{q:?}");
        }
    }

    #[test]
    fn isometry_matches_the_wire_pose() {
        let h = PoseHypothesis {
            rotation: [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            translation_mm: [1.0, 2.0, 3.0],
            ..Default::default()
        };
        for pose in [h.isometry(), PoseHint::from(&h).isometry()] {
            let p = pose * nalgebra::Point3::new(1.0, 0.0, 0.0);
            assert!(
                (p - nalgebra::Point3::new(1.0, 3.0, 3.0)).norm() < 1e-5,
                "{p}"
            );
        }
        // And back: the wire's numbers, to f32's rounding.
        let back = PoseHint::from_isometry(7, &h.isometry());
        assert_eq!(back.object_id, 7);
        assert_eq!(back.translation_mm, h.translation_mm);
        for (a, b) in back.rotation.iter().zip(&h.rotation) {
            assert!(
                (a - b).abs() < 1e-6,
                "{:?} against {:?}",
                back.rotation,
                h.rotation
            );
        }
    }
}
