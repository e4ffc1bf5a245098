//! The ppfd wire contract: what crosses the process boundary between camera drivers, the `ppfd`
//! daemon and robot processes. Every type here is `#[repr(C)]`, holds no pointer, derives
//! iceoryx2's `ZeroCopySend` with a `#[type_name]`, and states its units; nothing is serialised.
//!
//! - [`frame::FrameHeader`] heads a depth frame (a `[u16]` slice) that a camera driver publishes
//!   on `ppfd/camera/<name>/depth`.
//! - [`detect::DetectRequestHeader`] asks the daemon, on `ppfd/detect`, to find some objects in
//!   the newest frame of a camera (or in a frame carried inline as the request's `[u16]`
//!   payload). The answer is a [`detect::DetectResponseHeader`] with a [`detect::Status`], a
//!   [`detect::LatencyBreakdown`] and [`detect::DetectCounts`], over a `[`[`detect::PoseHypothesis`]`]`
//!   payload.
//! - [`control::ControlRequest`] lists, loads or drops models and reads
//!   [`control::DaemonStats`] on `ppfd/control`.
//! - [`services`] names every service and holds every port limit; its builders are the only way
//!   participants open services, so they always agree.
//!
//! Units: millimetres, pixels, nanoseconds of `CLOCK_MONOTONIC` ([`clock`]). Every header
//! carries [`PROTOCOL_VERSION`]; a mismatch is refused with [`detect::Status::ProtocolVersion`],
//! never misread. (A change of a type's layout also changes its size, which iceoryx2 itself
//! refuses when the service is opened.)
//!
//! ```
//! use ppfd_protocol::{detect::DetectRequestHeader, text, detect::FrameSource};
//! let mut request = DetectRequestHeader::default();
//! request.camera_name = text::encode_name("camera", "kinect").unwrap();
//! request.set_objects(&[1, 5, 6]).unwrap();
//! assert_eq!(request.validate(0).unwrap(), FrameSource::Camera("kinect".into()));
//! ```

pub mod clock;
pub mod control;
pub mod detect;
pub mod frame;
pub mod services;
pub mod text;

/// Version of this contract; it travels in every header.
pub const PROTOCOL_VERSION: u32 = 7;
/// Bytes of a camera name field (names are at most one less: the last byte stays NUL).
pub const CAMERA_NAME_BYTES: usize = 32;
/// Bytes of a message field: room for the longest refusal, whose end says how to fix it (the
/// depth scale that would fit a frame's values, the flag that raises a limit), and for the
/// detector parameters in the statistics.
pub const MESSAGE_BYTES: usize = 512;
/// Bytes of a detect response's diagnosis ([`detect::flags::DIAGNOSE`]): the lines of about
/// eight objects.
pub const DIAGNOSIS_BYTES: usize = 8192;
/// Bytes of a path field.
pub const PATH_BYTES: usize = 256;
/// Bytes of a model name field.
pub const MODEL_NAME_BYTES: usize = 48;
/// Objects one detect request may ask for.
pub const MAX_OBJECTS_PER_REQUEST: usize = 32;
/// Hypotheses per object one detect request may ask for.
pub const MAX_HYPOTHESES_PER_OBJECT: u32 = 16;
/// Prior poses ([`detect::PoseHint`]) one detect request may carry, over all its objects: as
/// many as two full answers of [`MAX_OBJECTS_PER_REQUEST`] objects, or four instances each of
/// 16 objects. The request header holds them in place (52 bytes each); raising it means a
/// new protocol version.
pub const MAX_HINTS_PER_REQUEST: usize = 64;
/// The largest frame a daemon detects in by default, pixels: 4096 × 4096, 32 MiB of depth.
/// A detection takes about 95 bytes per pixel, so this bounds one at about 1.6 GB; depth
/// sensors of picking cells give 0.3 to 12 megapixels. The daemon's `max_frame_pixels` sets
/// its own limit ([`frame::FrameHeader::check_pixels`]).
pub const DEFAULT_MAX_FRAME_PIXELS: usize = 4096 * 4096;

/// Refuses a header written by another protocol version.
pub fn check_version(version: u32) -> Result<(), ProtocolError> {
    if version == PROTOCOL_VERSION {
        Ok(())
    } else {
        Err(ProtocolError::Version {
            got: version,
            expected: PROTOCOL_VERSION,
        })
    }
}

