//! The detector's parameters by name: `stage.field` (`voting.reference_step`,
//! `filters.min_silhouette_fraction`, …), as `ppf detect --set` and the daemon's configuration
//! give them.
//!
//! ```
//! use ppfd_models::detect::detector::DetectParams;
//!
//! let mut p = DetectParams::new();
//! p.set("voting.reference_step", "4").unwrap();
//! assert_eq!(p.voting.reference_step, 4);
//! assert!(p.set("voting.reference_steps", "4").is_err());
//! assert!(p.set("rescoring.support_weight", "NaN").is_err());
//! ```

use crate::detect::detector::DetectParams;

/// A parameter's value as text, both ways.
trait Value: Sized {
    /// What the text must be, for errors.
    const EXPECTED: &'static str;
    fn parse(text: &str) -> Option<Self>;
    fn show(&self) -> String;
    /// The value as a number, for range checks; `None` for kinds that have no order.
    fn number(&self) -> Option<f64> {
        None
    }
}

/// Numbers: parsed with `FromStr` and accepted when `ok` holds.
macro_rules! number_value {
    ($($t:ty: $expected:literal, $ok:expr;)*) => {$(
        impl Value for $t {
            const EXPECTED: &'static str = $expected;
            fn parse(text: &str) -> Option<$t> {
                text.trim().parse().ok().filter($ok)
            }
            fn show(&self) -> String {
                self.to_string()
            }
            fn number(&self) -> Option<f64> {
                Some(*self as f64)
            }
        }
    )*};
}

number_value! {
    f32: "a finite number", |v: &f32| v.is_finite();
    usize: "a whole number", |_: &usize| true;
    u32: "a whole number", |_: &u32| true;
}

impl Value for bool {
    const EXPECTED: &'static str = "true or false";
    fn parse(text: &str) -> Option<bool> {
        text.trim().parse().ok()
    }
    fn show(&self) -> String {
        self.to_string()
    }
}

/// Smallest and largest value of a number, `None` for other kinds.
type Range = Option<(f64, f64)>;

/// Parses a value's text, checks it against the range and sets the field.
type Setter = fn(&mut DetectParams, &str, Range) -> Result<(), String>;

/// One named parameter: how to set it from text and show it as text.
struct Setting {
    key: &'static str,
    /// Smallest and largest value allowed, for numbers: beyond them a stage would do nothing
    /// useful, or loop over windows of millions of pixels.
    range: Range,
    set: Setter,
    get: fn(&DetectParams) -> String,
}

fn parsed<T: Value>(key: &str, text: &str, range: Range) -> Result<T, String> {
    let value = T::parse(text).ok_or_else(|| match range {
        Some((lo, hi)) => format!(
            "{key}: expected {} in {lo}..={hi}, got {text:?}",
            T::EXPECTED
        ),
        None => format!("{key}: expected {}, got {text:?}", T::EXPECTED),
    })?;
    if let (Some(x), Some((lo, hi))) = (value.number(), range) {
        if !(lo..=hi).contains(&x) {
            return Err(format!("{key}: {} is outside {lo}..={hi}", text.trim()));
        }
    }
    Ok(value)
}

macro_rules! range {
    () => {
        None
    };
    ($lo:literal, $hi:literal) => {
        Some(($lo as f64, $hi as f64))
    };
}

macro_rules! settings {
    ($($key:literal => $($field:ident).+ $(in $lo:literal ..= $hi:literal)?;)*) => {
        /// Every parameter that has a name, in the order of [`DetectParams`]' stages.
        const SETTINGS: &[Setting] = &[$(
            Setting {
                key: $key,
                range: range!($($lo, $hi)?),
                set: |p, text, range| {
                    p.$($field).+ = parsed($key, text, range)?;
                    Ok(())
                },
                get: |p| Value::show(&p.$($field).+),
            },
        )*];
    };
}

