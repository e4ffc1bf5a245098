//! Overlay pictures (`--overlay out.png`): the frame (its colour image when there is one, else
//! the depth colour-mapped), and over it each pose's outline and axes, labelled with object
//! id, rank and score; the ground truth, when known, outlined in another colour.

use std::path::Path;

use ppfd_models::geometry::camera::{DepthFrame, Intrinsics};
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::geometry::render::{bounding_sphere, render_depth};
use ppfd_models::Pose;

/// Outline of a pose that passed every check.
pub const PASSED: [u8; 3] = [40, 230, 40];
/// Outline of a pose that failed a filter.
pub const FAILED: [u8; 3] = [255, 230, 0];
/// Outline of the ground truth.
pub const TRUTH: [u8; 3] = [230, 40, 230];
const AXES: [[u8; 3]; 3] = [[255, 40, 40], [40, 255, 40], [60, 120, 255]];

/// An RGB picture of a frame's size.
pub struct Overlay {
    width: u32,
    height: u32,
    intrinsics: Intrinsics,
    rgb: Vec<u8>,
}

impl Overlay {
    /// The depth colour-mapped, near warm and far cool (between the frame's 2nd and 98th
    /// percentile of depth, so a far wall does not wash the objects out), no depth black.
    pub fn from_depth(frame: &DepthFrame) -> Overlay {
        let mut valid: Vec<u16> = frame.depth.iter().copied().filter(|&d| d > 0).collect();
        valid.sort_unstable();
        let at = |q: f32| {
            valid
                .get(((valid.len() as f32 - 1.0) * q) as usize)
                .copied()
                .unwrap_or(0) as f32
        };
        let (near, far) = (at(0.02), at(0.98).max(at(0.02) + 1.0));
        let mut rgb = Vec::with_capacity(frame.depth.len() * 3);
        for &d in frame.depth {
            if d == 0 {
                rgb.extend([0, 0, 0]);
            } else {
                let t = ((d as f32 - near) / (far - near)).clamp(0.0, 1.0);
                rgb.extend(ramp(t));
            }
        }
        Overlay {
            width: frame.width,
            height: frame.height,
            intrinsics: frame.intrinsics,
            rgb,
        }
    }

    /// The colour image `rgb` (`width × height` RGB triples), dimmed so that the drawing
    /// stands out; `None` when its size is not the frame's.
    pub fn from_colour(
        frame: &DepthFrame,
        width: u32,
        height: u32,
        rgb: Vec<u8>,
    ) -> Option<Overlay> {
        if (width, height) != (frame.width, frame.height)
            || rgb.len() != (width * height * 3) as usize
        {
            return None;
        }
        Some(Overlay {
            width,
            height,
            intrinsics: frame.intrinsics,
            rgb: rgb.into_iter().map(|c| (c as u16 * 3 / 4) as u8).collect(),
        })
    }

    fn put(&mut self, u: i64, v: i64, colour: [u8; 3]) {
        if u >= 0 && v >= 0 && u < self.width as i64 && v < self.height as i64 {
            let i = 3 * (v as usize * self.width as usize + u as usize);
            self.rgb[i..i + 3].copy_from_slice(&colour);
        }
    }

    /// Outlines `mesh` at `pose`: the pixels of its rendered silhouette that border pixels
    /// outside it, two pixels wide inwards. Returns how many pixels the outline took.
    pub fn outline(&mut self, mesh: &Mesh, pose: &Pose, colour: [u8; 3]) -> usize {
        let Ok(image) = render_depth(mesh, pose, &self.intrinsics, self.width, self.height) else {
            return 0;
        };
        let (w, h) = (self.width as i64, self.height as i64);
        let inside = |u: i64, v: i64| {
            u >= 0 && v >= 0 && u < w && v < h && image.get(u as u32, v as u32).is_some()
        };
        let mut drawn = 0;
        for v in 0..h {
            for u in 0..w {
                let edge = inside(u, v)
                    && [
                        (-2, 0),
                        (2, 0),
                        (0, -2),
                        (0, 2),
                        (-1, 0),
                        (1, 0),
                        (0, -1),
                        (0, 1),
                    ]
                    .iter()
                    .any(|(du, dv)| !inside(u + du, v + dv));
                if edge {
                    self.put(u, v, colour);
                    drawn += 1;
                }
            }
        }
        drawn
    }

