//! Hash maps keyed by integer grid cells (voxels), with a hash fit for them.
//!
//! The standard library's SipHash guards against keys chosen by an attacker; grid cells of
//! points are not, and at 27 look-ups per point (a cell and its neighbours) SipHash was most of
//! the time of subsampling a scene. This is a multiply-rotate hash in the manner of rustc's
//! FxHash.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Point3;

/// A cell of a regular 3-D grid.
pub type Cell = (i32, i32, i32);

/// A hash map from grid cells.
pub type CellMap<V> = HashMap<Cell, V, BuildHasherDefault<CellHasher>>;

/// The cell of `p` on a grid of cells `1 / inv_cell` wide with a corner at the origin.
#[inline]
pub fn cell_of(p: &Point3<f32>, inv_cell: f32) -> Cell {
    (
        floor(p.x * inv_cell),
        floor(p.y * inv_cell),
        floor(p.z * inv_cell),
    )
}

/// `x.floor() as i32` without the library call `floor` is on baseline x86-64 (for |x| < 2³¹;
/// beyond, saturates like the cast).
#[inline]
fn floor(x: f32) -> i32 {
    let t = x as i32;
    if (t as f32) > x {
        t.saturating_sub(1) // at i32::MIN the cast has saturated already
    } else {
        t
    }
}

/// The hasher of [`CellMap`].
#[derive(Clone, Copy, Default)]
pub struct CellHasher(u64);

const K: u64 = 0x517c_c1b7_2722_0a95;

impl CellHasher {
    #[inline]
    fn add(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(K);
    }
}

impl Hasher for CellHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(b as u64);
        }
    }

    #[inline]
    fn write_i32(&mut self, i: i32) {
        self.add(i as u32 as u64);
    }

    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.add(i as u64);
    }

    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_floor_towards_minus_infinity() {
        let p = Point3::new(2.5, -0.5, -3.0);
        assert_eq!(cell_of(&p, 1.0), (2, -1, -3));
        assert_eq!(cell_of(&p, 0.5), (1, -1, -2));
        for i in -1000..1000 {
            let x = i as f32 * 0.37 + 0.001;
            assert_eq!(floor(x), x.floor() as i32, "{x}");
        }
        assert_eq!(floor(1e12), i32::MAX);
        assert_eq!(floor(-1e12), i32::MIN);
        assert_eq!(floor(f32::NEG_INFINITY), i32::MIN);
        assert_eq!(floor(f32::NAN), 0);
    }

    #[test]
    fn neighbouring_cells_are_told_apart() {
        let mut map: CellMap<u32> = CellMap::default();
        let mut n = 0;
        for x in -20..20 {
            for y in -20..20 {
                for z in -20..20 {
                    map.insert((x, y, z), n);
                    n += 1;
                }
            }
        }
        assert_eq!(map.len(), 64_000);
        assert_eq!(map[&(-20, -20, -20)], 0);
        assert_eq!(map[&(19, 19, 19)], 63_999);
        assert_eq!(map[&(0, -1, 2)], (20 * 40 + 19) * 40 + 22);
        assert!(!map.contains_key(&(20, 0, 0)));
    }
}
