//! Detection at run time, one module per stage in the order they run: [`scene`] preparation,
//! [`voting`] (with the supporting [`plane`]), [`clustering`], [`rescoring`], [`icp`], the
//! [`filters`] and the [`exclusion`] of a first answer on a surface another object's explains
//! better. [`requirements`] is what a caller needs of the answer (minimum score, region,
//! pose restriction, order). [`silhouette`] holds what re-scoring and the filters both measure of a pose.
//! [`detector::Detector`] runs all of it with [`detector::DetectParams`], whose fields
//! [`settings`] names for `--set` and configuration files. [`diagnosis`] runs the same stages
//! one by one to say where an object near a given pose was lost.

pub mod clustering;
pub mod detector;
pub mod diagnosis;
pub mod exclusion;
pub mod filters;
pub mod icp;
pub mod plane;
pub mod requirements;
pub mod rescoring;
pub mod scene;
pub mod settings;
pub mod silhouette;
pub mod voting;
