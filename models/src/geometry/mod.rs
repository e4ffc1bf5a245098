//! What the pipeline stands on: camera intrinsics and depth frames ([`camera`]), triangle meshes
//! ([`mesh`]) and their coarser copies for silhouettes ([`simplify`]), depth rendering
//! ([`render`]), integer grid cells ([`grid`]), a seeded random generator ([`rng`]) and
//! points moved four at a time (`four`).

pub mod camera;
pub(crate) mod four;
pub mod grid;
pub mod mesh;
pub mod render;
pub mod rng;
pub mod simplify;
