//! What the pipeline stands on: camera intrinsics and depth frames ([`camera`]), triangle meshes
//! ([`mesh`]) and their coarser copies for silhouettes ([`simplify`]), depth rendering
//! ([`render`]), integer grid cells ([`grid`]) and a seeded random generator ([`rng`]).

pub mod camera;
pub mod grid;
pub mod mesh;
pub mod render;
pub mod rng;
pub mod simplify;
