//! What one mesh or one model may cost, and the sizes that make sense in millimetres. These are
//! decisions, not accidents: each default is far above what a picking cell needs (the LM-O and
//! YCB-Video meshes have at most a few hundred thousand faces, and their models are at most a
//! few megabytes), and far below what would exhaust a host. The daemon's own limits (frames,
//! loads) are beside its configuration; the port limits are in `ppfd-protocol`.

use crate::file::Limit;

/// Faces of one mesh. Building takes about 230 bytes per face, so this bounds one build at
/// about half a gigabyte.
pub const MAX_MESH_FACES: usize = 2_000_000;
/// Vertices of one mesh (a closed mesh has about half as many vertices as faces).
pub const MAX_MESH_VERTICES: usize = 2_000_000;
/// How a caller gets past [`MAX_MESH_FACES`] or [`MAX_MESH_VERTICES`].
pub const MESH_RAISE: &str =
    "decimate the mesh, or raise ppfd_models::limits::MAX_MESH_FACES / MAX_MESH_VERTICES and rebuild ppfd";

/// One mesh file: an ASCII PLY of [`MAX_MESH_FACES`] faces is about 150 MB.
pub const MESH_FILE: Limit = Limit {
    what: "mesh file",
    max_bytes: 512 << 20,
    raise: "decimate the mesh, or raise ppfd_models::limits::MESH_FILE and rebuild ppfd",
};

/// One model file: a model of the largest mesh is about 40 MB; the usual ones are under 16 MB.
pub const MODEL_FILE: Limit = Limit {
    what: "model file",
    max_bytes: 64 << 20,
    raise: "rebuild the model from a decimated mesh, or raise ppfd_models::limits::MODEL_FILE and rebuild ppfd",
};

/// The smallest object diameter taken as millimetres: a mesh in metres has a diameter of a few
/// tenths at most (a 100 mm part is 0.1).
pub const MIN_DIAMETER_MM: f32 = 2.0;
/// The largest object diameter taken as millimetres (10 m): beyond it the mesh is in
/// micrometres or another unit.
pub const MAX_DIAMETER_MM: f32 = 10_000.0;

/// Below this diameter a model is built with a warning: at 1 m a VGA depth pixel spans about
/// 1.7 mm, so a few pixels cover the object and a model this small matches any blob of the
/// scene; a mesh in centimetres (or inches) lands here too, where metres are refused.
pub const SMALL_DIAMETER_MM: f32 = 20.0;

/// The warning for a diameter below [`SMALL_DIAMETER_MM`]; `None` for a larger one.
pub fn small_diameter(diameter: f32) -> Option<String> {
    (diameter < SMALL_DIAMETER_MM).then(|| {
        format!(
            "the diameter is {diameter:.1} mm, below {SMALL_DIAMETER_MM} mm: depth sensors see \
             few points of an object this small, and its model matches small blobs of any \
             scene; if the mesh is in centimetres, scale it by 10 (inches: 25.4) with `ppf \
             model build --scale`"
        )
    })
}

/// The fewest subsampled model points a model may have. Subsampling takes its leaf from the
/// diameter, so a surface that spans its mesh's extent gives hundreds (the LM-O models have
/// 300–1 000); a handful means that the faces cover almost nothing of the extent the vertices
/// claim (a few faces far apart), and a model of them votes for any small blob.
pub const MIN_MODEL_POINTS: usize = 16;

/// The refusal of a diameter outside [`MIN_DIAMETER_MM`]..=[`MAX_DIAMETER_MM`], with the scale
/// that would bring it into millimetres; `None` for a sane one.
pub fn diameter_out_of_range(diameter: f32) -> Option<String> {
    if (MIN_DIAMETER_MM..=MAX_DIAMETER_MM).contains(&diameter) {
        return None;
    }
    let unit = if diameter.is_infinite() {
        return Some(
            "the diameter overflows: a vertex lies beyond 10^19 mm (a stray vertex, or a \
             value that is not a coordinate)"
                .to_string(),
        );
    } else if !diameter.is_finite() || diameter <= 0.0 {
        return Some(format!(
            "the diameter is {diameter} mm: the mesh has no extent"
        ));
    } else if diameter < MIN_DIAMETER_MM {
        // The unit whose factor brings it nearest a 100 mm part.
        [(1000.0, "metres"), (10.0, "centimetres")]
            .into_iter()
            .find(|(f, _)| diameter * f >= MIN_DIAMETER_MM)
            .unwrap_or((1000.0, "metres"))
    } else {
        [(0.001, "micrometres"), (0.1, "tenths of a millimetre")]
            .into_iter()
            .find(|(f, _)| diameter * f <= MAX_DIAMETER_MM)
            .unwrap_or((0.001, "micrometres"))
    };
    let (factor, name) = unit;
    Some(format!(
        "the diameter is {diameter} mm, outside {MIN_DIAMETER_MM}..{MAX_DIAMETER_MM} mm: the \
         mesh looks like it is in {name}; scale it by {factor} to millimetres (`ppf model build \
         --scale {factor}` makes a model file of it so; a mesh file read as it is must itself \
         be in millimetres)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_diameter_in_metres_is_named_with_its_scale() {
        assert_eq!(diameter_out_of_range(100.0), None);
        let m = diameter_out_of_range(0.1).unwrap();
        assert!(m.contains("metres") && m.contains("--scale 1000"), "{m}");
        let m = diameter_out_of_range(1e30).unwrap();
        assert!(
            m.contains("micrometres") && m.contains("--scale 0.001"),
            "{m}"
        );
        assert!(diameter_out_of_range(f32::NAN).is_some());
        let m = diameter_out_of_range(0.0).unwrap();
        assert!(m.contains("no extent"), "{m}");
        // A vertex so far out that the distance overflows is named as such, not as no extent.
        let m = diameter_out_of_range(f32::INFINITY).unwrap();
        assert!(m.contains("overflows") && m.contains("stray vertex"), "{m}");
    }
}
