//! The BOP results file: one pose estimate per line, `scene_id,im_id,obj_id,score,R,t,time`.
//!
//! `R` is nine numbers (row-major rotation, model to camera) and `t` three numbers (mm), each
//! space separated; `time` is the seconds the method spent on the whole image (the same on every
//! line of an image; BOP writes −1 when unknown). A header line naming the fields is optional
//! when reading and always written.

use std::io::{BufRead, Write};
use std::path::Path;

use nalgebra::{Matrix3, Translation3};

use ppfd_models::Pose;

use crate::{Error, Result};

/// The header line of a BOP results file.
pub const RESULTS_HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time";

const FIELDS: [&str; 7] = ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"];

/// One pose estimate of a results file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimateRow {
    /// The scene (6-digit folder of the split).
    pub scene_id: u32,
    /// The image within the scene.
    pub im_id: u32,
    /// The object the pose is for.
    pub obj_id: u32,
    /// Confidence: higher is better; estimates are matched in decreasing order of score.
    pub score: f32,
    /// Model-to-camera pose, mm.
    pub pose: Pose,
    /// Seconds spent on the whole image; negative when unknown.
    pub time_s: f32,
}

/// Reads a results file; see [`parse_results`].
pub fn read_results(path: impl AsRef<Path>) -> Result<Vec<EstimateRow>> {
    let path = path.as_ref();
    let (file, len) = ppfd_models::file::open_regular(path)?;
    RESULTS_FILE.check(path, len)?;
    // Bounded also when the file grows while it is read.
    let reader = std::io::Read::take(file, RESULTS_FILE.max_bytes);
    parse_results(std::io::BufReader::new(reader), path)
}

/// The largest results file read: about 7 million estimates, far beyond any BOP dataset's.
pub const RESULTS_FILE: ppfd_models::file::Limit = ppfd_models::file::Limit {
    what: "results file",
    max_bytes: 1 << 30,
    raise: "split the file by scene, or raise ppfd_bop::eval::csv::RESULTS_FILE and rebuild",
};

/// Parses a results file from `reader`; `name_for_errors` is the path named in errors.
///
/// Blank lines are skipped, and so is a first line that starts with `scene_id`. A rotation must
/// be within 0.05 of orthonormal with a positive determinant; it is replaced by the nearest
/// rotation. Errors ([`Error::Dataset`]) name the line (from 1) and the field.
pub fn parse_results<R: BufRead>(
    reader: R,
    name_for_errors: impl AsRef<Path>,
) -> Result<Vec<EstimateRow>> {
    let path = name_for_errors.as_ref();
    let fail = |reason: String| Error::Dataset {
        path: path.to_path_buf(),
        reason,
    };
    let mut rows = Vec::new();
    let mut seen_content = false;
    for (index, line) in reader.lines().enumerate() {
        let number = index + 1;
        let line = line.map_err(|e| fail(format!("line {number}: cannot be read: {e}")))?;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let first = !seen_content;
        seen_content = true;
        if first && line.starts_with("scene_id") {
            continue;
        }
        rows.push(parse_line(line).map_err(|reason| fail(format!("line {number}{reason}")))?);
    }
    Ok(rows)
}

/// One data line; the error starts with ", field …" or ": …" to follow "line N".
fn parse_line(line: &str) -> std::result::Result<EstimateRow, String> {
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    if fields.len() != FIELDS.len() {
        return Err(format!(
            ": expected {} comma-separated fields ({RESULTS_HEADER}), found {}",
            FIELDS.len(),
            fields.len()
        ));
    }
    let id = |i: usize| -> std::result::Result<u32, String> {
        fields[i].parse::<u32>().map_err(|_| {
            format!(
                ", field '{}': \"{}\" is not a non-negative integer",
                FIELDS[i], fields[i]
            )
        })
    };
    let numbers = |i: usize, expected: usize| -> std::result::Result<Vec<f64>, String> {
        let values: Vec<&str> = fields[i].split_whitespace().collect();
        if values.len() != expected {
            return Err(format!(
                ", field '{}': expected {expected} space-separated numbers, found {}",
                FIELDS[i],
                values.len()
            ));
        }
        values
            .iter()
            .enumerate()
            .map(|(k, v)| {
                v.parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        let which = if expected > 1 {
                            format!(" number {}", k + 1)
                        } else {
                            String::new()
                        };
                        format!(
                            ", field '{}'{which}: \"{v}\" is not a finite number",
                            FIELDS[i]
                        )
                    })
            })
            .collect()
    };
    let scene_id = id(0)?;
    let im_id = id(1)?;
    let obj_id = id(2)?;
    let score = numbers(3, 1)?[0] as f32;
    let r = Matrix3::from_row_slice(&numbers(4, 9)?);
    let rotation = crate::dataset::rotation(r, "the matrix", ", field 'R': ")?;
    let t = numbers(5, 3)?;
    let time_s = numbers(6, 1)?[0] as f32;
    Ok(EstimateRow {
        scene_id,
        im_id,
        obj_id,
        score,
        pose: Pose::from_parts(
            Translation3::new(t[0] as f32, t[1] as f32, t[2] as f32),
            rotation,
        ),
        time_s,
    })
}

