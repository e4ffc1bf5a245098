//! Local matching by voting (METHOD.md §2.3–2.5).
//!
//! For each reference point `s_r` of the scene, every scene point `s_i` within the model
//! diameter forms a pair; its feature's key (and the neighbouring keys of the paper's
//! quantisation-error rule) selects model pairs `(m_i, α_m)` in the lookup table, each voting for
//! `(m_i, α = α_m − α_s)` in a flat accumulator. Vote-once flags (Hinterstoisser et al. 2016)
//! keep a `(key, α_s bin)` from voting twice for one reference point. The accumulator's peaks
//! become pose hypotheses `T_s⁻¹ R_x(α) T_m`.

use rayon::prelude::*;

use crate::detect::plane::SupportingPlane;
use crate::detect::requirements::PixelRegion;
use crate::detect::scene::PreparedScene;
use crate::geometry::camera::Intrinsics;
use crate::geometry::grid::{cell_of, CellMap};
use crate::model::feature::{alpha_of_bin, pose_from_alignment, LocalFrame, PairBatch, MAX_KEYS};
use crate::model::table::fixed_difference_bin;
use crate::model::ObjectModel;
use crate::Pose;

/// Parameters of voting.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VotingParams {
    /// Reference points are spread evenly over the scene: it is cut into cubes of this side, a
    /// fraction of the model diameter, and in each cube the first subsampled point off the
    /// large planes and in front of the supporting one (see [`Selection`]) is a candidate. After neighbour filtering (on for
    /// every model by default) the subsampled cloud lists the points that stand for the most
    /// pixels first, so that is the cube's best-supported point. 0:
    /// every point is a candidate. Taking every n-th point instead leaves gaps and clumps
    /// where the cloud's order puts them; an even spread covers a small or occluded object
    /// with fewer points. docs/METHOD.md §2.3 has the measurements.
    pub reference_spacing_fraction: f32,
    /// Every `reference_step`-th candidate (see `reference_spacing_fraction`) is a reference
    /// point. Drost et al. use every 5th subsampled point; the even spread with every candidate
    /// finds more of voting's best clusters on generated views than every 2nd, 3rd or 4th point
    /// (docs/METHOD.md §2.3 has the table).
    pub reference_step: usize,
    /// Use the paper's neighbouring keys (≤ 15 extra) against quantisation noise.
    pub neighbour_keys: bool,
    /// Hinterstoisser's vote-once flags.
    pub vote_once: bool,
    /// At most this many accumulator peaks per reference point become hypotheses. Measured
    /// with 1, 2 and 3: on the LM-O frame 5, 6 and 5 of 8 best poses correct under VSD (1
    /// loses the hole puncher, 3 the glue); synth-lmo-dev's recall 0.926 with 2 and 3; noisy
    /// occluded generated views (4 × 40) 130, 130 and 124 best clusters within 0.05 D and 5°.
    pub peaks_per_reference: usize,
    /// A secondary peak must have at least this fraction of the highest peak's votes. With the
    /// refined scores of METHOD.md §3.3, 0.7 against 0.8: synth-lmo-dev 0.949 against 0.944,
    /// ycbv-real-dev's AR 0.658 against 0.644, the LM-O frame 6 of 8 either way (§2.5).
    pub peak_ratio: f32,
    /// Refine a peak's α inside its bin by a parabola through the votes of the bin and its two
    /// neighbours: a 12° bin alone leaves up to 6° of rotation error in every hypothesis.
    pub interpolate_alpha: bool,
}

impl Default for VotingParams {
    fn default() -> Self {
        Self {
            reference_spacing_fraction: 0.1,
            reference_step: 1,
            neighbour_keys: true,
            vote_once: true,
            peaks_per_reference: 2,
            peak_ratio: 0.7,
            interpolate_alpha: true,
        }
    }
}

/// One pose proposed by one reference point's accumulator peak.
#[derive(Clone, Copy, Debug)]
pub struct VotedPose {
    /// The pose `T_s⁻¹ R_x(α) T_m`, model to camera (mm).
    pub pose: Pose,
    /// The peak's votes.
    pub votes: u32,
    /// Index of the scene reference point (in the prepared scene's points).
    pub scene_point: u32,
    /// Index of the model point it matched.
    pub model_point: u32,
}

/// What voting did, for the latency breakdown.
#[derive(Clone, Copy, Debug, Default)]
pub struct VotingCounts {
    /// Reference points taken.
    pub reference_points: u32,
    /// Point pairs formed: reference points with their partners within D.
    pub pairs: u64,
    /// Votes cast into the accumulator (table entries visited).
    pub votes: u64,
}

/// Accumulator cells per model point: α bins (at most 32, as the vote-once flags need) padded
/// to a power of two, so that a cell's index is a shift and an or.
const ROW_SHIFT: usize = 5;
const ROW: usize = 1 << ROW_SHIFT;

/// Copies of the accumulator that take turns at a key's votes. Consecutive entries of a key
/// often name the same cell; with one accumulator each increment waits for the one before it
/// (a load behind a store to the same address). With byte cells, two copies are the fastest:
/// the eight objects of the LM-O frame voted in 626–633 ms with 2, 638–648 ms with 4 and
/// 685 ms with 1 (`RAYON_NUM_THREADS=1 ppf profile`, three alternating runs, the sum of the
/// objects' voting).
const LANES: usize = 2;

