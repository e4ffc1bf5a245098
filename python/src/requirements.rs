//! The keyword arguments of `Client.detect` that say what the poses must satisfy, as the
//! protocol's `Requirements`: minimum score, instance distance, region of interest, pose
//! restriction and order. Here they only change form (tuples, names); their ranges are checked
//! by `Requirements::validate` in the client library, before the request is sent, so Python
//! gets the Rust message.

use ppfd_client::{order, PoseRestriction, RegionOfInterest, Requirements};
use pyo3::conversion::FromPyObjectOwned;
use pyo3::prelude::*;

use crate::errors::protocol_error;

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
    value.extract::<[T; N]>().map_err(|_| {
        let got = value
            .repr()
            .map_or_else(|_| "an unprintable value".into(), |r| r.to_string());
        protocol_error(py, format!("{name} must be {form}, got {got}"))
    })
}