/// Writes `rows` with a header line, numbers in the shortest form that reads back exactly.
pub fn write_results<W: Write>(mut writer: W, rows: &[EstimateRow]) -> std::io::Result<()> {
    writeln!(writer, "{RESULTS_HEADER}")?;
    for row in rows {
        let r = row.pose.rotation.to_rotation_matrix();
        let r = r.matrix();
        let t = &row.pose.translation.vector;
        let rotation: Vec<String> = (0..3)
            .flat_map(|i| (0..3).map(move |j| r[(i, j)].to_string()))
            .collect();
        writeln!(
            writer,
            "{},{},{},{},{},{} {} {},{}",
            row.scene_id,
            row.im_id,
            row.obj_id,
            row.score,
            rotation.join(" "),
            t.x,
            t.y,
            t.z,
            row.time_s
        )?;
    }
    writer.flush()
}

/// Writes a results file; see [`write_results`].
pub fn write_results_file(path: impl AsRef<Path>, rows: &[EstimateRow]) -> Result<()> {
    let path = path.as_ref();
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    write_results(std::io::BufWriter::new(file), rows).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn row(scene_id: u32, im_id: u32, obj_id: u32, score: f32) -> EstimateRow {
        EstimateRow {
            scene_id,
            im_id,
            obj_id,
            score,
            pose: Pose::from_parts(
                Translation3::new(-12.5, 40.25, 903.125),
                UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.7)
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -1.2),
            ),
            time_s: 0.731,
        }
    }

    fn parse(text: &str) -> Result<Vec<EstimateRow>> {
        parse_results(text.as_bytes(), "results.csv")
    }

    #[test]
    fn round_trip_keeps_every_field() {
        let rows = vec![row(2, 3, 1, 0.5), row(2, 3, 5, 12.0), row(7, 100, 12, -1.0)];
        let mut bytes = Vec::new();
        write_results(&mut bytes, &rows).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        assert!(text.starts_with("scene_id,im_id,obj_id,score,R,t,time\n"));
        let back = parse(&text).unwrap();
        assert_eq!(back.len(), rows.len());
        for (a, b) in rows.iter().zip(&back) {
            assert_eq!(
                (a.scene_id, a.im_id, a.obj_id),
                (b.scene_id, b.im_id, b.obj_id)
            );
            assert_eq!(a.score, b.score);
            assert_eq!(a.time_s, b.time_s);
            assert_eq!(a.pose.translation, b.pose.translation);
            assert!(a.pose.rotation.angle_to(&b.pose.rotation) < 1e-6);
        }
    }

    #[test]
    fn reads_without_header_and_skips_blank_lines() {
        let text = "\n2,3,1,0.9,1 0 0 0 1 0 0 0 1,10 20 800,1.5\n\n2,3,5,0.4,0 -1 0 1 0 0 0 0 1,0 0 900,1.5\n";
        let rows = parse(text).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            rows[0].pose.translation.vector,
            Vector3::new(10.0, 20.0, 800.0)
        );
        let r = rows[1].pose.rotation.to_rotation_matrix();
        assert!(
            (r.matrix()[(0, 1)] + 1.0).abs() < 1e-6,
            "R is read row-major"
        );
        assert_eq!(rows[1].time_s, 1.5);
    }

    fn error_of(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    #[test]
    fn malformed_lines_name_line_and_field() {
        let header = "scene_id,im_id,obj_id,score,R,t,time\n";
        let good = "2,3,1,0.9,1 0 0 0 1 0 0 0 1,10 20 800,1.5\n";
        let e = error_of(&format!(
            "{header}{good}2,3,1,0.9,1 0 0 0 1 0 0 0 1,10 20 800\n"
        ));
        assert!(
            e.contains("results.csv") && e.contains("line 3") && e.contains("found 6"),
            "{e}"
        );
        let e = error_of(&format!(
            "{header}2,x,1,0.9,1 0 0 0 1 0 0 0 1,10 20 800,1\n"
        ));
        assert!(
            e.contains("line 2, field 'im_id'") && e.contains("\"x\""),
            "{e}"
        );
        let e = error_of(&format!("{good}2,3,-1,0.9,1 0 0 0 1 0 0 0 1,10 20 800,1\n"));
        assert!(e.contains("line 2, field 'obj_id'"), "{e}");
        let e = error_of("2,3,1,0.9,1 0 0 0 1 0 0 0,10 20 800,1\n");
        assert!(
            e.contains("line 1, field 'R'") && e.contains("expected 9"),
            "{e}"
        );
        let e = error_of("2,3,1,0.9,1 0 0 0 1 0 0 0 1,10 2o 800,1\n");
        assert!(e.contains("field 't' number 2") && e.contains("2o"), "{e}");
        let e = error_of("2,3,1,nan,1 0 0 0 1 0 0 0 1,10 20 800,1\n");
        assert!(e.contains("field 'score'"), "{e}");
        let e = error_of("2,3,1,1,2 0 0 0 1 0 0 0 1,10 20 800,1\n");
        assert!(
            e.contains("field 'R'") && e.contains("not a rotation"),
            "{e}"
        );
        let e = error_of("2,3,1,1,-1 0 0 0 1 0 0 0 1,10 20 800,1\n");
        assert!(e.contains("not a rotation"), "a reflection is refused: {e}");
        let e = error_of("2,3,1,1,1 0 0 0 1 0 0 0 1,10 20 800,soon\n");
        assert!(e.contains("field 'time'"), "{e}");
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let e = read_results("/nonexistent/results.csv").unwrap_err();
        assert!(
            matches!(e, Error::Io { .. }) && e.to_string().contains("/nonexistent/results.csv")
        );
    }
}
