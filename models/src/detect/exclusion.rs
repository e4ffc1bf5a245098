//! Exclusion across objects (METHOD.md §3.5): each scene surface belongs to one object. A pose
//! of one object whose confirmed surface lies mostly where a pose of another object confirms
//! more is an impostor on that object's surface (a flat side of the glue on the egg box's lid),
//! and gives way to the object's next pose that passed the filters.

use crate::detect::rescoring::{judge_point, Judgement, PoseMatrix};
use crate::detect::scene::SceneImage;
use crate::model::subsample::OrientedPoints;
use crate::Pose;

/// Scene pixels are grouped into square cells this many pixels wide: the model's surface
/// points (0.025 D apart) land a few pixels apart, and two poses on one surface confirm the
/// same cells rather than the same pixels.
const CELL_PX: i64 = 4;

/// Parameters of the exclusion across objects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExclusionParams {
    /// A pose gives way when at least this fraction of the cells it confirms are confirmed by
    /// another object's pose that confirms more cells. 0 turns exclusion off.
    pub min_shared_fraction: f32,
    /// How many further poses that passed the filters each object keeps to take the place of
    /// one that gives way.
    pub alternates: usize,
}

impl Default for ExclusionParams {
    fn default() -> Self {
        Self {
            min_shared_fraction: 0.5,
            alternates: 3,
        }
    }
}

impl ExclusionParams {
    /// Whether exclusion runs: a positive `min_shared_fraction` and at least one alternate.
    pub fn enabled(&self) -> bool {
        self.min_shared_fraction > 0.0 && self.alternates > 0
    }
}

/// The scene cells whose depth confirms a pose: where a surface point is an inlier as
/// re-scoring counts it ([`judge_point`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Claim {
    /// Cell indices, sorted, each once.
    cells: Vec<u32>,
}

impl Claim {
    /// The claim of `surface` at `pose`: the cells of its points that [`judge_point`] finds
    /// inliers (tolerance and conflict distance in mm, the normals' angle in degrees).
    pub fn new(
        surface: &OrientedPoints,
        pose: &Pose,
        scene: &SceneImage,
        tolerance_mm: f32,
        conflict_mm: f32,
        max_normal_angle_deg: f32,
    ) -> Claim {
        let cos_max = max_normal_angle_deg.to_radians().cos();
        let pose = PoseMatrix::new(pose);
        let columns = scene.width.div_ceil(CELL_PX as u32) as i64;
        let mut cells: Vec<u32> = surface
            .positions
            .iter()
            .zip(&surface.normals)
            .filter_map(|(p, n)| {
                match judge_point(&pose, p, n, scene, tolerance_mm, conflict_mm, cos_max) {
                    Some((Judgement::Inlier, u, v)) => {
                        Some(((v / CELL_PX) * columns + u / CELL_PX) as u32)
                    }
                    _ => None,
                }
            })
            .collect();
        cells.sort_unstable();
        cells.dedup();
        Claim { cells }
    }

    /// How many cells the pose confirms.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether the pose confirms no cell.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// How many cells both confirm.
    pub fn shared_with(&self, other: &Claim) -> usize {
        let (mut i, mut j, mut n) = (0, 0, 0);
        while i < self.cells.len() && j < other.cells.len() {
            match self.cells[i].cmp(&other.cells[j]) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    n += 1;
                    i += 1;
                    j += 1;
                }
            }
        }
        n
    }

    /// Whether `other` explains this claim away: it confirms more cells, and at least
    /// `min_shared_fraction` of this claim's among them.
    pub fn explained_by(&self, other: &Claim, min_shared_fraction: f32) -> bool {
        other.len() > self.len()
            && self.shared_with(other) as f32 >= min_shared_fraction * self.len() as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn claim(cells: &[u32]) -> Claim {
        Claim {
            cells: cells.to_vec(),
        }
    }

    #[test]
    fn shared_cells_are_counted_once_each() {
        let a = claim(&[1, 3, 5, 7, 9]);
        let b = claim(&[2, 3, 4, 5, 9, 11]);
        assert_eq!(a.shared_with(&b), 3);
        assert_eq!(b.shared_with(&a), 3);
        assert_eq!(a.shared_with(&Claim::default()), 0);
    }

    #[test]
    fn only_a_larger_claim_over_enough_of_it_explains_a_pose_away() {
        let small = claim(&[1, 2, 3, 4]);
        let covering = claim(&[2, 3, 4, 5, 6, 7]);
        let beside = claim(&[4, 5, 6, 7, 8, 9]);
        // Three of four shared, by a claim that confirms more.
        assert!(small.explained_by(&covering, 0.5));
        assert!(!small.explained_by(&covering, 0.8));
        // The larger claim is not explained away by the smaller one.
        assert!(!covering.explained_by(&small, 0.5));
        // One of four shared: objects side by side meet only at their borders.
        assert!(!small.explained_by(&beside, 0.5));
        // Equal claims explain neither away.
        assert!(!small.explained_by(&small.clone(), 0.5));
    }
}
