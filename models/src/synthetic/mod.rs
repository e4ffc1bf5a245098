//! Generated data with known ground truth, so that the pipeline can be tested without data
//! files: [`parts`] makes closed meshes of industrial-looking parts, [`scene`] places meshes on a
//! table and renders what a depth camera sees, with optional sensor noise.

pub mod parts;
pub mod scene;
