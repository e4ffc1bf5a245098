//! The flags of what a detection must satisfy (`ppf detect`, `ppf demo`): minimum score,
//! instance distance, region of interest, pose restriction and order, as the protocol carries
//! them.

use clap::{Args, ValueEnum};
use ppfd_client::{order, PoseRestriction, RegionOfInterest, Requirements};

/// The order of each object's poses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ValueEnum)]
pub enum OrderArg {
    /// Best score first.
    #[default]
    Score,
    /// Nearest to the camera first.
    Distance,
}

/// What the poses must satisfy; each flag is a field of the request (README: request options).
#[derive(Args, Debug, Clone, Default)]
pub struct RequirementArgs {
    /// Leave out poses scoring below this, 0 to 1 (HALCON's MinScore).
    #[arg(long, default_value_t = 0.0)]
    pub min_score: f32,
    /// Two poses whose model centres lie closer than this many diameters are one instance,
    /// above 0 to 2, or 0 for the detector's (the default: 0.25; HALCON's
    /// max_overlap_dist_rel), as the protocol and Python take it.
    #[arg(long, value_name = "DIAMETERS")]
    pub instance_distance: Option<f32>,
    /// Take reference points only in this pixel rectangle: X,Y,WIDTH,HEIGHT.
    #[arg(long, value_name = "X,Y,W,H", value_delimiter = ',', num_args = 1)]
    pub roi: Option<Vec<u32>>,
    /// Keep only poses whose model axis (--tilt-axis) leans at most this far from the camera
    /// direction (--tilt-direction), degrees, 0 to 180.
    #[arg(long, value_name = "DEGREES")]
    pub max_tilt: Option<f32>,
    /// The model axis of --max-tilt, in model coordinates.
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        requires = "max_tilt",
        default_value = "0,0,1"
    )]
    pub tilt_axis: Vec<f32>,
    /// The camera direction of --max-tilt, in camera coordinates (0,0,-1 points at the camera).
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        num_args = 1,
        allow_hyphen_values = true,
        requires = "max_tilt",
        default_value = "0,0,-1"
    )]
    pub tilt_direction: Vec<f32>,
    /// Order of each object's poses.
    #[arg(long, value_enum, default_value_t = OrderArg::Score)]
    pub order: OrderArg,
}

impl RequirementArgs {
    /// The request's requirements, checked against their ranges.
    pub fn wire(&self) -> Result<Requirements, String> {
        let three = |flag: &str, v: &[f32]| -> Result<[f32; 3], String> {
            match v {
                &[x, y, z] => Ok([x, y, z]),
                _ => Err(format!("{flag} takes 3 numbers X,Y,Z, got {}", v.len())),
            }
        };
        if let Some(r) = &self.roi {
            if r.len() != 4 {
                return Err(format!("--roi takes 4 numbers X,Y,W,H, got {}", r.len()));
            }
        }
        let (model_axis, camera_direction) = (
            three("--tilt-axis", &self.tilt_axis)?,
            three("--tilt-direction", &self.tilt_direction)?,
        );
        let requirements = Requirements {
            min_score: self.min_score,
            instance_distance_fraction: self.instance_distance.unwrap_or(0.0),
            order: match self.order {
                OrderArg::Score => order::SCORE,
                OrderArg::Distance => order::DISTANCE,
            },
            region_of_interest: self.roi.as_ref().map_or(RegionOfInterest::default(), |r| {
                RegionOfInterest {
                    x: r[0],
                    y: r[1],
                    width: r[2],
                    height: r[3],
                }
            }),
            pose_restriction: match self.max_tilt {
                Some(max_angle_deg) => PoseRestriction {
                    model_axis,
                    camera_direction,
                    max_angle_deg,
                },
                None => PoseRestriction::default(),
            },
        };
        requirements.validate().map_err(|e| e.to_string())?;
        Ok(requirements)
    }
}