    /// The model's axes at `pose`, from its centre, half its radius long: x red, y green,
    /// z blue.
    pub fn axes(&mut self, mesh: &Mesh, pose: &Pose) {
        let (centre, radius) = bounding_sphere(mesh);
        let origin = pose * centre;
        for (axis, colour) in AXES.iter().enumerate() {
            let mut end = centre;
            end[axis] += 0.5 * radius;
            self.line(&origin, &(pose * end), *colour);
        }
    }

    fn line(&mut self, a: &nalgebra::Point3<f32>, b: &nalgebra::Point3<f32>, colour: [u8; 3]) {
        if a.z <= 0.0 || b.z <= 0.0 {
            return;
        }
        let (pa, pb) = (self.intrinsics.project(a), self.intrinsics.project(b));
        let steps = (pb - pa).abs().max().ceil().clamp(1.0, 4096.0) as usize;
        for i in 0..=steps {
            let p = pa + (pb - pa) * (i as f32 / steps as f32);
            for (du, dv) in [(0, 0), (1, 0), (0, 1)] {
                self.put(p.x.round() as i64 + du, p.y.round() as i64 + dv, colour);
            }
        }
    }

    /// Writes `text` (digits, `.`, `#` and spaces) at the pose's centre, white on black.
    pub fn label(&mut self, mesh: &Mesh, pose: &Pose, text: &str) {
        let centre = pose * bounding_sphere(mesh).0;
        if centre.z <= 0.0 {
            return;
        }
        let p = self.intrinsics.project(&centre);
        let (x0, y0) = (p.x.round() as i64 + 4, p.y.round() as i64 + 4);
        let scale = 2;
        let advance = 4 * scale;
        for dv in -1..(5 * scale + 1) {
            for du in -1..(advance * text.len() as i64) {
                self.put(x0 + du, y0 + dv, [0, 0, 0]);
            }
        }
        for (i, c) in text.chars().enumerate() {
            let rows = glyph(c);
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..3 {
                    if bits & (4 >> col) != 0 {
                        for (su, sv) in (0..scale).flat_map(|a| (0..scale).map(move |b| (a, b))) {
                            self.put(
                                x0 + i as i64 * advance + col * scale + su,
                                y0 + r as i64 * scale + sv,
                                [255, 255, 255],
                            );
                        }
                    }
                }
            }
        }
    }

    /// Writes the picture as an 8-bit RGB PNG, to a temporary file renamed into place once
    /// whole: a full disk leaves no half-written picture (and an earlier one as it was).
    pub fn write_png(&self, path: &Path) -> Result<(), String> {
        let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
        let mut bytes = Vec::new();
        let mut encoder = png::Encoder::new(&mut bytes, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(|e| fail(&e))?;
        writer.write_image_data(&self.rgb).map_err(|e| fail(&e))?;
        writer.finish().map_err(|e| fail(&e))?;
        crate::common::write_all(&[(path.to_path_buf(), bytes)])
    }
}

/// Refuses, before any detection, an overlay path the picture cannot go to: one not ending in
/// `.png` (the picture is a PNG), a folder, or one in a folder that is not there or cannot be
/// written. Nothing is made or changed.
pub fn check_path(path: &Path) -> Result<(), String> {
    let png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        return Err(format!(
            "{}: the overlay is a PNG picture; give a path ending in .png",
            path.display()
        ));
    }
    if path.is_dir() {
        return Err(format!(
            "{}: is a folder; give a file's path",
            path.display()
        ));
    }
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let probe = parent.join(format!(".ppf-overlay-check-{}", std::process::id()));
    std::fs::File::create(&probe)
        .map(|_| {
            let _ = std::fs::remove_file(&probe);
        })
        .map_err(|e| format!("{}: cannot write there: {e}", path.display()))
}