/// One reference point's votes per (model point, α bin), kept small enough to stay in the
/// first-level cache: each of the [`LANES`] copies holds the low byte of its count, and a
/// low byte that wraps carries 256 into `carries` (rare: a cell seldom takes 256 votes from
/// one reference point). [`Accumulator::merge`] adds it all up into `totals`, exactly (up to
/// 65 535, where a cell saturates).
struct Accumulator {
    /// `LANES` copies of `cells` low bytes, one after the other.
    lanes: Vec<u8>,
    /// Per cell, how many times a low byte wrapped (summed over the copies).
    carries: Vec<u16>,
    /// Whether any low byte wrapped since the last merge.
    carried: bool,
    /// Per cell the reference point's votes, after [`Accumulator::merge`]; its length is the
    /// number of cells.
    totals: Vec<u16>,
    /// Per row of [`ROW`] cells (one model point), the largest of its `totals`.
    row_max: Vec<u16>,
    /// Cells waiting to be counted (see [`Accumulator::add_casts`]).
    pending: Vec<u32>,
}

impl Accumulator {
    fn new(cells: usize) -> Self {
        Self {
            lanes: vec![0; LANES * cells],
            carries: vec![0; cells],
            carried: false,
            totals: vec![0; cells],
            row_max: vec![0; cells.div_ceil(ROW)],
            pending: Vec::new(),
        }
    }

    /// One vote into cell `c` of the copy `lane` (a slice of `cells` low bytes).
    ///
    /// # Safety
    ///
    /// `c` must be below `lane.len()` (which is `carries.len()`).
    #[inline(always)]
    unsafe fn bump(lane: &mut [u8], carries: &mut [u16], carried: &mut bool, c: usize) {
        debug_assert!(c < lane.len() && lane.len() == carries.len());
        let cell = lane.get_unchecked_mut(c);
        let v = cell.wrapping_add(1);
        *cell = v;
        if v == 0 {
            let carry = carries.get_unchecked_mut(c);
            *carry = carry.saturating_add(1);
            *carried = true;
        }
    }

    /// The votes of every cast `(start, end, α_s)`: the table entries `start..end` of one
    /// key, for a scene pair of angle `α_s` (fixed point). The cells of many casts' entries
    /// are gathered first ([`push_cells`], four at a time) and then counted in one run, spread
    /// over the copies: a key holds about a dozen entries, and counting each cast's apart
    /// spends as much on starting and ending the loops as on the votes. The entries of the
    /// cast after next are fetched into the cache meanwhile.
    ///
    /// # Safety
    ///
    /// Every entry must name a model point below the number of cells over [`ROW`], and
    /// `alpha_bins` be at most [`ROW`].
    unsafe fn add_casts(
        &mut self,
        entries: &[rkyv::Archived<u32>],
        casts: &[Cast],
        alpha_bins: u16,
    ) {
        // Cells gathered before they are counted: 8 KB, which stays in the first-level cache
        // beside the copies.
        const PENDING: usize = 2048;
        let mut pending = std::mem::take(&mut self.pending);
        pending.clear();
        for (j, cast) in casts.iter().enumerate() {
            if let Some(next) = casts.get(j + 2) {
                prefetch(entries[next.start as usize..].as_ptr());
            }
            let (mut start, end) = (cast.start as usize, cast.end as usize);
            while start < end {
                let to = end.min(start + PENDING);
                push_cells(entries, start..to, cast.alpha_s, alpha_bins, &mut pending);
                start = to;
                if pending.len() >= PENDING {
                    // SAFETY: the caller's promise, which `push_cells` turns into cells
                    // below the number of cells.
                    unsafe { self.count(&pending) };
                    pending.clear();
                }
            }
        }
        // SAFETY: as above.
        unsafe { self.count(&pending) };
        pending.clear();
        self.pending = pending;
    }

    /// One vote into each of `cells`, taken by the copies in turn.
    ///
    /// # Safety
    ///
    /// Every cell must be below the number of cells.
    unsafe fn count(&mut self, cells: &[u32]) {
        let cells_len = self.totals.len();
        let mut copies = self.lanes.chunks_exact_mut(cells_len);
        let lanes: [&mut [u8]; LANES] = std::array::from_fn(|_| copies.next().unwrap());
        let (carries, carried) = (&mut self.carries[..], &mut self.carried);
        let mut groups = cells.chunks_exact(2 * LANES);
        for g in &mut groups {
            for i in 0..2 * LANES {
                // SAFETY: the caller's promise: below `cells_len`, the length of every copy.
                unsafe { Self::bump(&mut *lanes[i % LANES], carries, carried, g[i] as usize) };
            }
        }
        for (i, &c) in groups.remainder().iter().enumerate() {
            // SAFETY: as above.
            unsafe { Self::bump(&mut *lanes[i % LANES], carries, carried, c as usize) };
        }
    }

    /// Adds the copies (and carries) into `totals`, clears them for the next reference
    /// point, and writes each row's (model point's) largest total into `row_max`. One pass
    /// reads each copy once and writes it once: at a few hundred cells per vote cast, this
    /// pass and the peak search cost as much as the votes themselves when each walks all the
    /// cells apart.
    fn merge(&mut self) {
        let n = self.totals.len();
        let lanes = &mut self.lanes[..];
        for (row, (t, m)) in self
            .totals
            .chunks_exact_mut(ROW)
            .zip(self.row_max.iter_mut())
            .enumerate()
        {
            let mut sum = [0u16; ROW];
            for l in 0..LANES {
                let lane = &mut lanes[l * n + row * ROW..][..ROW];
                for i in 0..ROW {
                    sum[i] += lane[i] as u16;
                }
                lane.fill(0);
            }
            t.copy_from_slice(&sum);
            *m = sum.iter().copied().max().unwrap_or(0);
        }
        if self.carried {
            for ((t, c), m) in self
                .totals
                .chunks_exact_mut(ROW)
                .zip(self.carries.chunks_exact_mut(ROW))
                .zip(self.row_max.iter_mut())
            {
                for (t, c) in t.iter_mut().zip(c.iter_mut()) {
                    *t = (*t as u32 + ((*c as u32) << 8)).min(u16::MAX as u32) as u16;
                    *c = 0;
                }
                *m = t.iter().copied().max().unwrap_or(0);
            }
            self.carried = false;
        }
    }
}