settings! {
    "scene.normal_radius_mm" => scene.normal_radius_mm in 0.5..=100.0;
    "scene.normal_radius_px" => scene.normal_radius_px in 0..=16;
    "scene.max_slope_deg" => scene.max_slope_deg in 0.0..=89.9;
    "scene.min_depth_jump_mm" => scene.min_depth_jump_mm in 0.0..=1000.0;
    "scene.min_depth_mm" => scene.min_depth_mm in 0.0..=100000.0;
    "scene.max_depth_mm" => scene.max_depth_mm in 0.0..=100000.0;
    "scene.plane_residual_mm" => scene.plane_residual_mm in 0.0..=1000.0;
    "scene.plane_residual_fraction" => scene.plane_residual_fraction in 0.0..=1.0;
    "scene.plane_samples_per_axis" => scene.plane_samples_per_axis in 3..=33;
    "plane.enabled" => plane.enabled;
    "plane.tolerance_mm" => plane.tolerance_mm in 0.0..=1000.0;
    "plane.tolerance_fraction" => plane.tolerance_fraction in 0.0..=1.0;
    "plane.max_normal_angle_deg" => plane.max_normal_angle_deg in 0.0..=90.0;
    "plane.min_inlier_fraction" => plane.min_inlier_fraction in 0.0..=1.0;
    "plane.min_secondary_fraction" => plane.min_secondary_fraction in 0.0..=1.0;
    "plane.max_planes" => plane.max_planes in 0..=16;
    "plane.exclude_behind" => plane.exclude_behind;
    "voting.reference_spacing_fraction" => voting.reference_spacing_fraction in 0.0..=10.0;
    "voting.reference_step" => voting.reference_step in 1..=1000;
    "voting.neighbour_keys" => voting.neighbour_keys;
    "voting.vote_once" => voting.vote_once;
    "voting.peaks_per_reference" => voting.peaks_per_reference in 1..=32;
    "voting.peak_ratio" => voting.peak_ratio in 0.0..=1.0;
    "voting.interpolate_alpha" => voting.interpolate_alpha;
    "clustering.translation_fraction" => clustering.translation_fraction in 0.001..=10.0;
    "clustering.rotation_deg" => clustering.rotation_deg in 0.0..=180.0;
    "clustering.refine_rotation_deg" => clustering.refine_rotation_deg in 0.0..=180.0;
    "clustering.refine_rotation_shrink" => clustering.refine_rotation_shrink in 0.0..=1.0;
    "clustering.refine_translation_fraction" => clustering.refine_translation_fraction in 0.0..=10.0;
    "clustering.refine_iterations" => clustering.refine_iterations in 0..=100;
    "rescoring.top_clusters" => rescoring.top_clusters in 1..=100000;
    "rescoring.tolerance_fraction" => rescoring.tolerance_fraction in 0.0..=1.0;
    "rescoring.refined_tolerance_fraction" => rescoring.refined_tolerance_fraction in 0.0..=1.0;
    "rescoring.min_tolerance_mm" => rescoring.min_tolerance_mm in 0.0..=1000.0;
    "rescoring.max_normal_angle_deg" => rescoring.max_normal_angle_deg in 0.0..=180.0;
    "rescoring.conflict_fraction" => rescoring.conflict_fraction in 0.0..=1.0;
    "rescoring.min_conflict_mm" => rescoring.min_conflict_mm in 0.0..=1000.0;
    "rescoring.support_weight" => rescoring.support_weight in 0.0..=100.0;
    "rescoring.silhouette_weight" => rescoring.silhouette_weight in 0.0..=100.0;
    "rescoring.min_visible_outline" => rescoring.min_visible_outline in 0.0..=1.0;
    "rescoring.silhouette_mesh_cell_fraction" => rescoring.silhouette_mesh_cell_fraction in 0.0..=1.0;
    "rescoring.prescore_stride" => rescoring.prescore_stride in 1..=64;
    "rescoring.prescore_keep" => rescoring.prescore_keep in 0..=100000;
    "rescoring.coarse_outline_px" => rescoring.coarse_outline_px in 0..=100000;
    "rescoring.residual_scale_mm" => rescoring.residual_scale_mm in 0.001..=1000.0;
    "rescoring.residual_weight" => rescoring.residual_weight in 0.0..=100.0;
    "icp.top_poses" => icp.top_poses in 1..=100000;
    "icp.iterations" => icp.iterations in 0..=1000;
    "icp.initial_distance_fraction" => icp.initial_distance_fraction in 0.0..=1.0;
    "icp.final_distance_fraction" => icp.final_distance_fraction in 0.0..=1.0;
    "icp.max_normal_angle_deg" => icp.max_normal_angle_deg in 0.0..=180.0;
    "icp.coarse_iterations" => icp.coarse_iterations in 0..=1000;
    "icp.coarse_stride" => icp.coarse_stride in 1..=1000;
    "icp.min_constraint_ratio" => icp.min_constraint_ratio in 0.0..=1.0;
    "filters.max_see_through_fraction" => filters.max_see_through_fraction in 0.0..=1.0;
    "filters.min_support_fraction" => filters.min_support_fraction in 0.0..=1.0;
    "filters.edge_jump_mm" => filters.edge_jump_mm in 0.0..=1000.0;
    "filters.edge_jump_fraction" => filters.edge_jump_fraction in 0.0..=1.0;
    "filters.edge_radius_px" => filters.edge_radius_px in 0..=16;
    "filters.min_silhouette_fraction" => filters.min_silhouette_fraction in 0.0..=1.0;
    "filters.contour_probe_px" => filters.contour_probe_px in 0..=64;
    "filters.max_outline_px" => filters.max_outline_px in 0..=100000;
    "filters.max_candidates" => filters.max_candidates in 1..=100000;
    "exclusion.min_shared_fraction" => exclusion.min_shared_fraction in 0.0..=1.0;
    "exclusion.alternates" => exclusion.alternates in 0..=100;
    "nms_distance_fraction" => nms_distance_fraction in 0.0..=10.0;
    "shared_cloud_diameter_ratio" => shared_cloud_diameter_ratio in 1.0..=100.0;
    "scene_leaf_ratio" => scene_leaf_ratio in 0.5..=4.0;
}

