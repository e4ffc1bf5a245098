//! Four points at a time in SSE2 lanes (part of x86-64): a rotation and translation applied
//! with nalgebra's operations in nalgebra's order, so that each lane comes out as
//! `rotation * p + translation` gives one point, to the bit. nalgebra's `Matrix3 * Vector3`
//! sums `(r₀·x + r₁·y) + r₂·z` per row, with no fused multiply-add on baseline x86-64.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use nalgebra::{Matrix3, Vector3};

/// The `x`, `y` and `z` of four vectors, lane `i` from `v(i)`.
///
/// # Safety
///
/// SSE2 must be available, as it always is on x86-64.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn lanes_of(v: impl Fn(usize) -> Vector3<f32>) -> [__m128; 3] {
    let v = [v(0), v(1), v(2), v(3)];
    [
        _mm_setr_ps(v[0].x, v[1].x, v[2].x, v[3].x),
        _mm_setr_ps(v[0].y, v[1].y, v[2].y, v[3].y),
        _mm_setr_ps(v[0].z, v[1].z, v[2].z, v[3].z),
    ]
}

/// `rotation * v` of four vectors given by their coordinates' lanes, then plus `translation`
/// when there is one.
///
/// # Safety
///
/// SSE2 must be available, as it always is on x86-64.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn moved(
    rotation: &Matrix3<f32>,
    translation: Option<&Vector3<f32>>,
    [x, y, z]: [__m128; 3],
) -> [__m128; 3] {
    let s = |v: f32| _mm_set1_ps(v);
    let r = rotation;
    let row = |i: usize| {
        _mm_add_ps(
            _mm_add_ps(_mm_mul_ps(s(r[(i, 0)]), x), _mm_mul_ps(s(r[(i, 1)]), y)),
            _mm_mul_ps(s(r[(i, 2)]), z),
        )
    };
    let (rx, ry, rz) = (row(0), row(1), row(2));
    match translation {
        Some(t) => [
            _mm_add_ps(rx, s(t.x)),
            _mm_add_ps(ry, s(t.y)),
            _mm_add_ps(rz, s(t.z)),
        ],
        None => [rx, ry, rz],
    }
}

/// Rounds each lane half away from zero, as `(x + 0.5.copysign(x)) as i32` does for values
/// inside the `i32` range (beyond it, `i32::MIN`).
///
/// # Safety
///
/// SSE2 must be available, as it always is on x86-64.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn rounded(x: __m128) -> __m128i {
    let half = _mm_or_ps(_mm_and_ps(x, _mm_set1_ps(-0.0)), _mm_set1_ps(0.5));
    _mm_cvttps_epi32(_mm_add_ps(x, half))
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use crate::geometry::rng::Rng;
    use nalgebra::Point3;

    /// Each lane is `rotation * p + translation` of its point, to the bit.
    #[test]
    fn four_moved_points_are_each_moved_alone() {
        let mut rng = Rng::new(3);
        let mut r = || (rng.uniform() as f32 - 0.5) * 2.0;
        for _ in 0..500 {
            let rotation =
                *nalgebra::UnitQuaternion::from_euler_angles(3.0 * r(), 3.0 * r(), 3.0 * r())
                    .to_rotation_matrix()
                    .matrix();
            let translation = Vector3::new(300.0 * r(), 300.0 * r(), 1000.0 * r());
            let p: [Point3<f32>; 4] =
                std::array::from_fn(|_| Point3::new(90.0 * r(), 90.0 * r(), 90.0 * r()));
            for t in [Some(&translation), None] {
                let mut out = [[0f32; 4]; 3];
                // SAFETY: SSE2 is part of x86-64; each store writes one array of four.
                unsafe {
                    let lanes = moved(&rotation, t, lanes_of(|i| p[i].coords));
                    for (o, l) in out.iter_mut().zip(lanes) {
                        _mm_storeu_ps(o.as_mut_ptr(), l);
                    }
                }
                for (i, p) in p.iter().enumerate() {
                    let alone = match t {
                        Some(t) => rotation * p.coords + t,
                        None => rotation * p.coords,
                    };
                    assert_eq!(
                        [out[0][i], out[1][i], out[2][i]].map(f32::to_bits),
                        [alone.x, alone.y, alone.z].map(f32::to_bits)
                    );
                }
            }
        }
    }
}