/// One key's votes for one scene pair: the key's range of table entries and the pair's
/// `α_s` in fixed point (see [`crate::model::table::alpha_to_fixed`]).
#[derive(Clone, Copy, Debug)]
struct Cast {
    start: u32,
    end: u32,
    alpha_s: u16,
}

/// Appends to `cells` the accumulator cell of each table entry of `range` for a scene pair of
/// angle `alpha_s` (fixed point): `(model point << ROW_SHIFT) | bin(α_m − α_s)`, with the bin
/// as [`crate::model::table::fixed_difference_bin`] gives it. Computed four entries at a time,
/// reading (and writing into the spare capacity) up to three entries past the range's end
/// while the table goes on, so that a key's last few entries need no loop of their own.
#[inline(always)]
fn push_cells(
    entries: &[rkyv::Archived<u32>],
    range: std::ops::Range<usize>,
    alpha_s: u16,
    alpha_bins: u16,
    cells: &mut Vec<u32>,
) {
    let (start, end) = (range.start, range.end);
    debug_assert!(start <= end && end <= entries.len());
    cells.reserve(end - start + 3);
    let len = cells.len();
    let out = cells.spare_capacity_mut().as_mut_ptr() as *mut u32;
    let mut i = start;
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SSE2 is part of x86-64: four entries at a time in 16-bit lanes. The low half of
        // each entry is α_m; `(α_m − α_s) ^ 0x8000` is the wrapped difference plus half a turn,
        // and its high 16 bits times the bin count (a 16-bit `mulhi`) is the bin.
        // SAFETY: SSE2 is always available on x86-64; each load reads four entries inside
        // `entries` (`i + 4 <= entries.len()`), each store writes four cells at most three
        // past the range's `end - start`, inside the capacity reserved above. Archived `u32`
        // is a plain little-endian `u32`, as x86-64 is.
        unsafe {
            let alpha = _mm_set1_epi32(alpha_s as i32);
            let half = _mm_set1_epi32(0x8000);
            let bins = _mm_set1_epi32(alpha_bins as i32);
            let row_mask = _mm_set1_epi32(!((ROW as i32) - 1));
            while i < end && i + 4 <= entries.len() {
                let e = _mm_loadu_si128(entries.as_ptr().add(i) as *const __m128i);
                let d = _mm_xor_si128(_mm_sub_epi16(e, alpha), half);
                let bin = _mm_mulhi_epu16(d, bins);
                let point = _mm_and_si128(_mm_srli_epi32(e, 16 - ROW_SHIFT as i32), row_mask);
                let cell = _mm_or_si128(point, bin);
                _mm_storeu_si128(out.add(i - start) as *mut __m128i, cell);
                i += 4;
            }
        }
    }
    while i < end {
        let e = entries[i].to_native();
        let bin = fixed_difference_bin(e as u16, alpha_s, alpha_bins as u32);
        // SAFETY: `i - start < end - start`, inside the capacity reserved above.
        unsafe { out.add(i - start).write(((e >> 16) << ROW_SHIFT) | bin) };
        i += 1;
    }
    // SAFETY: the cells of the whole range are written.
    unsafe { cells.set_len(len + end - start) };
}