/// The error for an unknown name: it lists the names of the same stage, or the stages.
fn unknown(key: &str) -> String {
    let stage = key.split_once('.').map_or(key, |(stage, _)| stage);
    let same_stage: Vec<&str> = SETTINGS
        .iter()
        .map(|s| s.key)
        .filter(|k| k.split_once('.').is_some_and(|(st, _)| st == stage))
        .collect();
    if same_stage.is_empty() {
        let mut stages: Vec<&str> = SETTINGS
            .iter()
            .map(|s| s.key.split_once('.').map_or(s.key, |(stage, _)| stage))
            .collect();
        stages.dedup();
        format!(
            "unknown detector parameter {key:?}; the stages are {}",
            stages.join(", ")
        )
    } else {
        format!(
            "unknown detector parameter {key:?}; the {stage} parameters are {}",
            same_stage.join(", ")
        )
    }
}

impl DetectParams {
    /// Sets the parameter named `key` (`stage.field`) from `value` as text. An unknown name,
    /// or a value that is not of the parameter's kind (a number that is NaN or infinite among
    /// them), is refused with a message that names it, and nothing changes.
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), String> {
        let Some(setting) = SETTINGS.iter().find(|s| s.key == key) else {
            return Err(unknown(key));
        };
        (setting.set)(self, value, setting.range)
    }

    /// [`DetectParams::set`] from `stage.field=value`.
    pub fn set_from(&mut self, assignment: &str) -> Result<(), String> {
        let (key, value) = assignment.split_once('=').ok_or_else(|| {
            format!("a detector parameter is set as stage.field=value, got {assignment:?}")
        })?;
        self.set(key.trim(), value)
    }

    /// The value of the parameter named `key`, as text [`DetectParams::set`] takes.
    pub fn get(&self, key: &str) -> Option<String> {
        SETTINGS
            .iter()
            .find(|s| s.key == key)
            .map(|s| (s.get)(self))
    }

    /// The smallest and largest value [`DetectParams::set`] takes for the parameter named
    /// `key`; `None` for a parameter that is no number (or an unknown name).
    pub fn range(key: &str) -> Option<(f64, f64)> {
        SETTINGS.iter().find(|s| s.key == key).and_then(|s| s.range)
    }

    /// Refuses parameters that are each within range but cannot work together, naming them.
    pub fn check(&self) -> Result<(), String> {
        let scene = &self.scene;
        if scene.min_depth_mm >= scene.max_depth_mm {
            return Err(format!(
                "scene.min_depth_mm ({}) must be below scene.max_depth_mm ({}): no depth would be kept",
                scene.min_depth_mm, scene.max_depth_mm
            ));
        }
        Ok(())
    }

    /// The names of all parameters [`DetectParams::set`] knows.
    pub fn keys() -> impl Iterator<Item = &'static str> {
        SETTINGS.iter().map(|s| s.key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_depth_range_that_keeps_nothing_is_refused() {
        let mut p = DetectParams::new();
        assert!(p.check().is_ok());
        p.set("scene.min_depth_mm", "6000").unwrap();
        let e = p.check().unwrap_err();
        assert!(
            e.contains("scene.min_depth_mm") && e.contains("scene.max_depth_mm"),
            "{e}"
        );
        p.set("scene.max_depth_mm", "7000").unwrap();
        assert!(p.check().is_ok());
    }

    /// Another value of the parameter's kind, within its range.
    fn another_value(key: &str, shown: &str) -> String {
        match shown {
            "true" => return "false".into(),
            "false" => return "true".into(),
            _ => {}
        }
        let d: f64 = shown.parse().unwrap();
        let (lo, hi) = DetectParams::range(key).unwrap_or_else(|| panic!("{key} has no range"));
        assert!(
            (lo..=hi).contains(&d),
            "{key}: default {d} outside {lo}..={hi}"
        );
        let v = if d < hi {
            (d + hi) / 2.0
        } else {
            (lo + d) / 2.0
        };
        let mut p = DetectParams::new();
        if p.set(key, "0.5")
            .is_err_and(|e| e.contains("a whole number"))
        {
            // A count: a whole number between the default and a bound.
            let v = if d < hi { v.ceil() } else { v.floor() };
            return format!("{v}");
        }
        format!("{}", v as f32)
    }

    #[test]
    fn every_key_reads_back_what_was_set_and_nothing_else_changes() {
        let default = DetectParams::new();
        for key in DetectParams::keys() {
            let shown = default.get(key).unwrap();
            let other = another_value(key, &shown);
            assert_ne!(other, shown, "{key}");
            let mut p = default.clone();
            p.set(key, &other).unwrap();
            assert_eq!(p.get(key).unwrap(), other, "{key}");
            for other_key in DetectParams::keys().filter(|k| *k != key) {
                assert_eq!(
                    p.get(other_key),
                    default.get(other_key),
                    "{key} changed {other_key}"
                );
            }
            p.set(key, &shown).unwrap();
            assert_eq!(format!("{p:?}"), format!("{default:?}"), "{key}");
        }
    }

    #[test]
    fn keys_are_unique() {
        let mut keys: Vec<_> = DetectParams::keys().collect();
        let n = keys.len();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), n);
    }

    #[test]
    fn bad_names_and_values_are_refused_and_change_nothing() {
        let mut p = DetectParams::new();
        let before = format!("{p:?}");
        let refused = [
            ("voting.reference_steps", "4", "unknown detector parameter"),
            ("voting.reference_step", "-1", "a whole number in 1..=1000"),
            ("voting.reference_step", "two", "a whole number in 1..=1000"),
            ("filters.min_silhouette_fraction", "NaN", "finite"),
            ("filters.min_silhouette_fraction", "inf", "finite"),
            ("voting.vote_once", "yes", "true or false"),
            ("scene.normal_radius_px", "1000000", "outside 0..=16"),
            ("voting.reference_step", "0", "outside 1..=1000"),
            ("filters.min_silhouette_fraction", "1.5", "outside 0..=1"),
            ("clustering.rotation_deg", "-5", "outside"),
            // No pose refined is no pose answered.
            ("icp.top_poses", "0", "outside 1..=100000"),
        ];
        for (key, value, said) in refused {
            let e = p.set(key, value).unwrap_err();
            assert!(e.contains(said) && e.contains(key), "{key}={value}: {e}");
        }
        let e = p.set("voting.steps", "4").unwrap_err();
        assert!(e.contains("voting.reference_step, "), "{e}");
        let e = p.set("votes.reference_step", "4").unwrap_err();
        assert!(e.contains("scene, plane, voting, clustering"), "{e}");
        let e = p.set_from("voting.reference_step").unwrap_err();
        assert!(e.contains("stage.field=value"), "{e}");
        assert_eq!(format!("{p:?}"), before);
        p.set_from("voting.reference_step = 4").unwrap();
        assert_eq!(p.voting.reference_step, 4);
    }
}
