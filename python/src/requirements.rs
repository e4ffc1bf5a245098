//! The keyword arguments of `Client.detect` that say what the poses must satisfy, as the
//! protocol's `Requirements`: minimum score, instance distance, region of interest, pose
//! restriction and order; and the poses already known, as the protocol's hints. Here they only change form (tuples, names); their ranges are checked
//! by `Requirements::validate` in the client library, before the request is sent, so Python
//! gets the Rust message.

use ppfd_client::{order, PoseHint, PoseRestriction, RegionOfInterest, Requirements};
use pyo3::conversion::FromPyObjectOwned;
use pyo3::prelude::*;

use crate::client::Detection;
use crate::errors::{protocol_error, shown};

/// The requirement keywords as Python gave them; `None` leaves the protocol's default.
pub struct RequirementArgs<'a, 'py> {
    pub min_score: f32,
    pub instance_distance: Option<f32>,
    pub roi: Option<&'a Bound<'py, PyAny>>,
    pub max_tilt_deg: Option<f32>,
    pub tilt_axis: Option<&'a Bound<'py, PyAny>>,
    pub tilt_direction: Option<&'a Bound<'py, PyAny>>,
    pub order: &'a str,
}

impl<'py> RequirementArgs<'_, 'py> {
    /// The request's requirements; a value of the wrong form raises `ProtocolError` naming the
    /// argument (its range is the client library's to check).
    pub fn wire(&self, py: Python<'py>) -> PyResult<Requirements> {
        let defaults = Requirements::default();
        let region_of_interest = match self.roi {
            Some(roi) => {
                let [x, y, width, height] =
                    numbers::<u32, 4>(py, "roi", "4 pixel counts (x, y, width, height)", roi)?;
                RegionOfInterest {
                    x,
                    y,
                    width,
                    height,
                }
            }
            None => defaults.region_of_interest,
        };
        let unrestricted = defaults.pose_restriction;
        let vector = |name: &str, value: Option<&Bound<'py, PyAny>>, default: [f32; 3]| {
            value.map_or(Ok(default), |v| {
                numbers::<f32, 3>(py, name, "3 numbers (x, y, z)", v)
            })
        };
        let pose_restriction = match self.max_tilt_deg {
            Some(max_angle_deg) => PoseRestriction {
                model_axis: vector("tilt_axis", self.tilt_axis, unrestricted.model_axis)?,
                camera_direction: vector(
                    "tilt_direction",
                    self.tilt_direction,
                    unrestricted.camera_direction,
                )?,
                max_angle_deg,
            },
            None => {
                // An axis without an angle would restrict nothing, silently.
                for (name, given) in [
                    ("tilt_axis", self.tilt_axis),
                    ("tilt_direction", self.tilt_direction),
                ] {
                    if given.is_some() {
                        return Err(protocol_error(
                            py,
                            format!("{name} applies only with max_tilt_deg: give max_tilt_deg too"),
                        ));
                    }
                }
                unrestricted
            }
        };
        Ok(Requirements {
            min_score: self.min_score,
            instance_distance_fraction: self
                .instance_distance
                .unwrap_or(defaults.instance_distance_fraction),
            order: match self.order {
                "score" => order::SCORE,
                "distance" => order::DISTANCE,
                other => {
                    return Err(protocol_error(
                        py,
                        format!("order must be \"score\" or \"distance\", got {other:?}"),
                    ))
                }
            },
            region_of_interest,
            pose_restriction,
        })
    }
}

/// The `N` numbers of the sequence `value`, or a `ProtocolError` saying that `name` must be
/// `form` and what it got.
fn numbers<'py, T: FromPyObjectOwned<'py>, const N: usize>(
    py: Python<'py>,
    name: &str,
    form: &str,
    value: &Bound<'py, PyAny>,
) -> PyResult<[T; N]> {
    value
        .extract::<[T; N]>()
        .map_err(|_| protocol_error(py, format!("{name} must be {form}, got {}", shown(value))))
}

/// The `hints` (or `diagnose`, as `name` says) keyword of `Client.detect` as the protocol's
/// poses: each item is a `Detection`
/// (a previous answer) or a pair `(object_id, pose)` with `pose` a 4×4 (or 3×4) array-like
/// `[[R, t], [0, 0, 0, 1]]` in millimetres. A value of the wrong form raises `ProtocolError`
/// naming the item; whether the pose is a rotation, and its object one of the request's, is the
/// client library's to check. A `Detection` of an object not in `object_ids` is left out: a
/// picking loop passes its last answer whole while the objects it asks for change.
pub fn poses<'py>(
    py: Python<'py>,
    name: &str,
    value: &Bound<'py, PyAny>,
    object_ids: &[u32],
) -> PyResult<Vec<PoseHint>> {
    let mut out = Vec::new();
    for (index, item) in value.try_iter()?.enumerate() {
        let item = item?;
        if let Ok(detection) = item.cast::<Detection>() {
            let hint = detection.get().hint();
            if object_ids.contains(&hint.object_id) {
                out.push(hint);
            }
            continue;
        }
        let wrong = |what: &str| {
            protocol_error(
                py,
                format!(
                    "{name}[{index}] must be a Detection or (object_id, 4×4 pose){what}; got {}",
                    shown(&item)
                ),
            )
        };
        let (object_id, pose) = item
            .extract::<(u32, Bound<'py, PyAny>)>()
            .map_err(|_| wrong(""))?;
        // A numpy array gives its rows as lists; a nested sequence is taken as it is.
        let rows = match pose.hasattr("tolist")? {
            true => pose.call_method0("tolist")?,
            false => pose,
        };
        let rows: Vec<Vec<f64>> = rows
            .extract()
            .map_err(|_| wrong(": the pose is not a table of numbers"))?;
        if !(rows.len() == 3 || rows.len() == 4) || rows.iter().any(|r| r.len() != 4) {
            return Err(wrong(": the pose must have 4 columns and 3 or 4 rows"));
        }
        if rows.iter().flatten().any(|v| !v.is_finite()) {
            return Err(wrong(": the pose's numbers must be finite"));
        }
        if rows.len() == 4 && rows[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(wrong(": the pose's last row must be (0, 0, 0, 1)"));
        }
        let mut rotation = [0f32; 9];
        let mut translation_mm = [0f32; 3];
        for (r, row) in rows.iter().take(3).enumerate() {
            for c in 0..3 {
                rotation[3 * r + c] = row[c] as f32;
            }
            translation_mm[r] = row[3] as f32;
        }
        out.push(PoseHint {
            object_id,
            rotation,
            translation_mm,
        });
    }
    Ok(out)
}