/// Asks for the cache line at `p` ahead of its use (nothing on other architectures).
#[inline(always)]
fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch does not access memory; any address is allowed.
    unsafe {
        std::arch::x86_64::_mm_prefetch(p as *const i8, std::arch::x86_64::_MM_HINT_T0);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// A key of the lookup table as voting reads it: where its entries start (they end where the
/// next key's start), and the α_s bins it has voted with for the reference point under way.
#[derive(Clone, Copy, Debug)]
#[repr(C)]
struct KeySlot {
    start: u32,
    flags: u32,
}

/// Per-thread scratch: the accumulator and vote-once flags, reused across reference points.
struct Scratch {
    accumulator: Accumulator,
    /// The reference point's casts, in the order its pairs made them.
    casts: Vec<Cast>,
    slots: Vec<KeySlot>,
    touched_keys: Vec<u32>,
    /// The reference point's partners.
    pairs: PairBatch,
}

/// Votes with every reference point of `scene` against `model`; returns the hypotheses of all
/// reference points.
pub fn vote(
    model: &ObjectModel,
    scene: &PreparedScene,
    params: &VotingParams,
) -> (Vec<VotedPose>, VotingCounts) {
    let selection = Selection::new(scene, params, &[], model.diameter_mm());
    vote_from(model, scene, &selection, params)
}

/// Which scene points an object's voting uses: its reference points, and which points are left
/// out: those on a large plane, and those behind the supporting plane (see [`crate::detect::plane`]).
#[derive(Clone, Debug, Default)]
pub struct Selection {
    /// Indices into the scene's points.
    pub references: Vec<usize>,
    /// Per scene point: on one of the planes too large to be a face of the object, or behind
    /// the supporting plane ([`crate::detect::plane::PlaneParams::exclude_behind`]).
    pub excluded: Vec<bool>,
}

impl Selection {
    /// For an object of diameter `diameter_mm`: the reference points `params` spread over the
    /// scene points that lie on none of the given planes too large to be the object's own
    /// faces, nor behind the first of them (see [`VotingParams::reference_spacing_fraction`] and
    /// [`VotingParams::reference_step`]).
    pub fn new(
        scene: &PreparedScene,
        params: &VotingParams,
        planes: &[SupportingPlane],
        diameter_mm: f32,
    ) -> Selection {
        Self::within(scene, params, planes, diameter_mm, None)
    }

    /// [`Selection::new`] with reference points only among the scene points that project into
    /// `region` (seen through `intrinsics`); every admitted point stays a partner, so an object
    /// the region cuts keeps the votes of its points outside it.
    pub fn within(
        scene: &PreparedScene,
        params: &VotingParams,
        planes: &[SupportingPlane],
        diameter_mm: f32,
        region: Option<(&PixelRegion, &Intrinsics)>,
    ) -> Selection {
        let points = &scene.points;
        let planes: Vec<&SupportingPlane> = planes
            .iter()
            .filter(|pl| pl.excludes_for(diameter_mm))
            .collect();
        let excluded: Vec<bool> = (0..points.len())
            .map(|i| {
                planes
                    .iter()
                    .any(|pl| pl.excludes(&points.positions[i], &points.normals[i]))
            })
            .collect();
        let admitted = (0..points.len()).filter(|&i| {
            !excluded[i] && region.is_none_or(|(r, k)| r.holds(k, &points.positions[i]))
        });
        let step = params.reference_step.max(1);
        let spacing = params.reference_spacing_fraction * diameter_mm;
        let references = if spacing > 0.0 {
            let inverse = 1.0 / spacing;
            let mut taken: CellMap<()> = CellMap::default();
            admitted
                .filter(|&i| {
                    taken
                        .insert(cell_of(&points.positions[i], inverse), ())
                        .is_none()
                })
                .step_by(step)
                .collect()
        } else {
            admitted.step_by(step).collect()
        };
        Selection {
            references,
            excluded,
        }
    }
}

/// Votes with the selected reference points only; what [`vote`] does with every
/// `reference_step`-th point. Points on the selection's large
/// planes are no one's partners either.
pub fn vote_from(
    model: &ObjectModel,
    scene: &PreparedScene,
    selection: &Selection,
    params: &VotingParams,
) -> (Vec<VotedPose>, VotingCounts) {
    let references = &selection.references[..];
    let skip_partner = |i: usize| selection.excluded.get(i).copied().unwrap_or(false);
    let data = model.data();
    let n_model = model.point_count();
    let alpha_bins = data.params.alpha_bins.to_native();
    let quantizer = model.quantizer();
    let key_count = quantizer.key_count();
    let diameter = model.diameter_mm();
    let model_frames: Vec<LocalFrame> = (0..n_model)
        .map(|i| LocalFrame::new(&model.point(i), &model.normal(i)))
        .collect();
    let nb = alpha_bins as usize;

    let offsets = &data.table_offsets;
    let entries_all = &data.table_entries;
    // What the accumulator's unchecked counting relies on (a model file's entries are
    // checked on load, and a built table's are in range; this costs a pass over the table).
    assert!(
        entries_all
            .iter()
            .all(|e| ((e.to_native() >> 16) as usize) < n_model),
        "a table entry names a model point past the model's {n_model}"
    );
    assert!(nb <= ROW, "{nb} α bins, at most {ROW}");
    // Per key: where its entries start, and its vote-once flags, all bits set when it holds no
    // entries so that it never votes; one slot past the last key ends the last key's entries.
    let empty_slots: Vec<KeySlot> = (0..=key_count)
        .map(|k| KeySlot {
            start: offsets[k].to_native(),
            flags: if k == key_count || offsets[k] == offsets[k + 1] {
                u32::MAX
            } else {
                0
            },
        })
        .collect();
    // A few blocks per thread, each with its own scratch: enough to balance the load, few
    // enough that the scratch (540 KB of key slots, and 192 bytes per model point for the
    // accumulator: its copies' low bytes, its carries and its totals) is set up only a
    // handful of times.
    let block = references
        .len()
        .div_ceil(4 * rayon::current_num_threads())
        .max(16);
    let results: Vec<(Vec<VotedPose>, u64, u64)> = references
        .par_chunks(block)
        .map(|chunk| {
            let mut scratch = Scratch {
                accumulator: Accumulator::new(n_model * ROW),
                casts: Vec::new(),
                slots: empty_slots.clone(),
                touched_keys: Vec::new(),
                pairs: PairBatch::default(),
            };
            let s = &mut scratch;
            let mut out = Vec::new();
            let mut pairs = 0u64;
            let mut votes = 0u64;
            for &r in chunk {
                let (sr, nr) = (scene.points.positions[r], scene.points.normals[r]);
                let frame = LocalFrame::new(&sr, &nr);
                s.pairs.clear();
                let points = &scene.points;
                scene.within(&sr, diameter, |i| {
                    if i != r && !skip_partner(i) {
                        s.pairs.push(&points.positions[i], &points.normals[i]);
                    }
                });
                s.pairs.compute(&sr, &nr, &frame, &quantizer);
                let mut keys = [0u32; MAX_KEYS];
                for (c, &alpha_s_fixed) in s.pairs.coordinates.iter().zip(&s.pairs.alpha_fixed) {
                    if *c == PairBatch::COINCIDENT {
                        continue;
                    }
                    pairs += 1;
                    let n_keys = if params.neighbour_keys {
                        quantizer.keys_with_neighbours_at(*c, &mut keys)
                    } else {
                        match quantizer.key_at(*c) {
                            Some(k) => {
                                keys[0] = k;
                                1
                            }
                            None => 0,
                        }
                    };
                    let bit = 1u32 << fixed_bin(alpha_s_fixed, alpha_bins);
                    // Without branches: whether a key votes depends on the pair's noise, so
                    // two branches per key (empty? flagged?) are often mispredicted; without
                    // them voting takes about 6 % less (docs/METHOD.md §2.4). Every key writes
                    // a cast and a touched key; only a voting one (a new one) keeps them. An
                    // empty key's flags are all set (`empty_slots`), so it never votes and is
                    // never touched.
                    s.casts.reserve(MAX_KEYS);
                    s.touched_keys.reserve(MAX_KEYS);
                    let (mut n_casts, mut n_touched) = (s.casts.len(), s.touched_keys.len());
                    let casts = s.casts.spare_capacity_mut().as_mut_ptr();
                    let touched = s.touched_keys.spare_capacity_mut().as_mut_ptr();
                    let (casts_from, touched_from) = (n_casts, n_touched);
                    for &key in &keys[..n_keys] {
                        let k = key as usize;
                        let flag = s.slots[k].flags;
                        let new = flag & bit == 0;
                        let (start, end) = (s.slots[k].start, s.slots[k + 1].start);
                        // SAFETY: at most `MAX_KEYS` writes per pair, each within the
                        // capacity reserved above; only the first `n_casts` and `n_touched`
                        // (all written) are kept.
                        unsafe {
                            casts
                                .add(n_casts - casts_from)
                                .write(std::mem::MaybeUninit::new(Cast {
                                    start,
                                    end,
                                    alpha_s: alpha_s_fixed,
                                }));
                            touched
                                .add(n_touched - touched_from)
                                .write(std::mem::MaybeUninit::new(key));
                        }
                        votes += u64::from(end - start) * u64::from(new);
                        n_casts += usize::from(new);
                        if params.vote_once {
                            n_touched += usize::from(flag == 0);
                            s.slots[k].flags = flag | bit;
                        }
                    }
                    // SAFETY: the first `n_casts` casts and `n_touched` keys are written.
                    unsafe {
                        s.casts.set_len(n_casts);
                        s.touched_keys.set_len(n_touched);
                    }
                }
                // SAFETY: every entry names a model point below `n_model` and there are at
                // most `ROW` α bins (both checked above); the accumulator has `n_model * ROW`
                // cells.
                unsafe {
                    s.accumulator
                        .add_casts(entries_all, &s.casts, alpha_bins as u16)
                };
                s.casts.clear();
                s.accumulator.merge();
                for &k in &s.touched_keys {
                    s.slots[k as usize].flags = 0; // a touched key has entries (see `empty_slots`)
                }
                s.touched_keys.clear();
                let totals = &s.accumulator.totals;
                peaks(totals, &s.accumulator.row_max, nb, params, |cell, votes| {
                    let (m, a) = (cell >> ROW_SHIFT, (cell & (ROW - 1)) as u32);
                    let mut alpha = alpha_of_bin(a, alpha_bins);
                    if params.interpolate_alpha {
                        let row = &totals[m * ROW..m * ROW + nb];
                        let below = row[(a as usize + nb - 1) % nb];
                        let above = row[(a as usize + 1) % nb];
                        alpha += sub_bin_offset(below as u32, votes, above as u32)
                            * (2.0 * std::f32::consts::PI / nb as f32);
                    }
                    out.push(VotedPose {
                        pose: pose_from_alignment(&frame, &model_frames[m], alpha),
                        votes,
                        scene_point: r as u32,
                        model_point: m as u32,
                    });
                });
            }
            (out, pairs, votes)
        })
        .collect();
    let mut counts = VotingCounts {
        reference_points: references.len() as u32,
        ..Default::default()
    };
    let mut hypotheses = Vec::new();
    for (h, p, v) in results {
        hypotheses.extend(h);
        counts.pairs += p;
        counts.votes += v;
    }
    (hypotheses, counts)
}

/// The bin of an angle given in fixed point (as [`crate::model::table::alpha_to_fixed`] makes it) among `bins`:
/// the same bins as [`crate::model::feature::alpha_bin`] (both start at −π).
#[inline]
fn fixed_bin(alpha_fixed: u16, bins: u32) -> u32 {
    (alpha_fixed as u32 * bins) >> 16
}

/// Where the peak of a parabola through `(−1, below)`, `(0, centre)`, `(1, above)` lies, in
/// bins, within `[−0.5, 0.5]` (0 when the centre is not a strict maximum of a concave parabola).
#[inline]
fn sub_bin_offset(below: u32, centre: u32, above: u32) -> f32 {
    let (b, c, a) = (below as f32, centre as f32, above as f32);
    let curvature = b - 2.0 * c + a;
    if curvature >= 0.0 {
        return 0.0;
    }
    (0.5 * (b - a) / curvature).clamp(-0.5, 0.5)
}

/// Calls `emit(cell, votes)` for up to `peaks_per_reference` highest cells with at least
/// `peak_ratio` of the maximum (and at least one vote), highest first. A cell next to a better
/// peak's cell in the same model point's row (±1 α bin, circularly over `nb` bins) is the same
/// peak's flank, not a second pose: it is skipped, so one reference point does not vote twice
/// for one pose cluster. `row_max` holds each row's largest cell (rows of [`ROW`] cells).
fn peaks(
    acc: &[u16],
    row_max: &[u16],
    nb: usize,
    params: &VotingParams,
    mut emit: impl FnMut(usize, u32),
) {
    let k = params.peaks_per_reference.max(1);
    debug_assert_eq!(row_max.len(), acc.len().div_ceil(ROW));
    let max = row_max.iter().copied().max().unwrap_or(0) as u32;
    if max == 0 {
        return;
    }
    let threshold = ((params.peak_ratio * max as f32).ceil() as u32).clamp(1, max) as u16;
    // The best `3 k` cells at or above the threshold, highest first (equal counts in scan
    // order): each of the `k` peaks taken can hide at most two flank cells, so the `k` peaks
    // are among them. Most rows hold no cell near the maximum: their maximum skips them whole.
    let keep = 3 * k;
    let mut candidates: Vec<(u32, usize)> = Vec::with_capacity(keep + 1);
    for (row, cells) in acc.chunks(ROW).enumerate() {
        if row_max[row] < threshold {
            continue;
        }
        for (i, &v) in cells.iter().enumerate() {
            if v < threshold {
                continue;
            }
            let v = v as u32;
            if candidates.len() == keep && v <= candidates[keep - 1].0 {
                continue;
            }
            let pos = candidates.partition_point(|&(bv, _)| bv >= v);
            candidates.insert(pos, (v, row * ROW + i));
            candidates.truncate(keep);
        }
    }
    let mut taken: Vec<usize> = Vec::with_capacity(k);
    for (v, cell) in candidates {
        if taken.len() == k {
            break;
        }
        let flank = taken.iter().any(|&t| {
            if t >> ROW_SHIFT != cell >> ROW_SHIFT {
                return false;
            }
            let (a, b) = (t & (ROW - 1), cell & (ROW - 1));
            let d = a.abs_diff(b);
            d <= 1 || d + 1 == nb
        });
        if flank {
            continue;
        }
        taken.push(cell);
        emit(cell, v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::table::entry_model_point;

    /// Each row's largest cell, as [`Accumulator::merge`] leaves them for [`peaks`].
    fn row_maxima(acc: &[u16]) -> Vec<u16> {
        acc.chunks(ROW)
            .map(|r| r.iter().copied().max().unwrap_or(0))
            .collect()
    }

    /// Counts past a byte carry exactly, whichever copy takes the votes, and saturate at
    /// 65 535; a merge leaves every copy and carry cleared for the next reference point.
    #[test]
    fn the_accumulator_counts_past_a_byte_and_saturates_at_sixteen_bits() {
        let bins = 30u16;
        let mut acc = Accumulator::new(4 * ROW);
        // Entries of model point 2 at α_m = 0 (fixed point): with α_s = 0 they vote for bin
        // 15 (the bins start at −π).
        let entries: Vec<rkyv::Archived<u32>> = (0..1001)
            .map(|_| rkyv::Archived::<u32>::from_native(2 << 16))
            .collect();
        let cast = Cast {
            start: 0,
            end: entries.len() as u32,
            alpha_s: 0,
        };
        let cell = (2 << ROW_SHIFT) | 15;
        // 1001 votes from one cast, then 3 casts of 7 entries each: 1022 in all.
        let casts = [
            cast,
            Cast { end: 7, ..cast },
            Cast { end: 7, ..cast },
            Cast { end: 7, ..cast },
        ];
        // SAFETY: every entry names model point 2 < 4, and 30 bins <= ROW.
        unsafe { acc.add_casts(&entries, &casts, bins) };
        acc.merge();
        assert_eq!(acc.totals[cell], 1022);
        assert_eq!(acc.totals.iter().map(|&v| v as u32).sum::<u32>(), 1022);
        assert_eq!(acc.row_max, row_maxima(&acc.totals));
        assert!(acc.lanes.iter().all(|&v| v == 0) && acc.carries.iter().all(|&c| c == 0));

        // The next reference point starts from nothing.
        unsafe { acc.add_casts(&entries, &casts[1..2], bins) };
        acc.merge();
        assert_eq!(acc.totals[cell], 7);
        assert_eq!(acc.row_max, [0, 0, 7, 0]);

        // 70 070 votes saturate.
        let many = vec![cast; 70];
        unsafe { acc.add_casts(&entries, &many, bins) };
        acc.merge();
        assert_eq!(acc.totals[cell], u16::MAX);
        assert_eq!(acc.row_max, [0, 0, u16::MAX, 0]);
        assert_eq!(acc.totals.iter().filter(|&&v| v > 0).count(), 1);
    }

    /// Cells gathered over many casts count as each entry counted alone: casts longer than
    /// the gathering buffer, casts of one entry, and casts that end at the table's last entry
    /// (where the four-at-a-time reading stops).
    #[test]
    fn gathered_cells_count_as_each_entry_alone() {
        let (points, bins) = (37usize, 30u16);
        let mut rng = crate::geometry::rng::Rng::new(5);
        let entries: Vec<rkyv::Archived<u32>> = (0..6003)
            .map(|_| {
                let m = (rng.next_u64() % points as u64) as u32;
                let alpha_m = (rng.next_u64() & 0xffff) as u32;
                rkyv::Archived::<u32>::from_native((m << 16) | alpha_m)
            })
            .collect();
        let n = entries.len() as u32;
        let mut casts = vec![
            Cast {
                start: 0,
                end: n,
                alpha_s: 123,
            },
            Cast {
                start: n - 1,
                end: n,
                alpha_s: 40_000,
            },
            Cast {
                start: n - 3,
                end: n,
                alpha_s: 7,
            },
            Cast {
                start: 17,
                end: 17,
                alpha_s: 9,
            },
        ];
        for _ in 0..500 {
            let start = (rng.next_u64() % n as u64) as u32;
            let len = (rng.next_u64() % 30) as u32;
            casts.push(Cast {
                start,
                end: (start + len).min(n),
                alpha_s: (rng.next_u64() & 0xffff) as u16,
            });
        }
        let mut expected = vec![0u32; points * ROW];
        for c in &casts {
            for e in &entries[c.start as usize..c.end as usize] {
                let e = e.to_native();
                let bin = fixed_difference_bin(e as u16, c.alpha_s, bins as u32);
                expected[((e >> 16) as usize) << ROW_SHIFT | bin as usize] += 1;
            }
        }
        let mut acc = Accumulator::new(points * ROW);
        // SAFETY: every entry names a model point below 37, and 30 bins <= ROW.
        unsafe { acc.add_casts(&entries, &casts, bins) };
        acc.merge();
        let totals: Vec<u32> = acc.totals.iter().map(|&v| v as u32).collect();
        assert!(expected.iter().all(|&v| v < u16::MAX as u32));
        assert_eq!(totals, expected);
        assert!(expected.iter().sum::<u32>() > 2 * n);
    }

    #[test]
    fn sub_bin_offset_moves_towards_the_stronger_neighbour() {
        assert_eq!(sub_bin_offset(5, 10, 5), 0.0);
        assert!(sub_bin_offset(2, 10, 8) > 0.2);
        assert!(sub_bin_offset(8, 10, 2) < -0.2);
        // Equal neighbour and centre: the peak lies on the border between them.
        assert!((sub_bin_offset(0, 10, 10) - 0.5).abs() < 1e-6);
        assert_eq!(sub_bin_offset(0, 0, 0), 0.0);
        // A symmetric triangle sampled off-centre: true peak at +0.25.
        let f = |x: f32| (10.0 - 4.0 * (x - 0.25).abs()) as u32;
        let o = sub_bin_offset(f(-1.0), f(0.0), f(1.0));
        assert!(o > 0.0 && o < 0.5, "{o}");
    }

    /// The accumulator against a plain count: every pair within D (in the kd-tree's order:
    /// which pair of a (key, α bin) votes first decides the cells), its keys, the vote-once
    /// flags as a set, one counter per (model point, α bin).
    #[test]
    fn votes_match_a_plain_count() {
        use crate::model::feature::PointPairFeature;
        use crate::model::subsample::OrientedPoints;
        use crate::model::table::alpha_to_fixed;
        use crate::model::{ModelParams, ObjectModel};
        use nalgebra::{Translation3, UnitQuaternion};
        use std::collections::HashSet;

        let part = crate::synthetic::parts::Part::LBracket;
        let model = ObjectModel::build(&part.mesh(), 1, "l", &ModelParams::default()).unwrap();
        let d = model.diameter_mm();
        let pose = Pose::from_parts(
            Translation3::new(10.0, -20.0, 700.0),
            UnitQuaternion::from_euler_angles(0.3, -0.5, 1.1),
        );
        let surface = model.surface_points();
        let mut moved = OrientedPoints::default();
        for (p, n) in surface.positions.iter().zip(&surface.normals) {
            moved.push(pose * p, pose * n);
        }
        let scene = PreparedScene::new(&moved, &model.params().subsample_params(d)).unwrap();
        let mut checked = 0;
        // Each key votes once per α_s bin, or (`vote_once` off) as often as pairs fall under it.
        for vote_once in [true, false] {
            let params = VotingParams {
                peaks_per_reference: 1,
                interpolate_alpha: false,
                vote_once,
                ..Default::default()
            };
            let q = model.quantizer();
            let data = model.data();
            let bins = data.params.alpha_bins.to_native();
            let pts = &scene.points;
            for r in (0..pts.len()).step_by(7).take(25) {
                let one = Selection {
                    references: vec![r],
                    excluded: Vec::new(),
                };
                let (hyps, counts) = vote_from(&model, &scene, &one, &params);

                let (sr, nr) = (pts.positions[r], pts.normals[r]);
                let frame = LocalFrame::new(&sr, &nr);
                let mut acc = vec![0u32; model.point_count() * ROW];
                let mut cast = HashSet::new();
                let mut votes = 0u64;
                let mut partners = Vec::new();
                scene.within(&sr, d, |i| partners.push(i));
                assert!(partners.len() > 20);
                for i in partners {
                    let (si, ni) = (pts.positions[i], pts.normals[i]);
                    if i == r {
                        continue;
                    }
                    let Some(f) = PointPairFeature::compute(&sr, &nr, &si, &ni) else {
                        continue;
                    };
                    let alpha_s = alpha_to_fixed(frame.alpha(&si));
                    let mut keys = [0u32; MAX_KEYS];
                    let n = q.keys_with_neighbours(&f, &mut keys);
                    for &k in &keys[..n] {
                        let k = k as usize;
                        let (start, end) = (
                            data.table_offsets[k].to_native() as usize,
                            data.table_offsets[k + 1].to_native() as usize,
                        );
                        if start == end
                            || (vote_once && !cast.insert((k, fixed_bin(alpha_s, bins))))
                        {
                            continue;
                        }
                        for e in &data.table_entries[start..end] {
                            let e = e.to_native();
                            let a = fixed_difference_bin(e as u16, alpha_s, bins) as usize;
                            acc[(entry_model_point(e) as usize) * ROW + a] += 1;
                            votes += 1;
                        }
                    }
                }
                assert_eq!(
                    counts.votes, votes,
                    "reference point {r}, vote once: {vote_once}"
                );
                let max = acc.iter().copied().max().unwrap();
                assert!(max > 0);
                let h = &hyps[0];
                assert_eq!(h.votes, max, "reference point {r}, vote once: {vote_once}");
                let row = &acc[h.model_point as usize * ROW..][..ROW];
                assert_eq!(row.iter().copied().max(), Some(max));
                checked += 1;
            }
        }
        assert_eq!(checked, 50);
    }

    /// Reference points spread evenly: one per cube of the spacing, every cube that holds a
    /// point off the planes has one, and it is the cube's first point in the cloud's order.
    #[test]
    fn reference_points_are_spread_one_per_cube() {
        use crate::model::subsample::OrientedPoints;
        use nalgebra::{Point3, Vector3};
        use std::collections::{HashMap, HashSet};

        // A wavy sheet of points, 2 mm apart, 200 mm square.
        let mut sheet = OrientedPoints::default();
        for i in 0..100 {
            for j in 0..100 {
                let (x, y) = (i as f32 * 2.0, j as f32 * 2.0);
                let z = 600.0 + 10.0 * (x / 30.0).sin();
                sheet.push(Point3::new(x, y, z), -Vector3::z());
            }
        }
        let scene = PreparedScene::new(
            &sheet,
            &crate::model::subsample::SubsampleParams {
                leaf_mm: 2.5,
                cluster_angle: 0.5,
                neighbour_filtering: false,
            },
        )
        .unwrap();
        let points = &scene.points.positions;
        let diameter = 100.0;
        let params = VotingParams {
            reference_spacing_fraction: 0.1,
            reference_step: 1,
            ..Default::default()
        };
        let spread = Selection::new(&scene, &params, &[], diameter);
        let cube = |i: usize| cell_of(&points[i], 1.0 / 10.0);
        let mut first = HashMap::new();
        for i in 0..points.len() {
            first.entry(cube(i)).or_insert(i);
        }
        let chosen: HashSet<_> = spread.references.iter().map(|&r| cube(r)).collect();
        assert_eq!(chosen.len(), spread.references.len(), "two in one cube");
        assert_eq!(
            chosen.len(),
            first.len(),
            "a cube without a reference point"
        );
        assert!(spread.references.iter().all(|&r| first[&cube(r)] == r));
        // A few points per 10 mm cube of a sheet sampled every 2.5 mm.
        assert!(
            spread.references.len() * 10 < points.len(),
            "{}",
            points.len()
        );

        // Every second of them, and without spacing every second point.
        let halved = Selection::new(
            &scene,
            &VotingParams {
                reference_step: 2,
                ..params
            },
            &[],
            diameter,
        );
        let expected: Vec<usize> = spread.references.iter().copied().step_by(2).collect();
        assert_eq!(halved.references, expected);
        let strided = Selection::new(
            &scene,
            &VotingParams {
                reference_spacing_fraction: 0.0,
                reference_step: 2,
                ..params
            },
            &[],
            diameter,
        );
        let expected: Vec<usize> = (0..points.len()).step_by(2).collect();
        assert_eq!(strided.references, expected);
    }

    #[test]
    fn peaks_are_highest_first_and_above_ratio() {
        // One model point's row of 12 α bins.
        let acc: Vec<u16> = vec![0, 5, 9, 1, 10, 0, 0, 8, 0, 0, 0, 0];
        let params = VotingParams {
            peaks_per_reference: 3,
            peak_ratio: 0.8,
            ..Default::default()
        };
        let mut got = Vec::new();
        peaks(&acc, &row_maxima(&acc), 12, &params, |c, v| {
            got.push((c, v))
        });
        assert_eq!(got, vec![(4, 10), (2, 9), (7, 8)]);
        let params = VotingParams {
            peaks_per_reference: 3,
            peak_ratio: 0.95,
            ..Default::default()
        };
        got.clear();
        peaks(&acc, &row_maxima(&acc), 12, &params, |c, v| {
            got.push((c, v))
        });
        assert_eq!(got, vec![(4, 10)]);
        got.clear();
        peaks(&[0, 0, 0], &[0], 3, &params, |c, v| got.push((c, v)));
        assert!(got.is_empty());
        // Peaks in different accumulator rows (model points), one row without any.
        let mut acc = vec![0u16; 4 * ROW];
        acc[3] = 40;
        acc[2 * ROW + 7] = 50;
        acc[3 * ROW + 31] = 45;
        acc[3 * ROW] = 20;
        let params = VotingParams {
            peaks_per_reference: 2,
            peak_ratio: 0.5,
            ..Default::default()
        };
        got.clear();
        peaks(&acc, &row_maxima(&acc), 30, &params, |c, v| {
            got.push((c, v))
        });
        assert_eq!(got, vec![(2 * ROW + 7, 50), (3 * ROW + 31, 45)]);
    }

    /// The cells beside a peak in its own row (±1 α bin, also across the wrap from the last bin
    /// to the first) are its flanks, not second peaks; the same bins of another model point's
    /// row are peaks of their own.
    #[test]
    fn a_peaks_flanks_are_not_second_peaks() {
        let nb = 30;
        let params = VotingParams {
            peaks_per_reference: 2,
            peak_ratio: 0.5,
            ..Default::default()
        };
        let mut acc = vec![0u16; 3 * ROW];
        acc[ROW + 10] = 50;
        acc[ROW + 11] = 49; // flank of the peak
        acc[ROW + 9] = 48; // flank of the peak
        acc[ROW + 20] = 30; // a second peak of the same model point
        let mut got = Vec::new();
        peaks(&acc, &row_maxima(&acc), nb, &params, |c, v| {
            got.push((c, v))
        });
        assert_eq!(got, vec![(ROW + 10, 50), (ROW + 20, 30)]);

        // Across the wrap: bin 0 and bin 29 are neighbours.
        let mut acc = vec![0u16; 3 * ROW];
        acc[2 * ROW] = 40;
        acc[2 * ROW + nb - 1] = 39;
        acc[ROW + nb - 1] = 35; // the same bin in another model point's row
        got.clear();
        peaks(&acc, &row_maxima(&acc), nb, &params, |c, v| {
            got.push((c, v))
        });
        assert_eq!(got, vec![(2 * ROW, 40), (ROW + nb - 1, 35)]);
    }
}
