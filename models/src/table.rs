//! The PPF lookup table: a dense CSR array over the whole key space.
//!
//! The key space of 20 × 15 × 15 × 15 = 67 500 cells is small enough to index directly:
//! `offsets[key]..offsets[key + 1]` is the range of `entries` stored under that key. No hashing,
//! no collisions, one contiguous array that serialises as it is.
//!
//! An entry packs the model reference point's index (high 16 bits) with `α_m` quantised to 16
//! bits over `[−π, π)` (low 16 bits).

use std::f32::consts::PI;

/// Packs a model point index and its `α_m` into one table entry.
#[inline]
pub fn pack_entry(model_point: u16, alpha_m: f32) -> u32 {
    let a = ((alpha_m + PI) * (65536.0 / (2.0 * PI))) as i64;
    ((model_point as u32) << 16) | (a.rem_euclid(65536) as u32)
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
    pub offsets: Vec<u32>,
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
    fn csr_groups_by_key_in_input_order() {
        let pairs = [(3, 30), (1, 10), (3, 31), (0, 0), (3, 32)];
        let t = LookupTable::from_pairs(5, &pairs);
        assert_eq!(t.offsets, vec![0, 1, 2, 2, 5, 5]);
        assert_eq!(t.get(3), &[30, 31, 32]);
        assert_eq!(t.get(2), &[] as &[u32]);
        assert_eq!(t.get(4), &[] as &[u32]);
    }
}