/// What is wrong with a message, as far as the contract alone can tell.
#[derive(Debug, Clone, PartialEq)]
pub enum ProtocolError {
    /// The header's protocol version is not [`PROTOCOL_VERSION`].
    Version { got: u32, expected: u32 },
    /// A name does not fit its fixed field.
    NameTooLong {
        field: &'static str,
        name: String,
        max_bytes: usize,
    },
    /// A name holds characters it may not.
    InvalidName {
        field: &'static str,
        name: String,
        reason: &'static str,
    },
    /// An environment variable holds a value refused as `error` says: named, since a user who
    /// gave no value may not know where it came from.
    Variable {
        variable: &'static str,
        error: Box<ProtocolError>,
    },
    /// The frame's payload does not hold `width × height` values (or the size is zero).
    FrameSize {
        width: u32,
        height: u32,
        values: usize,
    },
    /// A frame of more pixels than the daemon's `max_frame_pixels`.
    FrameTooLarge {
        width: u32,
        height: u32,
        max_pixels: u64,
    },
    /// Focal lengths outside 1 to 10⁶ pixels (zero, negative, not finite), or a principal
    /// point not finite or, for a frame, more than the image's size outside it.
    InvalidIntrinsics(frame::Intrinsics),
    /// Zero, negative or non-finite depth scale.
    InvalidDepthScale(f32),
    /// A request without objects.
    EmptyObjectList,
    /// More objects than [`MAX_OBJECTS_PER_REQUEST`].
    TooManyObjects(usize),
    /// The same object id twice.
    DuplicateObject(u32),
    /// Hypotheses per object outside 1..=[`MAX_HYPOTHESES_PER_OBJECT`].
    HypothesesPerObject(u32),
    /// Flag bits this version does not know.
    UnknownFlags(u32),
    /// A request naming a camera carried a payload.
    UnexpectedPayload(usize),
    /// More hints than [`MAX_HINTS_PER_REQUEST`].
    TooManyHints(usize),
    /// A hint (or, with `diagnosis`, a pose to diagnose against) for an object the request
    /// does not ask for.
    HintForUnrequestedObject {
        index: usize,
        object_id: u32,
        diagnosis: bool,
    },
    /// A hint (or, with `diagnosis`, a pose to diagnose against) that is not a pose: a value
    /// not finite, or a matrix that is not a rotation.
    InvalidHint {
        index: usize,
        object_id: u32,
        reason: String,
        diagnosis: bool,
    },
    /// [`detect::flags::DIAGNOSE`] without a pose to diagnose against.
    DiagnoseWithoutPoses,
    /// Hints and poses to diagnose against in one request: they share one field.
    DiagnoseWithHints,
    /// [`services::remove_prefix_leftovers`] for a prefix a running daemon serves.
    PrefixServed { prefix: String },
    /// A request option out of its range: a value of [`detect::Requirements`], the maximum
    /// frame age, or the timeout.
    Requirement {
        field: &'static str,
        value: String,
        expected: String,
    },
}

impl ProtocolError {
    /// The status a daemon answers this error with.
    pub fn status(&self) -> detect::Status {
        use detect::Status;
        match self {
            ProtocolError::Version { .. } => Status::ProtocolVersion,
            ProtocolError::FrameSize { .. }
            | ProtocolError::FrameTooLarge { .. }
            | ProtocolError::InvalidDepthScale(_) => Status::InvalidFrame,
            ProtocolError::InvalidIntrinsics(_) => Status::InvalidIntrinsics,
            ProtocolError::EmptyObjectList => Status::EmptyObjectList,
            _ => Status::InvalidRequest,
        }
    }
}