/// The colour image at `path` if it reads, else `None` with a note on stderr: the overlay
/// falls back to the depth, and the detection's work is not lost to a broken picture.
pub fn colour_or_note(path: &Path) -> Option<(u32, u32, Vec<u8>)> {
    match read_colour_png(path) {
        Ok(colour) => Some(colour),
        Err(e) => {
            eprintln!("note: {e}; the overlay is drawn on the depth instead");
            None
        }
    }
}

/// A pose to draw: outline in `colour`, axes, and a label when `label` is given.
pub struct Drawn<'a> {
    pub mesh: &'a Mesh,
    pub pose: Pose,
    pub colour: [u8; 3],
    pub label: Option<String>,
}

impl Overlay {
    /// Draws the ground truth first, then the poses over it (best last, so it stays on top).
    pub fn draw_all(&mut self, truth: &[Drawn], poses: &[Drawn]) {
        for t in truth {
            self.outline(t.mesh, &t.pose, t.colour);
        }
        for d in poses.iter().rev() {
            self.outline(d.mesh, &d.pose, d.colour);
            self.axes(d.mesh, &d.pose);
        }
        for d in poses.iter().rev() {
            if let Some(text) = &d.label {
                self.label(d.mesh, &d.pose, text);
            }
        }
    }
}

/// The outline colour of a pose with these check bits: [`PASSED`] when it passed both
/// filters, else [`FAILED`].
pub fn check_colour(checks: u32) -> [u8; 3] {
    let both = ppfd_client::checks::CONSISTENT | ppfd_client::checks::SILHOUETTE;
    if checks & both == both {
        PASSED
    } else {
        FAILED
    }
}

/// The mesh of a model file: a PLY mesh as read, a model file's own.
pub fn mesh_of_file(path: &Path) -> Result<Mesh, String> {
    let ply = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"));
    if ply {
        Mesh::from_ply_file(path).map_err(|e| e.to_string())
    } else {
        ppfd_models::model::store::load(path)
            .map(|m| m.render_mesh())
            .map_err(|e| e.to_string())
    }
}

/// The picture of a daemon's answer: over the colour image when given (else the depth),
/// each hypothesis with its object's mesh among `meshes`, and the truth.
pub fn draw_detections(
    frame: &DepthFrame,
    colour: Option<(u32, u32, Vec<u8>)>,
    meshes: &[(u32, Mesh)],
    found: &ppfd_client::Detections,
    truth: &[(u32, Pose)],
) -> Overlay {
    let mut overlay = colour
        .and_then(|(w, h, rgb)| Overlay::from_colour(frame, w, h, rgb))
        .unwrap_or_else(|| Overlay::from_depth(frame));
    let mesh = |id: u32| meshes.iter().find(|(m, _)| *m == id).map(|(_, mesh)| mesh);
    let truth: Vec<Drawn> = truth
        .iter()
        .filter_map(|(id, pose)| {
            Some(Drawn {
                mesh: mesh(*id)?,
                pose: *pose,
                colour: TRUTH,
                label: None,
            })
        })
        .collect();
    let poses: Vec<Drawn> = found
        .hypotheses
        .iter()
        .filter_map(|h| {
            Some(Drawn {
                mesh: mesh(h.object_id)?,
                pose: h.isometry(),
                colour: check_colour(h.checks),
                label: Some(label(h.object_id, h.instance_rank as usize, h.score)),
            })
        })
        .collect();
    overlay.draw_all(&truth, &poses);
    overlay
}

/// A label: object id, `#` rank from 1, score.
pub fn label(object_id: u32, rank: usize, score: f32) -> String {
    format!("{object_id} #{} {score:.2}", rank + 1)
}

/// Blue (far) through cyan, green and yellow to red (near).
fn ramp(t: f32) -> [u8; 3] {
    let near = 1.0 - t;
    // Dimmed, so that the outlines' full colours stand out.
    let c = |x: f32| (x.clamp(0.0, 1.0) * 160.0) as u8;
    [
        c(2.0 * near - 0.6),
        c(1.0 - (2.0 * near - 1.0).abs() * 0.8),
        c(1.4 - 2.0 * near),
    ]
}

