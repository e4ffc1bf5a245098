//! The PPF lookup table: a dense CSR array over the whole key space.
//!
//! The key space of 20 × 15 × 15 × 15 = 67 500 cells is small enough to index directly:
//! `offsets[key]..offsets[key + 1]` is the range of `entries` stored under that key. No hashing,
//! no collisions, one contiguous array that serialises as it is.
//!
//! An entry packs the model reference point's index (high 16 bits) with `α_m` quantised to 16
//! bits over `[−π, π)` (low 16 bits).

use std::f32::consts::PI;

/// An angle in 16-bit fixed point: `[−π, π)` ↦ `0..65536`, so that differences wrap for free.
#[inline]
pub fn alpha_to_fixed(alpha: f32) -> u16 {
    // Rounded to the nearest step, wrapping: floor(x + ½) modulo 2¹⁶. Written without
    // `round`/`rem_euclid`, which are library calls on baseline x86-64 and sat in the voting
    // loop's profile (once per scene pair).
    let x = (alpha + PI) * (65536.0 / (2.0 * PI)) + 0.5;
    let t = x as i64;
    let floor = if (t as f32) > x { t - 1 } else { t };
    floor as u16
}

/// The α bin of `α_m − α_s` given both in fixed point: integer arithmetic only, as the voting
/// loop needs. Equal to `feature::alpha_bin(wrap_angle(α_m − α_s), bins)` up to rounding.
#[inline]
pub fn fixed_difference_bin(alpha_m: u16, alpha_s: u16, bins: u32) -> u32 {
    // (a_m − a_s) is α in [0, 2π); adding half a turn maps it to [−π, π) like the bins.
    let d = alpha_m.wrapping_sub(alpha_s).wrapping_add(32768);
    (d as u32 * bins) >> 16
}

/// Packs a model point index and its `α_m` into one table entry.
#[inline]
pub fn pack_entry(model_point: u16, alpha_m: f32) -> u32 {
    ((model_point as u32) << 16) | alpha_to_fixed(alpha_m) as u32
}

/// The model point index of a table entry.
#[inline]
pub fn entry_model_point(entry: u32) -> u32 {
    entry >> 16
}

/// The `α_m` of a table entry, radians in `[−π, π)`.
#[inline]
pub fn entry_alpha(entry: u32) -> f32 {
    (entry & 0xFFFF) as f32 * (2.0 * PI / 65536.0) - PI
}

/// A lookup table under construction or deserialised: `offsets` has one more element than there
/// are keys.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LookupTable {
    /// Where each key's entries start in `entries`, and one past the last key's end.
    pub offsets: Vec<u32>,
    /// The entries of every key, key after key (see [`pack_entry`]).
    pub entries: Vec<u32>,
}

impl LookupTable {
    /// Builds the CSR arrays from `(key, entry)` pairs by a counting sort; within a key the
    /// input order is kept.
    pub fn from_pairs(key_count: usize, pairs: &[(u32, u32)]) -> Self {
        let mut offsets = vec![0u32; key_count + 1];
        for &(k, _) in pairs {
            offsets[k as usize + 1] += 1;
        }
        for k in 0..key_count {
            offsets[k + 1] += offsets[k];
        }
        let mut cursor = offsets.clone();
        let mut entries = vec![0u32; pairs.len()];
        for &(k, e) in pairs {
            let c = &mut cursor[k as usize];
            entries[*c as usize] = e;
            *c += 1;
        }
        Self { offsets, entries }
    }

    /// The entries stored under `key`.
    #[inline]
    pub fn get(&self, key: u32) -> &[u32] {
        let k = key as usize;
        &self.entries[self.offsets[k] as usize..self.offsets[k + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_round_trip() {
        for (i, a) in [
            (0u16, -PI),
            (65535, PI - 1e-3),
            (1234, 0.0),
            (7, -1.0),
            (9, 2.5),
        ] {
            let e = pack_entry(i, a);
            assert_eq!(entry_model_point(e), i as u32);
            assert!(
                (entry_alpha(e) - a).abs() < 2.0 * PI / 65536.0 + 1e-6,
                "{a}"
            );
        }
    }

    #[test]
    fn fixed_point_rounds_to_the_nearest_step_and_wraps() {
        let step = 2.0 * PI / 65536.0;
        assert_eq!(alpha_to_fixed(-PI), 0);
        assert_eq!(alpha_to_fixed(0.0), 32768);
        // π is a whole turn from −π: it wraps to 0, and so does a hair below it.
        assert_eq!(alpha_to_fixed(PI), 0);
        assert_eq!(alpha_to_fixed(PI - 0.2 * step), 0);
        assert_eq!(alpha_to_fixed(-PI + 0.4 * step), 0);
        assert_eq!(alpha_to_fixed(-PI + 0.6 * step), 1);
        // Below −π (a sum of angles, say) it wraps the other way.
        assert_eq!(alpha_to_fixed(-PI - 1.0 * step), 65535);
        for i in 0..1000 {
            let a = -3.0 * PI + 6.0 * PI * (i as f32 + 0.13) / 1000.0;
            let exact = ((a as f64 + std::f64::consts::PI) / step as f64).round() as i64;
            let got = alpha_to_fixed(a) as i64;
            // Equal up to f32 rounding of the scaled angle (at most one step, circularly).
            let off = (got - exact).rem_euclid(65536);
            assert!(off <= 1 || off == 65535, "{a}: {got} vs {exact}");
        }
    }

    #[test]
    fn fixed_point_bins_match_float_bins() {
        use crate::model::feature::{alpha_bin, wrap_angle};
        let mut mismatches = 0;
        let n = 200;
        for i in 0..n {
            for j in 0..n {
                let am = -PI + 2.0 * PI * (i as f32 + 0.37) / n as f32;
                let as_ = -PI + 2.0 * PI * (j as f32 + 0.71) / n as f32;
                let fixed = fixed_difference_bin(alpha_to_fixed(am), alpha_to_fixed(as_), 30);
                let float = alpha_bin(wrap_angle(am - as_), 30);
                if fixed != float {
                    mismatches += 1;
                    // Only right at a bin border may rounding differ, and by one bin.
                    assert!(
                        (fixed as i32 - float as i32).rem_euclid(30) == 1
                            || (float as i32 - fixed as i32).rem_euclid(30) == 1
                    );
                }
            }
        }
        assert!(mismatches < n * n / 500, "{mismatches}");
    }

    #[test]
    fn csr_groups_by_key_in_input_order() {
        let pairs = [(3, 30), (1, 10), (3, 31), (0, 0), (3, 32)];
        let t = LookupTable::from_pairs(5, &pairs);
        assert_eq!(t.offsets, vec![0, 1, 2, 2, 5, 5]);
        assert_eq!(t.get(3), &[30, 31, 32]);
        assert_eq!(t.get(2), &[] as &[u32]);
        assert_eq!(t.get(4), &[] as &[u32]);
    }
}