impl std::fmt::Display for ProtocolError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ProtocolError::Version { got, expected } => {
                write!(
                    f,
                    "protocol version {got} is not supported, expected {expected}"
                )
            }
            ProtocolError::NameTooLong {
                field,
                name,
                max_bytes,
            } => {
                write!(
                    f,
                    "{field} name {name:?} is too long: at most {max_bytes} bytes"
                )
            }
            ProtocolError::InvalidName {
                field,
                name,
                reason,
            } => {
                write!(f, "{field} name {name:?} {reason}")
            }
            ProtocolError::Variable { variable, error } => write!(f, "{variable}: {error}"),
            ProtocolError::FrameSize { width, height, .. } if *width == 0 || *height == 0 => {
                write!(
                    f,
                    "depth frame {width}x{height} has no pixels: its width and height must be at \
                     least 1"
                )
            }
            ProtocolError::FrameSize {
                width,
                height,
                values,
            } => write!(
                f,
                "depth frame {width}x{height} needs {} values, got {values}",
                *width as usize * *height as usize
            ),
            ProtocolError::FrameTooLarge {
                width,
                height,
                max_pixels,
            } => write!(
                f,
                "depth frame {width}x{height} has {} pixels, more than the daemon's limit of \
                 {max_pixels} (max_frame_pixels; raise it with ppfd --max-frame-pixels, or send \
                 a smaller frame)",
                *width as u64 * *height as u64
            ),
            ProtocolError::InvalidIntrinsics(k) => write!(
                f,
                "intrinsics need focal lengths of {} to {} pixels and a principal point within \
                 the image widened by its size on each side, got fx={} fy={} cx={} cy={}",
                frame::Intrinsics::MIN_FOCAL_PX,
                frame::Intrinsics::MAX_FOCAL_PX,
                k.fx,
                k.fy,
                k.cx,
                k.cy
            ),
            ProtocolError::InvalidDepthScale(s) => {
                write!(f, "depth scale must be finite and positive, got {s}")
            }
            ProtocolError::EmptyObjectList => write!(f, "the request asks for no object"),
            ProtocolError::TooManyObjects(n) => {
                write!(
                    f,
                    "the request asks for {n} objects, at most {MAX_OBJECTS_PER_REQUEST} allowed"
                )
            }
            ProtocolError::DuplicateObject(id) => write!(f, "object id {id} is asked for twice"),
            ProtocolError::HypothesesPerObject(n) => write!(
                f,
                "hypotheses per object must be 1 to {MAX_HYPOTHESES_PER_OBJECT}, got {n}"
            ),
            ProtocolError::UnknownFlags(bits) => write!(f, "unknown request flags {bits:#x}"),
            ProtocolError::Requirement {
                field,
                value,
                expected,
            } => write!(f, "{field} {value} is out of range: expected {expected}"),
            ProtocolError::UnexpectedPayload(n) => write!(
                f,
                "a request naming a camera must carry no frame, got {n} depth values \
                 (set the inline-frame flag to send a frame)"
            ),
            ProtocolError::TooManyHints(n) => write!(
                f,
                "the request carries {n} hints, at most {MAX_HINTS_PER_REQUEST} allowed (a fixed \
                 field of the request: send the hints of fewer objects, or one per instance)"
            ),
            ProtocolError::DiagnoseWithoutPoses => write!(
                f,
                "the request asks for a diagnosis but carries no pose to diagnose against (the \
                 poses the objects are believed at, in the hints field)"
            ),
            ProtocolError::PrefixServed { prefix } => write!(
                f,
                "a ppfd daemon is running under the iceoryx2 prefix {prefix:?}: its files are \
                 removed only after it has stopped, or its clients and cameras could no longer \
                 reach it"
            ),
            ProtocolError::DiagnoseWithHints => write!(
                f,
                "a request cannot both carry hints and ask for a diagnosis: a diagnosis runs \
                 the detection from scratch; send the hints in a request of their own"
            ),
            ProtocolError::HintForUnrequestedObject {
                index,
                object_id,
                diagnosis,
            } => write!(
                f,
                "{} is for object {object_id}, which the request does not ask for",
                pose_name(*index, *diagnosis)
            ),
            ProtocolError::InvalidHint {
                index,
                object_id,
                reason,
                diagnosis,
            } => write!(
                f,
                "{} for object {object_id} {reason}",
                pose_name(*index, *diagnosis)
            ),
        }
    }
}

impl std::error::Error for ProtocolError {}

/// How an error names the `index`-th pose of the hints field: a hint, or with
/// [`detect::flags::DIAGNOSE`] a pose to diagnose against.
fn pose_name(index: usize, diagnosis: bool) -> String {
    if diagnosis {
        format!("pose {index} to diagnose against")
    } else {
        format!("hint {index}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn version_check_names_both_versions() {
        assert!(check_version(PROTOCOL_VERSION).is_ok());
        let e = check_version(PROTOCOL_VERSION + 7).unwrap_err();
        assert_eq!(e.status(), detect::Status::ProtocolVersion);
        let m = e.to_string();
        assert!(
            m.contains(&(PROTOCOL_VERSION + 7).to_string())
                && m.contains(&PROTOCOL_VERSION.to_string())
        );
    }

    #[test]
    fn every_wire_type_has_a_stable_type_name() {
        use iceoryx2::prelude::ZeroCopySend;
        // SAFETY: type_name only returns a static string.
        unsafe {
            assert_eq!(frame::FrameHeader::type_name(), "ppfd::FrameHeader");
            assert_eq!(
                detect::DetectRequestHeader::type_name(),
                "ppfd::DetectRequestHeader"
            );
            assert_eq!(
                detect::DetectResponseHeader::type_name(),
                "ppfd::DetectResponseHeader"
            );
            assert_eq!(detect::PoseHypothesis::type_name(), "ppfd::PoseHypothesis");
            assert_eq!(detect::PoseHint::type_name(), "ppfd::PoseHint");
            assert_eq!(control::ControlRequest::type_name(), "ppfd::ControlRequest");
            assert_eq!(
                control::ControlResponseHeader::type_name(),
                "ppfd::ControlResponseHeader"
            );
            assert_eq!(control::ModelInfo::type_name(), "ppfd::ModelInfo");
            assert_eq!(detect::Requirements::type_name(), "ppfd::Requirements");
        }
    }
}
