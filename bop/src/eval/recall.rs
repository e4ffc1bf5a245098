//! Matching estimates to ground truth and counting recall, as the BOP toolkit's
//! `pose_matching.match_poses` and `score.calc_localization_scores` do.

/// The BOP 2019 grid `0.05, 0.10, …, 0.50`: VSD's τ (fraction of the diameter) and its
/// correctness thresholds θ, and MSSD's thresholds (fraction of the diameter).
pub fn bop19_fractions() -> Vec<f64> {
    (1..=10).map(|i| i as f64 * 0.05).collect()
}

/// The BOP 2019 MSPD thresholds `5, 10, …, 50` pixels, for a 640-pixel-wide image (they are
/// scaled by `width / 640`).
pub fn bop19_mspd_thresholds_px() -> Vec<f64> {
    (1..=10).map(|i| i as f64 * 5.0).collect()
}

/// Greedy matching of one target's estimates to the ground-truth instances of its object.
///
/// `errors[e][g]` is the error of estimate `e` against instance `g`; the estimates must already
/// be in decreasing order of score and cut to the target's instance count. Each estimate in turn
/// takes the unmatched valid instance with the lowest error below `threshold` (strictly; on ties
/// the first), if there is one. Returns, per estimate, the instance it matched.
pub fn match_greedy(errors: &[Vec<f64>], gt_valid: &[bool], threshold: f64) -> Vec<Option<usize>> {
    let mut taken = vec![false; gt_valid.len()];
    errors
        .iter()
        .map(|row| {
            let mut best: Option<usize> = None;
            let mut best_error = threshold;
            for (g, &error) in row.iter().enumerate().take(gt_valid.len()) {
                if gt_valid[g] && !taken[g] && error < best_error {
                    best = Some(g);
                    best_error = error;
                }
            }
            if let Some(g) = best {
                taken[g] = true;
            }
            best
        })
        .collect()
}

/// Matched and total counts of valid ground-truth instances.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    /// Valid instances that an estimate matched.
    pub matched: usize,
    /// Valid instances.
    pub total: usize,
}

impl Tally {
    /// `matched / total`, 0 when there is nothing to find (as the toolkit reports it).
    pub fn recall(&self) -> f64 {
        if self.total == 0 {
            0.0
        } else {
            self.matched as f64 / self.total as f64
        }
    }

    /// Adds another tally.
    pub fn add(&mut self, other: Tally) {
        self.matched += other.matched;
        self.total += other.total;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_are_the_benchmarks() {
        let f = bop19_fractions();
        assert_eq!(f.len(), 10);
        assert!((f[0] - 0.05).abs() < 1e-12 && (f[9] - 0.5).abs() < 1e-12);
        assert_eq!(
            bop19_mspd_thresholds_px(),
            vec![5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0]
        );
    }

    #[test]
    fn best_scored_estimate_takes_its_closest_instance() {
        // Estimate 0 (best score) is closest to instance 1; estimate 1 then takes instance 0.
        let errors = vec![vec![0.2, 0.1], vec![0.15, 0.05]];
        assert_eq!(
            match_greedy(&errors, &[true, true], 0.3),
            vec![Some(1), Some(0)]
        );
        // Below the threshold only: estimate 1's error to instance 0 is too large at 0.12.
        assert_eq!(
            match_greedy(&errors, &[true, true], 0.12),
            vec![Some(1), None]
        );
    }

    #[test]
    fn threshold_is_strict_and_invalid_instances_are_never_matched() {
        assert_eq!(match_greedy(&[vec![0.3]], &[true], 0.3), vec![None]);
        assert_eq!(
            match_greedy(&[vec![0.0, 0.2]], &[false, true], 0.3),
            vec![Some(1)]
        );
        assert_eq!(match_greedy(&[vec![0.0]], &[false], 0.3), vec![None]);
    }

    #[test]
    fn ties_go_to_the_first_instance() {
        assert_eq!(
            match_greedy(&[vec![0.1, 0.1]], &[true, true], 0.3),
            vec![Some(0)]
        );
    }

    #[test]
    fn recall_of_nothing_is_zero() {
        assert_eq!(Tally::default().recall(), 0.0);
        let mut t = Tally {
            matched: 1,
            total: 4,
        };
        t.add(Tally {
            matched: 2,
            total: 2,
        });
        assert_eq!(t.recall(), 0.5);
    }
}
