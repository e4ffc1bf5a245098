//! PLY input: the header decides what is read, one element at a time, so that every error can
//! say which element (and, for ASCII, which line) was wrong.

use std::io::{BufRead, BufReader, ErrorKind, Read};
use std::path::Path;

use nalgebra::{Point3, Vector3};
use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{
    ElementDef, Encoding, Header, Property, PropertyAccess, PropertyAccessResult, PropertyType,
    ScalarType,
};

use crate::limits::{MAX_MESH_FACES, MAX_MESH_VERTICES, MESH_RAISE};

use super::{is_degenerate, unit_f32, vertex_normals_from_faces, with_normals_from_faces, Mesh};
use crate::{Error, Result};

/// Names of the face element's index list, in order of preference.
const FACE_INDEX_NAMES: [&str; 2] = ["vertex_indices", "vertex_index"];

/// Caps what a header's element count can make us allocate before the data is seen.
const MAX_PREALLOCATED: usize = 1 << 16;

/// One vertex as stored in the file: `x y z nx ny nz` (zero where the header has no such
/// property), whatever their scalar type.
#[derive(Clone, Copy, Default)]
struct VertexRecord {
    values: [f64; 6],
}

impl PropertyAccess for VertexRecord {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let slot = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            "nx" => 3,
            "ny" => 4,
            "nz" => 5,
            _ => return PropertyAccessResult::Ignored,
        };
        match scalar_as_f64(&property) {
            Some(v) => {
                self.values[slot] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

/// One face as stored in the file: its vertex indices, widened so that negative ones survive
/// until they are reported.
#[derive(Default)]
struct FaceRecord {
    indices: Vec<i64>,
}

impl PropertyAccess for FaceRecord {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if !FACE_INDEX_NAMES.contains(&name) {
            return PropertyAccessResult::Ignored;
        }
        fn widen<T: Copy + Into<i64>>(values: &[T]) -> Vec<i64> {
            values.iter().map(|&v| v.into()).collect()
        }
        self.indices = match &property {
            Property::ListChar(v) => widen(v),
            Property::ListUChar(v) => widen(v),
            Property::ListShort(v) => widen(v),
            Property::ListUShort(v) => widen(v),
            Property::ListInt(v) => widen(v),
            Property::ListUInt(v) => widen(v),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// An element this reader does not use: read past, nothing kept.
struct Skipped;

impl PropertyAccess for Skipped {
    fn new() -> Self {
        Skipped
    }
}

fn scalar_as_f64(property: &Property) -> Option<f64> {
    Some(match *property {
        Property::Char(v) => v.into(),
        Property::UChar(v) => v.into(),
        Property::Short(v) => v.into(),
        Property::UShort(v) => v.into(),
        Property::Int(v) => v.into(),
        Property::UInt(v) => v.into(),
        Property::Float(v) => v.into(),
        Property::Double(v) => v,
        _ => return None,
    })
}

/// What the header promises, checked before any data is read.
struct Layout {
    has_normals: bool,
}

impl Layout {
    fn from_header(header: &Header) -> std::result::Result<Layout, String> {
        let vertex = header.elements.get("vertex").ok_or_else(|| {
            "the mesh is empty: the header declares no 'vertex' element".to_string()
        })?;
        if vertex.count == 0 {
            return Err("the mesh is empty: the header declares 0 vertices".into());
        }
        let is_number = |name: &str| -> std::result::Result<bool, String> {
            match vertex.properties.get(name).map(|p| &p.data_type) {
                None => Ok(false),
                Some(PropertyType::Scalar(_)) => Ok(true),
                Some(PropertyType::List(..)) => Err(format!(
                    "vertex property '{name}' is a list, expected one number"
                )),
            }
        };
        for axis in ["x", "y", "z"] {
            if !is_number(axis)? {
                return Err(format!(
                    "the 'vertex' element has no '{axis}' property (vertices need x, y and z)"
                ));
            }
        }
        let normal_axes = [is_number("nx")?, is_number("ny")?, is_number("nz")?];
        let has_normals = normal_axes.iter().all(|&b| b);
        if !has_normals && normal_axes.iter().any(|&b| b) {
            return Err("vertex normals need nx, ny and nz; the header declares only some".into());
        }
        if let Some(face) = header.elements.get("face") {
            let lists: Vec<_> = FACE_INDEX_NAMES
                .iter()
                .filter_map(|n| face.properties.get(*n))
                .collect();
            match lists.as_slice() {
                [] => {
                    return Err(
                        "the 'face' element has no 'vertex_indices' (or 'vertex_index') \
                                property"
                            .into(),
                    )
                }
                [one] => match &one.data_type {
                    PropertyType::List(_, ScalarType::Float | ScalarType::Double) => {
                        return Err(format!(
                            "face property '{}' holds floating-point values, expected integer \
                             vertex indices",
                            one.name
                        ))
                    }
                    PropertyType::List(..) => {}
                    PropertyType::Scalar(_) => {
                        return Err(format!(
                            "face property '{}' is a single number, expected a list of vertex \
                             indices",
                            one.name
                        ))
                    }
                },
                _ => {
                    return Err(
                        "the 'face' element has both 'vertex_indices' and 'vertex_index'; \
                                expected one"
                            .into(),
                    )
                }
            }
        }
        Ok(Layout { has_normals })
    }
}

/// Reads a whole mesh; see [`Mesh::from_ply_file`] for what is accepted.
pub(super) fn read_mesh<R: Read>(source: R, path: &Path) -> Result<Mesh> {
    let fail = |reason: String| Error::Ply {
        path: path.to_path_buf(),
        reason,
    };
    let mut reader = Reader::new(BufReader::new(source));
    let header = Parser::<Skipped>::new()
        .read_header(&mut reader)
        .map_err(|e| fail(format!("bad header: {}", flatten(&e))))?;
    let layout = Layout::from_header(&header).map_err(fail)?;
    // A well-formed file beyond a limit: refused as too large, not as malformed.
    let count = |element: &str| header.elements.get(element).map_or(0, |e| e.count);
    for (count, max, noun) in [
        (count("vertex"), MAX_MESH_VERTICES, "vertices"),
        (count("face"), MAX_MESH_FACES, "faces"),
    ] {
        if count > max {
            return Err(Error::File {
                path: path.to_path_buf(),
                reason: format!(
                    "the header declares {count} {noun}, more than the {max} a mesh may have \
                     ({MESH_RAISE})"
                ),
            });
        }
    }

    let mut vertices: Vec<VertexRecord> = Vec::new();
    let mut faces: Vec<FaceRecord> = Vec::new();
    let mut line = reader.line();
    for (name, element) in &header.elements {
        let input = reader.get_mut();
        match name.as_str() {
            "vertex" => {
                vertices = read_element(input, &header, element, &mut line).map_err(fail)?
            }
            "face" => faces = read_element(input, &header, element, &mut line).map_err(fail)?,
            _ => drop(read_element::<Skipped>(input, &header, element, &mut line).map_err(fail)?),
        }
    }
    let last = header.elements.values().last();
    check_end(reader.get_mut(), header.encoding, line, last).map_err(fail)?;
    build_mesh(&vertices, &faces, layout.has_normals).map_err(fail)
}

/// Refuses data after the last element (whitespace aside): a header that declares fewer items
/// than the file holds is as wrong as one that declares more, and reading only the declared
/// ones would build a model of part of the mesh.
fn check_end(
    input: &mut impl BufRead,
    encoding: Encoding,
    line_number: usize,
    last: Option<&ElementDef>,
) -> std::result::Result<(), String> {
    let mut offset = 0usize;
    loop {
        let chunk = input.fill_buf().map_err(|e| e.to_string())?;
        if chunk.is_empty() {
            return Ok(());
        }
        if let Some(at) = chunk.iter().position(|b| !b.is_ascii_whitespace()) {
            let lines = chunk[..at].iter().filter(|&&b| b == b'\n').count();
            let declared = last.map_or(String::new(), |e| {
                format!(" (the header declares {} {})", e.count, noun(e))
            });
            let place = match encoding {
                Encoding::Ascii => format!("line {}", line_number + lines),
                _ => format!("byte {} after the declared data", offset + at),
            };
            return Err(format!(
                "data after the last element{declared}, at {place}: does the header declare \
                 all the items the file holds?"
            ));
        }
        let n = chunk.len();
        offset += n;
        input.consume(n);
    }
}

/// The plural a message uses for `element`'s items.
fn noun(element: &ElementDef) -> String {
    match element.name.as_str() {
        "vertex" => "vertices".into(),
        "face" => "faces".into(),
        other => format!("'{other}' elements"),
    }
}

/// Reads the `element.count` items of one element, tracking the ASCII line number.
fn read_element<E: PropertyAccess>(
    input: &mut impl BufRead,
    header: &Header,
    element: &ElementDef,
    line_number: &mut usize,
) -> std::result::Result<Vec<E>, String> {
    let parser = Parser::<E>::new();
    let mut items = Vec::with_capacity(element.count.min(MAX_PREALLOCATED));
    let truncated = |i: usize| {
        format!(
            "truncated: the data ends after {i} of the {} {} the header declares",
            element.count,
            noun(element)
        )
    };
    let item_name = match element.name.as_str() {
        "vertex" | "face" => element.name.clone(),
        other => format!("'{other}' element"),
    };
    match header.encoding {
        Encoding::Ascii => {
            let scalars_only = element
                .properties
                .values()
                .all(|p| matches!(p.data_type, PropertyType::Scalar(_)));
            let mut text = String::new();
            for i in 0..element.count {
                text.clear();
                let read = input
                    .read_line(&mut text)
                    .map_err(|e| format!("{item_name} {i} (line {line_number}): {e}"))?;
                if read == 0 {
                    return Err(truncated(i));
                }
                if scalars_only {
                    let found = text.split_whitespace().count();
                    if found != element.properties.len() {
                        return Err(format!(
                            "{item_name} {i} (line {line_number}): expected {} values, found \
                             {found}; does the file hold all {} {} its header declares?",
                            element.properties.len(),
                            element.count,
                            noun(element)
                        ));
                    }
                    let not_finite = text
                        .split_whitespace()
                        .enumerate()
                        .find(|(_, word)| !word.parse::<f64>().is_ok_and(f64::is_finite));
                    if let Some((k, word)) = not_finite {
                        return Err(format!(
                            "{item_name} {i} (line {line_number}): value {} is '{}', not a \
                             finite number",
                            k + 1,
                            shown(word)
                        ));
                    }
                }
                let item = parser.read_ascii_element(&text, element).map_err(|e| {
                    format!("{item_name} {i} (line {line_number}): {}", flatten(&e))
                })?;
                items.push(item);
                *line_number += 1;
            }
        }
        Encoding::BinaryLittleEndian | Encoding::BinaryBigEndian => {
            let big = header.encoding == Encoding::BinaryBigEndian;
            for i in 0..element.count {
                let item = if big {
                    parser.read_big_endian_element(input, element)
                } else {
                    parser.read_little_endian_element(input, element)
                };
                let item = item.map_err(|e| {
                    if e.kind() == ErrorKind::UnexpectedEof {
                        truncated(i)
                    } else {
                        format!("{item_name} {i}: {}", flatten(&e))
                    }
                })?;
                items.push(item);
            }
        }
    }
    Ok(items)
}

/// Turns the records into a mesh: finite positions, fan-triangulated faces with indices in
/// range, unit normals from the file or from the faces.
fn build_mesh(
    vertices: &[VertexRecord],
    faces: &[FaceRecord],
    has_normals: bool,
) -> std::result::Result<Mesh, String> {
    let mut positions = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let p = Point3::new(v.values[0], v.values[1], v.values[2]).cast::<f32>();
        if !p.coords.iter().all(|c| c.is_finite()) {
            return Err(format!(
                "vertex {i}: coordinates ({:?}, {:?}, {:?}) are not finite numbers",
                v.values[0], v.values[1], v.values[2]
            ));
        }
        positions.push(p);
    }

    let vertex_count = positions.len();
    let mut triangles = Vec::with_capacity(faces.len());
    let mut skipped = 0usize;
    for (f, face) in faces.iter().enumerate() {
        let mut indices = Vec::with_capacity(face.indices.len());
        for &index in &face.indices {
            match u32::try_from(index) {
                Ok(v) if (v as usize) < vertex_count => indices.push(v),
                _ => {
                    return Err(format!(
                        "face {f}: vertex index {index} is out of range (the mesh has \
                         {vertex_count} vertices, numbered 0 to {})",
                        vertex_count.saturating_sub(1)
                    ))
                }
            }
        }
        if indices.len() < 3 {
            skipped += 1;
            continue;
        }
        for k in 1..indices.len() - 1 {
            let triangle = [indices[0], indices[k], indices[k + 1]];
            if is_degenerate(&positions, triangle) {
                skipped += 1;
            } else {
                triangles.push(triangle);
            }
        }
    }
    if skipped > 0 && triangles.is_empty() {
        // A point cloud (no faces) is read as one; faces that are all degenerate are a broken
        // mesh, named as such rather than as a mesh without faces.
        return Err(format!(
            "all {skipped} triangles of its faces are degenerate (a repeated vertex or zero area): no \
             surface to sample"
        ));
    }
    if skipped > 0 {
        tracing::debug!(
            skipped,
            kept = triangles.len(),
            "degenerate PLY faces skipped"
        );
    }

    // A vertex that no face uses is not on the surface the model samples, yet it would count
    // in the diameter, and so in every length of the model: one stray vertex half a metre out,
    // as CAD and decimation exports leave, makes a 100 mm part's model five times too coarse
    // to be found. Such vertices are dropped; a file without faces is a point cloud and keeps
    // all.
    // The file's number of each vertex of the mesh, when some are dropped.
    let mut kept: Option<Vec<usize>> = None;
    if !triangles.is_empty() {
        let mut used = vec![false; vertex_count];
        triangles
            .iter()
            .flatten()
            .for_each(|&v| used[v as usize] = true);
        if !used.iter().all(|&u| u) {
            let mut new_index = vec![u32::MAX; vertex_count];
            let in_file: Vec<usize> = (0..vertex_count).filter(|&i| used[i]).collect();
            for (j, &i) in in_file.iter().enumerate() {
                new_index[i] = j as u32;
            }
            for t in &mut triangles {
                *t = t.map(|v| new_index[v as usize]);
            }
            positions = in_file.iter().map(|&i| positions[i]).collect();
            tracing::debug!(
                dropped = vertex_count - in_file.len(),
                "PLY vertices that no face uses dropped"
            );
            kept = Some(in_file);
        }
    }
    let in_file = |j: usize| kept.as_ref().map_or(j, |k| k[j]);

    let mut face_normals = None;
    let mut normals = Vec::with_capacity(positions.len());
    if has_normals {
        // `i` is the vertex's number in the file, for messages; `j` its index in the mesh.
        for j in 0..positions.len() {
            let i = in_file(j);
            let v = &vertices[i];
            let n = Vector3::new(v.values[3], v.values[4], v.values[5]);
            if !n.iter().all(|c| c.is_finite()) {
                return Err(format!(
                    "vertex {i}: normal ({}, {}, {}) is not finite",
                    n.x, n.y, n.z
                ));
            }
            let unit = match unit_f32(&n) {
                Some(unit) => unit,
                None if triangles.is_empty() => {
                    return Err(format!(
                        "vertex {i}: the normal has zero length and there are no faces to \
                         compute one from"
                    ))
                }
                None => {
                    let from_faces = face_normals
                        .get_or_insert_with(|| vertex_normals_from_faces(&positions, &triangles));
                    from_faces[j].ok_or_else(|| {
                        format!(
                            "vertex {i}: the normal has zero length and the vertex lies on no \
                             face of non-zero area to compute one from"
                        )
                    })?
                }
            };
            normals.push(unit);
        }
    } else {
        if triangles.is_empty() {
            return Err(
                "no normals and no faces to compute them from (the file has no \
                        nx/ny/nz and no non-degenerate faces)"
                    .into(),
            );
        }
        return with_normals_from_faces(&positions, &triangles).map_err(|j| {
            let i = in_file(j);
            format!(
                "vertex {i}: the file has no normals and the vertex lies on no face of \
                 non-zero area to compute one from"
            )
        });
    }
    Ok(Mesh {
        positions,
        normals,
        faces: triangles,
    })
}

/// A parser message on one line, without the grammar's internal debug dump.
/// The parser's message on one line, its quote of the file [`shown`] safely.
fn flatten(error: &ParseError) -> String {
    let text = error.to_string().replace("\r\n'", "'").replace("\n'", "'");
    let text = text
        .split(['\n', '\t'])
        .map(str::trim)
        .filter(|s| !s.is_empty() && !s.starts_with("Error: ParseError"))
        .collect::<Vec<_>>()
        .join("; ");
    shown(&text)
}

/// Text taken from the file, fit for a message: cut short, its control characters escaped
/// (a garbage line can be megabytes of terminal escape codes).
fn shown(text: &str) -> String {
    const MAX_CHARS: usize = 200;
    let mut shown = String::new();
    for c in text.chars().take(MAX_CHARS) {
        if c.is_control() {
            shown.extend(c.escape_default());
        } else {
            shown.push(c);
        }
    }
    if text.chars().nth(MAX_CHARS).is_some() {
        shown.push('…');
    }
    shown
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    #[derive(Clone, Copy, Debug)]
    enum Format {
        Ascii,
        Le,
        Be,
    }

    /// A PLY file described in the test: vertex properties with their types, rows of values,
    /// and optionally a face list with its count/index types.
    struct Fixture<'a> {
        vertex_props: &'a [(&'a str, &'a str)],
        vertices: Vec<Vec<f64>>,
        /// (count type, index type, property name)
        face_list: Option<(&'a str, &'a str, &'a str)>,
        faces: Vec<Vec<i64>>,
    }

    fn put(out: &mut Vec<u8>, ty: &str, v: f64, format: Format) {
        macro_rules! bytes {
            ($t:ty) => {{
                let x = v as $t;
                match format {
                    Format::Le => out.extend_from_slice(&x.to_le_bytes()),
                    _ => out.extend_from_slice(&x.to_be_bytes()),
                }
            }};
        }
        match ty {
            "char" => bytes!(i8),
            "uchar" => bytes!(u8),
            "short" => bytes!(i16),
            "ushort" => bytes!(u16),
            "int" => bytes!(i32),
            "uint" => bytes!(u32),
            "float" => bytes!(f32),
            "double" => bytes!(f64),
            other => panic!("unknown type {other}"),
        }
    }

    fn ascii_value(ty: &str, v: f64) -> String {
        match ty {
            "float" | "double" => format!("{v}"),
            _ => format!("{}", v as i64),
        }
    }

    impl Fixture<'_> {
        fn header(&self, format: Format, vertex_count: usize) -> String {
            let name = match format {
                Format::Ascii => "ascii",
                Format::Le => "binary_little_endian",
                Format::Be => "binary_big_endian",
            };
            let mut h = format!("ply\nformat {name} 1.0\ncomment test fixture\n");
            h += &format!("element vertex {vertex_count}\n");
            for (n, t) in self.vertex_props {
                h += &format!("property {t} {n}\n");
            }
            if let Some((count_ty, index_ty, name)) = self.face_list {
                h += &format!("element face {}\n", self.faces.len());
                h += &format!("property list {count_ty} {index_ty} {name}\n");
                h += "property uchar flags\n";
            }
            h + "end_header\n"
        }

        fn bytes(&self, format: Format) -> Vec<u8> {
            self.bytes_with_vertex_count(format, self.vertices.len())
        }

        fn bytes_with_vertex_count(&self, format: Format, declared: usize) -> Vec<u8> {
            let mut out = self.header(format, declared).into_bytes();
            for row in &self.vertices {
                assert_eq!(row.len(), self.vertex_props.len());
                match format {
                    Format::Ascii => {
                        let tokens: Vec<String> = row
                            .iter()
                            .zip(self.vertex_props)
                            .map(|(v, (_, t))| ascii_value(t, *v))
                            .collect();
                        out.extend_from_slice((tokens.join(" ") + "\n").as_bytes());
                    }
                    _ => {
                        for (v, (_, t)) in row.iter().zip(self.vertex_props) {
                            put(&mut out, t, *v, format);
                        }
                    }
                }
            }
            if let Some((count_ty, index_ty, _)) = self.face_list {
                for face in &self.faces {
                    match format {
                        Format::Ascii => {
                            let mut tokens = vec![face.len().to_string()];
                            tokens.extend(face.iter().map(|i| i.to_string()));
                            tokens.push("7".into());
                            out.extend_from_slice((tokens.join(" ") + "\n").as_bytes());
                        }
                        _ => {
                            put(&mut out, count_ty, face.len() as f64, format);
                            for &i in face {
                                put(&mut out, index_ty, i as f64, format);
                            }
                            put(&mut out, "uchar", 7.0, format);
                        }
                    }
                }
            }
            out
        }
    }

    const XYZ: &[(&str, &str)] = &[("x", "float"), ("y", "float"), ("z", "float")];
    const XYZ_RGB: &[(&str, &str)] = &[
        ("x", "float"),
        ("y", "float"),
        ("z", "float"),
        ("red", "uchar"),
        ("green", "uchar"),
        ("blue", "uchar"),
        ("s", "float"),
    ];
    const XYZ_N: &[(&str, &str)] = &[
        ("x", "float"),
        ("y", "float"),
        ("z", "float"),
        ("nx", "float"),
        ("ny", "float"),
        ("nz", "float"),
    ];

    fn cube_corners() -> Vec<[f64; 3]> {
        (0..8)
            .map(|i| {
                let s = |bit: i32| if i & bit != 0 { 10.0 } else { -10.0 };
                [s(1), s(2), s(4)]
            })
            .collect()
    }

    /// The cube's six sides as quads, counter-clockwise seen from outside.
    fn cube_quads() -> Vec<Vec<i64>> {
        crate::geometry::mesh::CUBE_QUADS
            .iter()
            .map(|q| q.iter().map(|&v| v as i64).collect())
            .collect()
    }

    fn cube_fixture() -> Fixture<'static> {
        let vertices = cube_corners()
            .iter()
            .enumerate()
            .map(|(i, c)| vec![c[0], c[1], c[2], 200.0, i as f64, 3.0, 0.25])
            .collect();
        Fixture {
            vertex_props: XYZ_RGB,
            vertices,
            face_list: Some(("uchar", "int", "vertex_indices")),
            faces: cube_quads(),
        }
    }

    fn read(bytes: &[u8]) -> Result<Mesh> {
        Mesh::from_ply_reader(bytes, "fixture.ply")
    }

    /// Asserts a PLY error whose message holds every one of `needles`.
    fn expect_ply_error(result: Result<Mesh>, needles: &[&str]) -> String {
        match result {
            Err(Error::Ply { path, reason }) => {
                assert_eq!(path, PathBuf::from("fixture.ply"));
                for needle in needles {
                    assert!(
                        reason.contains(needle),
                        "message {reason:?} lacks {needle:?}"
                    );
                }
                reason
            }
            Err(other) => panic!("expected a PLY error, got {other}"),
            Ok(mesh) => panic!(
                "expected a PLY error, got a mesh of {} vertices",
                mesh.positions.len()
            ),
        }
    }

    #[test]
    fn ascii_and_both_binary_encodings_agree() {
        let fixture = cube_fixture();
        let ascii = read(&fixture.bytes(Format::Ascii)).unwrap();
        let le = read(&fixture.bytes(Format::Le)).unwrap();
        let be = read(&fixture.bytes(Format::Be)).unwrap();
        // Without normals in the file, each corner becomes three vertices, one per face, with
        // that face's normal (the faces meet at right angles: creases).
        assert_eq!(ascii.positions.len(), 24);
        assert!(ascii.normals.iter().all(|n| n.amax() == 1.0));
        assert_eq!(ascii.faces.len(), 12, "six quads fan into twelve triangles");
        for other in [&le, &be] {
            assert_eq!(ascii.positions, other.positions);
            assert_eq!(ascii.normals, other.normals);
            assert_eq!(ascii.faces, other.faces);
        }
        assert!((ascii.surface_area() - 2400.0).abs() < 1e-3);
    }

    #[test]
    fn normals_from_faces_point_outward_and_are_unit() {
        let mesh = read(&cube_fixture().bytes(Format::Le)).unwrap();
        mesh.validate().unwrap();
        for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
            assert!((n.norm() - 1.0).abs() < 1e-6, "normal {n:?} is not unit");
            assert!(
                n.dot(&p.coords.normalize()) > 0.5,
                "normal {n:?} at {p:?} points inward"
            );
        }
    }

    #[test]
    fn double_coordinates_and_normals() {
        let props: &[(&str, &str)] = &[
            ("x", "double"),
            ("y", "double"),
            ("z", "double"),
            ("nx", "double"),
            ("ny", "double"),
            ("nz", "double"),
        ];
        let fixture = Fixture {
            vertex_props: props,
            vertices: vec![
                vec![0.1, -2.5e3, 1e-7, 0.0, 0.0, 2.0],
                vec![3.0, 4.0, 5.0, 3.0, 4.0, 0.0],
            ],
            face_list: None,
            faces: vec![],
        };
        for format in [Format::Ascii, Format::Le, Format::Be] {
            let mesh = read(&fixture.bytes(format)).unwrap();
            assert_eq!(
                mesh.positions[0],
                Point3::new(0.1f64 as f32, -2500.0, 1e-7f64 as f32)
            );
            assert_eq!(mesh.normals[0], Vector3::z(), "{format:?}");
            assert!(
                (mesh.normals[1] - Vector3::new(0.6, 0.8, 0.0)).norm() < 1e-6,
                "{format:?}"
            );
            assert!(mesh.faces.is_empty());
        }
    }

    #[test]
    fn non_unit_normals_are_normalised() {
        let fixture = Fixture {
            vertex_props: XYZ_N,
            vertices: vec![
                vec![0.0, 0.0, 0.0, 0.0, 0.0, 4.0],
                vec![1.0, 0.0, 0.0, 0.01, 0.0, 0.0],
                vec![0.0, 1.0, 0.0, -1.0, -1.0, -1.0],
            ],
            face_list: None,
            faces: vec![],
        };
        let mesh = read(&fixture.bytes(Format::Ascii)).unwrap();
        mesh.validate().unwrap();
        assert_eq!(mesh.normals[0], Vector3::z());
        assert_eq!(mesh.normals[1], Vector3::x());
        let s = -1.0 / 3f32.sqrt();
        assert!((mesh.normals[2] - Vector3::new(s, s, s)).norm() < 1e-6);
    }

    #[test]
    fn zero_normal_is_recomputed_from_faces() {
        let fixture = Fixture {
            vertex_props: XYZ_N,
            vertices: vec![
                vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                vec![1.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                vec![0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            ],
            face_list: Some(("uchar", "uint", "vertex_indices")),
            faces: vec![vec![0, 1, 2]],
        };
        let mesh = read(&fixture.bytes(Format::Be)).unwrap();
        assert_eq!(mesh.normals[0], Vector3::z());
    }

    #[test]
    fn zero_normal_without_faces_names_the_vertex() {
        let fixture = Fixture {
            vertex_props: XYZ_N,
            vertices: vec![
                vec![0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
                vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            ],
            face_list: None,
            faces: vec![],
        };
        expect_ply_error(
            read(&fixture.bytes(Format::Ascii)),
            &["vertex 1", "zero length"],
        );
    }

    #[test]
    fn no_normals_and_no_faces_is_refused() {
        let fixture = Fixture {
            vertex_props: XYZ,
            vertices: vec![vec![0.0, 0.0, 0.0], vec![1.0, 0.0, 0.0]],
            face_list: None,
            faces: vec![],
        };
        expect_ply_error(
            read(&fixture.bytes(Format::Le)),
            &["no normals and no faces"],
        );
    }

    #[test]
    fn any_integer_index_type_and_either_list_name() {
        let reference = read(&cube_fixture().bytes(Format::Le)).unwrap();
        for (count_ty, index_ty, name) in [
            ("uchar", "uchar", "vertex_index"),
            ("ushort", "ushort", "vertex_indices"),
            ("int", "short", "vertex_index"),
            ("uint", "uint", "vertex_indices"),
            ("char", "char", "vertex_indices"),
        ] {
            let mut fixture = cube_fixture();
            fixture.face_list = Some((count_ty, index_ty, name));
            for format in [Format::Ascii, Format::Le, Format::Be] {
                let mesh = read(&fixture.bytes(format)).unwrap();
                assert_eq!(
                    mesh.faces, reference.faces,
                    "{count_ty} {index_ty} {name} {format:?}"
                );
            }
        }
    }

    #[test]
    fn degenerate_faces_are_skipped() {
        let mut fixture = cube_fixture();
        fixture
            .vertices
            .push(vec![-10.0, -10.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        // A repeated index, a collinear triangle (vertex 8 lies on the edge 0-4), a two-index face.
        fixture
            .faces
            .extend([vec![0, 0, 1], vec![0, 8, 4], vec![1, 2]]);
        fixture.faces.push(vec![0, 4, 6, 2]);
        // Vertex 8 is on no face of non-zero area: it is dropped, with the bad faces, whether
        // the file has normals or not.
        let mesh = read(&fixture.bytes(Format::Le)).unwrap();
        assert!(
            mesh.positions
                .iter()
                .all(|p| p != &Point3::new(-10.0, -10.0, 0.0)),
            "vertex 8 dropped"
        );
        let with_normals = Fixture {
            vertex_props: XYZ_N,
            vertices: fixture
                .vertices
                .iter()
                .map(|v| vec![v[0], v[1], v[2], 0.0, 0.0, 1.0])
                .collect(),
            face_list: fixture.face_list,
            faces: fixture.faces.clone(),
        };
        let mesh = read(&with_normals.bytes(Format::Ascii)).unwrap();
        assert_eq!(mesh.positions.len(), 8);
        assert_eq!(
            mesh.faces.len(),
            14,
            "12 cube triangles and the repeated quad's two"
        );
        // Faces that are all degenerate (every vertex at one place) are named as such.
        let collapsed = Fixture {
            vertices: with_normals
                .vertices
                .iter()
                .map(|v| vec![1.0, 2.0, 3.0, v[3], v[4], v[5]])
                .collect(),
            ..with_normals
        };
        expect_ply_error(
            read(&collapsed.bytes(Format::Ascii)),
            &["all 17 triangles of its faces are degenerate"],
        );
    }

    #[test]
    fn truncated_payload_is_reported() {
        let bytes = cube_fixture().bytes(Format::Le);
        let cut = &bytes[..bytes.len() - 20];
        expect_ply_error(read(cut), &["truncated", "faces", "of the 6"]);
        // Cut inside the vertices too.
        let header_len = cube_fixture().header(Format::Le, 8).len();
        let cut = &bytes[..header_len + 3 * 19 + 5];
        expect_ply_error(read(cut), &["truncated", "after 3 of the 8 vertices"]);
    }

    /// More data than the header declares is as wrong as less: a file holding more faces, or
    /// bytes after the binary data, is refused rather than read in part. Whitespace after the
    /// last element is no data.
    #[test]
    fn data_after_the_declared_elements_is_refused() {
        let fixture = cube_fixture();
        let mut ascii = fixture.bytes(Format::Ascii);
        let intact = read(&ascii).unwrap();
        ascii.extend_from_slice(b"\n  \r\n");
        assert_eq!(read(&ascii).unwrap().faces, intact.faces);
        // Header lines, then 8 vertex lines, 6 face lines and two blank ones: the stray face is
        // line 17 after the header.
        let header_lines = fixture.header(Format::Ascii, 8).lines().count();
        ascii.extend_from_slice(b"3 0 1 2\n");
        let reason = expect_ply_error(
            read(&ascii),
            &["data after the last element", "declares 6 faces"],
        );
        assert!(
            reason.contains(&format!("line {}", header_lines + 8 + 6 + 3)),
            "{reason}"
        );
        for format in [Format::Le, Format::Be] {
            let mut binary = fixture.bytes(format);
            binary.extend_from_slice(&[b' ', b'\n', b'\t', 0, 7]);
            expect_ply_error(
                read(&binary),
                &[
                    "data after the last element",
                    "at byte 3 after the declared data",
                ],
            );
        }
    }

    #[test]
    fn fewer_vertices_than_the_header_declares() {
        let fixture = cube_fixture();
        // Header says 11, the file holds 8 vertex lines followed by the faces.
        let ascii = fixture.bytes_with_vertex_count(Format::Ascii, 11);
        let reason = expect_ply_error(read(&ascii), &["vertex 8", "11 vertices"]);
        assert!(reason.contains("line"), "{reason}");
        // Without faces the data simply ends early.
        let no_faces = Fixture {
            face_list: None,
            faces: vec![],
            ..cube_fixture()
        };
        let ascii = no_faces.bytes_with_vertex_count(Format::Ascii, 11);
        expect_ply_error(read(&ascii), &["after 8 of the 11 vertices"]);
        let binary = no_faces.bytes_with_vertex_count(Format::Be, 11);
        expect_ply_error(read(&binary), &["after 8 of the 11 vertices"]);
    }

    #[test]
    fn missing_coordinate_property() {
        let props: &[(&str, &str)] = &[("x", "float"), ("z", "float"), ("nx", "float")];
        let fixture = Fixture {
            vertex_props: props,
            vertices: vec![vec![1.0, 2.0, 3.0]],
            face_list: None,
            faces: vec![],
        };
        expect_ply_error(read(&fixture.bytes(Format::Ascii)), &["no 'y' property"]);
    }

    #[test]
    fn nan_coordinate_names_the_vertex() {
        let mut fixture = cube_fixture();
        fixture.vertices[3][1] = f64::NAN;
        expect_ply_error(
            read(&fixture.bytes(Format::Le)),
            &["vertex 3", "not finite"],
        );
        // In ASCII: the value is named, as the binary case's are.
        let text = String::from_utf8(cube_fixture().bytes(Format::Ascii)).unwrap();
        for word in ["nan", "inf", "-inf", "abc"] {
            let text = text.replacen("\n10 -10 -10 ", &format!("\n10 {word} -10 "), 1);
            // 15 header lines, then vertex 0 on line 16.
            expect_ply_error(
                read(text.as_bytes()),
                &[
                    "vertex 1 (line 17)",
                    &format!("value 2 is '{word}', not a finite number"),
                ],
            );
        }
    }

    #[test]
    fn infinite_coordinate_names_the_vertex() {
        let mut fixture = cube_fixture();
        fixture.vertices[6][2] = f64::INFINITY;
        expect_ply_error(
            read(&fixture.bytes(Format::Be)),
            &["vertex 6", "inf", "not finite"],
        );
        // A double beyond f32's range is infinite once stored.
        let props: &[(&str, &str)] = &[("x", "double"), ("y", "double"), ("z", "double")];
        let fixture = Fixture {
            vertex_props: props,
            vertices: vec![
                vec![0.0, 0.0, 0.0],
                vec![1e300, 0.0, 0.0],
                vec![0.0, 1.0, 0.0],
            ],
            face_list: Some(("uchar", "int", "vertex_indices")),
            faces: vec![vec![0, 1, 2]],
        };
        expect_ply_error(
            read(&fixture.bytes(Format::Le)),
            &["vertex 1", "not finite"],
        );
    }

    /// A stray vertex that no face uses (first in the file, so that every face's indices move)
    /// reads as the mesh without it, normals in the file or not: it would otherwise count in
    /// the diameter, and so in every length of the model.
    #[test]
    fn a_vertex_no_face_uses_is_dropped() {
        let shifted = |faces: &[Vec<i64>]| -> Vec<Vec<i64>> {
            faces
                .iter()
                .map(|f| f.iter().map(|i| i + 1).collect())
                .collect()
        };
        for (props, stray) in [
            (XYZ, vec![500.0, 0.0, 0.0]),
            (XYZ_N, vec![500.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
        ] {
            let corners: Vec<Vec<f64>> = cube_corners()
                .iter()
                .map(|c| {
                    let mut v = c.to_vec();
                    if props.len() == 6 {
                        v.extend(c.iter().map(|x| x / 10.0 / 3f64.sqrt()));
                    }
                    v
                })
                .collect();
            let clean = Fixture {
                vertex_props: props,
                vertices: corners.clone(),
                face_list: Some(("uchar", "int", "vertex_indices")),
                faces: cube_quads(),
            };
            let with_stray = Fixture {
                vertex_props: props,
                vertices: std::iter::once(stray).chain(corners).collect(),
                face_list: Some(("uchar", "int", "vertex_indices")),
                faces: shifted(&cube_quads()),
            };
            for format in [Format::Ascii, Format::Le] {
                let (clean, with_stray) = (
                    read(&clean.bytes(format)).unwrap(),
                    read(&with_stray.bytes(format)).unwrap(),
                );
                assert_eq!(
                    with_stray.positions, clean.positions,
                    "{props:?} {format:?}"
                );
                assert_eq!(with_stray.faces, clean.faces, "{props:?} {format:?}");
                assert_eq!(with_stray.fingerprint(), clean.fingerprint());
            }
        }
    }

    /// A header declaring more faces than a mesh may have is refused as too large (not as
    /// malformed) before any data is read, saying how to get past it.
    #[test]
    fn a_mesh_beyond_the_face_limit_is_refused_as_too_large() {
        let text = format!(
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
             property float z\nelement face {}\nproperty list uchar int vertex_indices\n\
             end_header\n0 0 0\n1 0 0\n0 1 0\n",
            MAX_MESH_FACES + 1
        );
        match read(text.as_bytes()) {
            Err(Error::File { path, reason }) => {
                assert_eq!(path, PathBuf::from("fixture.ply"));
                assert!(
                    reason.contains(&format!("{} faces, more than the", MAX_MESH_FACES + 1))
                        && reason.contains("decimate the mesh"),
                    "{reason}"
                );
            }
            other => panic!("expected a refusal as too large, got {other:?}"),
        }
    }

    #[test]
    fn face_index_out_of_range_names_face_and_index() {
        let mut fixture = cube_fixture();
        fixture.faces[4] = vec![0, 2, 9, 1];
        for format in [Format::Ascii, Format::Le] {
            expect_ply_error(
                read(&fixture.bytes(format)),
                &["face 4", "vertex index 9", "8 vertices, numbered 0 to 7"],
            );
        }
        fixture.faces[4] = vec![0, -2, 3];
        expect_ply_error(
            read(&fixture.bytes(Format::Be)),
            &["face 4", "vertex index -2"],
        );
    }

    #[test]
    fn empty_mesh_is_refused() {
        let fixture = Fixture {
            vertices: vec![],
            face_list: None,
            faces: vec![],
            ..cube_fixture()
        };
        expect_ply_error(
            read(&fixture.bytes(Format::Ascii)),
            &["empty", "0 vertices"],
        );
        let no_vertex_element = b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
        expect_ply_error(read(no_vertex_element), &["empty", "no 'vertex' element"]);
    }

    #[test]
    fn garbage_header_is_refused() {
        expect_ply_error(read(b"\x89PNG\r\n\x1a\n garbage"), &["bad header"]);
        expect_ply_error(read(b"hello world\n"), &["bad header", "magic number"]);
        expect_ply_error(read(b""), &["bad header"]);
        let bad_line =
            b"ply\nformat ascii 1.0\nelement vertex eight\nproperty float x\nend_header\n";
        expect_ply_error(read(bad_line), &["bad header", "Line 3"]);
        let no_end = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n";
        expect_ply_error(read(no_end), &["bad header", "end_header"]);
        // A header line of megabytes of terminal escape codes is quoted short, escaped.
        let mut garbage = b"ply\nformat ascii 1.0\n".to_vec();
        for _ in 0..100_000 {
            garbage.extend_from_slice(b"\x1b[31mX");
        }
        garbage.push(b'\n');
        let e = read(&garbage).unwrap_err().to_string();
        assert!(
            e.contains("bad header") && e.contains("\\u{1b}[31mX"),
            "{e}"
        );
        assert!(e.len() < 1000 && !e.contains('\x1b'), "{} bytes", e.len());
        // So is a vertex's value.
        let text = String::from_utf8(cube_fixture().bytes(Format::Ascii)).unwrap();
        let word = "\x1b[31mX".repeat(100_000);
        let text = text.replacen("\n10 -10 -10 ", &format!("\n10 {word} -10 "), 1);
        let e = read(text.as_bytes()).unwrap_err().to_string();
        assert!(
            e.contains("value 2 is '\\u{1b}[31mX") && e.contains("…'"),
            "{e}"
        );
        assert!(e.len() < 1000 && !e.contains('\x1b'), "{} bytes", e.len());
    }

    #[test]
    fn float_face_indices_are_refused() {
        let mut fixture = cube_fixture();
        fixture.face_list = Some(("uchar", "float", "vertex_indices"));
        expect_ply_error(
            read(&fixture.bytes(Format::Le)),
            &["floating-point", "vertex_indices"],
        );
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let err = Mesh::from_ply_file("/nonexistent/dir/obj_000001.ply").unwrap_err();
        assert!(matches!(err, Error::Io { .. }), "{err}");
        assert!(err.to_string().contains("obj_000001.ply"));
    }

    /// Every PLY file of the shared data set loads, with the header's vertex count and unit
    /// normals.
    #[test]
    fn every_shared_ply_file_loads() {
        let Some(root) = ppfd_bop::shared_test_data("") else {
            return;
        };
        let mut files = Vec::new();
        let mut dirs = vec![root];
        while let Some(dir) = dirs.pop() {
            for entry in std::fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    dirs.push(path);
                } else if path
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
                {
                    files.push(path);
                }
            }
        }
        assert!(
            files.len() >= 19,
            "expected the shared PLY files, found {}",
            files.len()
        );
        for path in &files {
            let mesh = Mesh::from_ply_file(path).unwrap_or_else(|e| panic!("{e}"));
            let header = Parser::<Skipped>::new()
                .read_ply_header(&mut std::fs::File::open(path).unwrap())
                .unwrap();
            // A file without normals gets a vertex per side of each crease.
            let in_file = header.elements["vertex"].count;
            let has_normals = header.elements["vertex"].properties.contains_key("nx");
            if has_normals {
                assert_eq!(mesh.positions.len(), in_file, "{}", path.display());
            } else {
                assert!(mesh.positions.len() >= in_file, "{}", path.display());
            }
            mesh.validate()
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            for (i, n) in mesh.normals.iter().enumerate() {
                assert!(
                    (n.norm() - 1.0).abs() < 1e-5,
                    "{}: normal {i} {n:?}",
                    path.display()
                );
            }
        }
    }

    /// Normals computed from the faces of BOP's evaluation meshes (which have none in the file)
    /// point away from the object's centre almost everywhere: the windings are read right.
    #[test]
    fn normals_from_faces_of_real_meshes_point_outward() {
        let Some(root) = ppfd_bop::shared_test_data("") else {
            return;
        };
        for obj in [1, 5, 9] {
            let path = root.join(format!("lmo/models_eval/obj_{obj:06}.ply"));
            let mesh = Mesh::from_ply_file(&path).unwrap();
            let centre = mesh.bounding_box().unwrap().centre();
            let outward = mesh
                .positions
                .iter()
                .zip(&mesh.normals)
                .filter(|(p, n)| n.dot(&(*p - centre)) > 0.0)
                .count();
            let fraction = outward as f32 / mesh.positions.len() as f32;
            assert!(
                fraction > 0.8,
                "{}: only {fraction} of normals point outward",
                path.display()
            );
        }
    }

    /// A fixture with irregular coordinates and normals (values exact in `f32`, so that every
    /// encoding holds the same numbers), a `-0.0` among them, and two triangles.
    fn irregular_fixture(ty: &'static str) -> Fixture<'static> {
        let props: &'static [(&'static str, &'static str)] = match ty {
            "float" => XYZ_N,
            _ => &[
                ("x", "double"),
                ("y", "double"),
                ("z", "double"),
                ("nx", "double"),
                ("ny", "double"),
                ("nz", "double"),
            ],
        };
        let f = |v: f64| v as f32 as f64;
        Fixture {
            vertex_props: props,
            vertices: vec![
                vec![f(10.1), f(-3.25e-2), f(1234.567), 0.0, 0.0, 1.0],
                vec![f(57.3), -0.0, f(1234.567), f(0.6), f(0.8), 0.0],
                vec![f(10.1), f(41.7), f(1190.02), f(-0.28), f(0.96), 0.0],
                vec![f(-7.77), f(13.3), f(1201.5), 0.0, -1.0, 0.0],
            ],
            face_list: Some(("uchar", "int", "vertex_indices")),
            faces: vec![vec![0, 1, 2], vec![0, 2, 3]],
        }
    }

    #[test]
    fn fingerprint_does_not_depend_on_the_encoding() {
        let reference = read(&irregular_fixture("float").bytes(Format::Ascii))
            .unwrap()
            .fingerprint();
        for ty in ["float", "double"] {
            for format in [Format::Ascii, Format::Le, Format::Be] {
                let mesh = read(&irregular_fixture(ty).bytes(format)).unwrap();
                assert_eq!(mesh.fingerprint(), reference, "{ty} {format:?}");
            }
        }
        // The same file with one coordinate one step of f32 away is another mesh.
        let mut moved = irregular_fixture("float");
        moved.vertices[2][1] = f64::from(f32::from_bits((41.7f32).to_bits() + 1));
        let moved = read(&moved.bytes(Format::Le)).unwrap();
        assert_ne!(moved.fingerprint(), reference);
        // And so is the same vertex list with a triangle's winding reversed.
        let mut flipped = irregular_fixture("float");
        flipped.faces[1] = vec![0, 3, 2];
        let flipped = read(&flipped.bytes(Format::Ascii)).unwrap();
        assert_ne!(flipped.fingerprint(), reference);
    }

    /// Rewrites an ASCII PLY file holding only `vertex` and `face` elements as binary little
    /// endian with the same numbers: each token is parsed as its declared type.
    fn ascii_to_binary(text: &str) -> Vec<u8> {
        let (header, body) = text.split_once("end_header\n").expect("a PLY header");
        let mut vertex_types = Vec::new();
        let mut list_types = None;
        let mut vertex_count = 0;
        let mut element = "";
        for line in header.lines() {
            let words: Vec<&str> = line.split_whitespace().collect();
            match words.as_slice() {
                ["element", name, count] => {
                    element = name;
                    if *name == "vertex" {
                        vertex_count = count.parse().unwrap();
                    } else {
                        assert_eq!(*name, "face", "only vertex and face elements");
                    }
                }
                ["property", "list", count_ty, index_ty, _] => {
                    assert_eq!(element, "face");
                    list_types = Some((count_ty.to_string(), index_ty.to_string()));
                }
                ["property", ty, _] => {
                    assert_eq!(element, "vertex", "face properties other than the list");
                    vertex_types.push(ty.to_string());
                }
                _ => {}
            }
        }
        let mut out = header
            .replace("format ascii 1.0", "format binary_little_endian 1.0")
            .into_bytes();
        out.extend_from_slice(b"end_header\n");
        let value = |ty: &str, token: &str| -> f64 {
            match ty {
                "float" => f64::from(token.parse::<f32>().unwrap()),
                _ => token.parse::<f64>().unwrap(),
            }
        };
        let (count_ty, index_ty) = list_types.expect("a face list");
        for (row, line) in body.lines().filter(|l| !l.trim().is_empty()).enumerate() {
            let tokens: Vec<&str> = line.split_whitespace().collect();
            if row < vertex_count {
                assert_eq!(tokens.len(), vertex_types.len());
                for (ty, token) in vertex_types.iter().zip(&tokens) {
                    put(&mut out, ty, value(ty, token), Format::Le);
                }
            } else {
                put(&mut out, &count_ty, value(&count_ty, tokens[0]), Format::Le);
                for token in &tokens[1..] {
                    put(&mut out, &index_ty, value(&index_ty, token), Format::Le);
                }
            }
        }
        out
    }

    /// A real object model (an ASCII file) and its binary little-endian copy give one
    /// fingerprint.
    #[test]
    fn fingerprint_of_a_real_mesh_survives_conversion_to_binary() {
        let Some(root) = ppfd_bop::shared_test_data("") else {
            return;
        };
        let path = root.join("lmo/models/obj_000001.ply");
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("format ascii 1.0"),
            "{} is ASCII",
            path.display()
        );
        let binary = ascii_to_binary(&text);
        assert!(binary.len() < text.len(), "the copy is binary");
        let from_ascii = Mesh::from_ply_file(&path).unwrap();
        let from_binary = read(&binary).unwrap();
        assert_eq!(from_ascii.positions.len(), from_binary.positions.len());
        assert_eq!(from_ascii.fingerprint(), from_binary.fingerprint());
        // Another object's mesh gives another fingerprint.
        let other = Mesh::from_ply_file(root.join("lmo/models/obj_000005.ply")).unwrap();
        assert_ne!(other.fingerprint(), from_ascii.fingerprint());
    }
}
