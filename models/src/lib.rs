//! Object models and matching them: the improved Point Pair Feature method of Vidal, Lin and
//! Martí (2018), as a plain library with no IPC.
//!
//! The modules are grouped by where they stand in the pipeline, which reads top-down as the paper
//! does:
//!
//! - [`geometry`]: [`mesh::Mesh`] is an object's surface as read from a PLY file (or generated
//!   by [`parts`]); [`camera::DepthFrame`] is a depth image with its intrinsics; [`render`]
//!   draws meshes into depth images (silhouettes, generated scenes), from coarser copies of them
//!   ([`simplify`]) where a silhouette needs no more.
//! - [`model`]: [`model::ObjectModel`] is built from a mesh once, offline: dense surface samples
//!   ([`sampling`]) are subsampled with normal clustering ([`subsample`]) and every ordered pair
//!   of the remaining oriented points is stored under its quantised point pair feature
//!   ([`feature`]) in a dense lookup table ([`table::LookupTable`]). A model may carry the
//!   object's [`symmetry`], the poses that cannot be told apart. [`store`] writes it to disk and
//!   reads it back.
//! - [`detect`]: at run time a depth frame becomes oriented scene points ([`scene`]), which vote
//!   for model-point/angle pairs ([`voting`]); the votes become poses that are clustered
//!   ([`clustering`]), re-scored from the camera's view ([`rescoring`]), refined by projective
//!   ICP ([`icp`]) and filtered ([`filters`]); re-scoring and the filters both measure a pose's
//!   outline against the scene's depth edges ([`silhouette`]). [`detector::Detector`] runs all
//!   of it.
//! - [`synthetic`]: generated parts ([`parts`]) and table-top scenes with ground truth and sensor
//!   noise ([`synthetic::scene`]), so that all of the above can be tested without data files.
//!
//! BOP datasets are read, and poses scored as the BOP toolkit does, by the `ppfd-bop` crate.
//!
//! [`mesh::Mesh`]: geometry::mesh::Mesh
//! [`parts`]: synthetic::parts
//! [`camera::DepthFrame`]: geometry::camera::DepthFrame
//! [`render`]: geometry::render
//! [`simplify`]: geometry::simplify
//! [`sampling`]: model::sampling
//! [`subsample`]: model::subsample
//! [`feature`]: model::feature
//! [`table::LookupTable`]: model::table::LookupTable
//! [`symmetry`]: model::symmetry
//! [`store`]: model::store
//! [`scene`]: detect::scene
//! [`voting`]: detect::voting
//! [`clustering`]: detect::clustering
//! [`rescoring`]: detect::rescoring
//! [`icp`]: detect::icp
//! [`filters`]: detect::filters
//! [`silhouette`]: detect::silhouette
//! [`detector::Detector`]: detect::detector::Detector
//!
//! The modules cite the method notes by section (`METHOD.md §2.3`): `docs/METHOD.md` in the
//! repository describes the method as implemented, with every departure from the paper.
//!
//! Units: millimetres for lengths, radians for angles; a pose maps model coordinates into camera
//! coordinates, `p_cam = R p_model + t`, OpenCV camera convention.
//!
//! ```
//! use ppfd_models::detect::detector::{RunOptions, Detector};
//! use ppfd_models::model::{ModelParams, ObjectModel};
//! use ppfd_models::synthetic::parts::Part;
//! use ppfd_models::synthetic::scene::SceneSpec;
//!
//! let mesh = Part::TPipe.mesh();
//! let model = ObjectModel::build(&mesh, 4, "t_pipe", &ModelParams::default()).unwrap();
//! let scene = SceneSpec::new(1).object(4, &mesh).build().unwrap();
//! let found = Detector::default()
//!     .detect(&scene.frame.view(), &[&model], &RunOptions::default())
//!     .unwrap();
//! let best = &found.objects[0].hypotheses[0];
//! println!("pose {:?}, score {:.2}, {:?} in voting", best.pose, best.score, found.timings.voting);
//! ```

#![warn(missing_docs)]

pub mod detect;
pub mod error;
pub mod file;
pub mod geometry;
pub mod limits;
pub mod model;
pub mod synthetic;

pub use error::{Error, Result};

/// A rigid transform from model coordinates into camera coordinates (millimetres).
pub type Pose = nalgebra::Isometry3<f32>;