/// 3 × 5 glyphs, one row per entry, the high bit the left column.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '#' => [5, 7, 5, 7, 5],
        '-' => [0, 0, 7, 0, 0],
        _ => [0; 5],
    }
}

/// Reads an 8-bit colour PNG (RGB, RGBA or grey) as RGB triples.
pub fn read_colour_png(path: &Path) -> Result<(u32, u32, Vec<u8>), String> {
    let bad = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let file = std::fs::File::open(path).map_err(|e| bad(&e))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| bad(&e))?;
    let mut buf = vec![
        0;
        reader
            .output_buffer_size()
            .ok_or_else(|| bad(&"too large"))?
    ];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(&e))?;
    let pixels = (info.width * info.height) as usize;
    let channels = info.line_size / info.width as usize;
    let rgb = match channels {
        3 => buf[..pixels * 3].to_vec(),
        4 => buf[..pixels * 4]
            .chunks(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        1 => buf[..pixels].iter().flat_map(|&g| [g, g, g]).collect(),
        2 => buf[..pixels * 2]
            .chunks(2)
            .flat_map(|p| [p[0], p[0], p[0]])
            .collect(),
        n => return Err(bad(&format!("{n} channels per pixel, expected 1 to 4"))),
    };
    Ok((info.width, info.height, rgb))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ppfd_models::synthetic::parts::Part;
    use ppfd_models::synthetic::scene::SyntheticScene;

    /// The outline lies where the model projects: every pixel of the written PNG in the
    /// outline's colour is a pixel of the model's rendered silhouette at the pose, on its
    /// border, and the silhouette's border is drawn all round.
    #[test]
    fn the_png_shows_the_outline_where_the_model_projects() {
        let part = Part::TPipe;
        let mesh = part.mesh();
        let pose = Pose::from_parts(
            nalgebra::Translation3::new(30.0, -20.0, 700.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.4, -0.3, 0.8),
        );
        let scene = SyntheticScene::single(&mesh, 4, pose, None, 1).unwrap();
        let frame = scene.frame.view();
        let mut overlay = Overlay::from_depth(&frame);
        let drawn = overlay.outline(&mesh, &pose, PASSED);
        overlay.label(&mesh, &pose, &label(4, 0, 0.5));
        let path = std::env::temp_dir().join(format!("ppf-overlay-{}.png", std::process::id()));
        overlay.write_png(&path).unwrap();
        let (w, h, rgb) = read_colour_png(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert_eq!((w, h), (640, 480));

        let silhouette = render_depth(&mesh, &pose, &frame.intrinsics, w, h).unwrap();
        let inside = |u: i64, v: i64| {
            u >= 0
                && v >= 0
                && u < w as i64
                && v < h as i64
                && silhouette.get(u as u32, v as u32).is_some()
        };
        let border = |u: i64, v: i64| {
            inside(u, v)
                && [(-1, 0), (1, 0), (0, -1), (0, 1)]
                    .iter()
                    .any(|(a, b)| !inside(u + a, v + b))
        };
        let (mut green, mut border_pixels, mut border_green) = (0, 0, 0);
        for v in 0..h as i64 {
            for u in 0..w as i64 {
                let i = 3 * (v as usize * w as usize + u as usize);
                let is_green = rgb[i..i + 3] == PASSED;
                if is_green {
                    green += 1;
                    assert!(inside(u, v), "outline pixel ({u}, {v}) off the silhouette");
                }
                if border(u, v) {
                    border_pixels += 1;
                    border_green += is_green as usize;
                }
            }
        }
        eprintln!("{green} outline pixels, {border_green} of {border_pixels} border pixels");
        assert!(green > 100 && green <= drawn);
        // The label covers a few border pixels; all the others are drawn.
        assert!(border_green as f32 > 0.9 * border_pixels as f32);
    }
}
