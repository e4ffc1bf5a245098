//! Generated test objects: closed triangle meshes of industrial-looking parts, sized like the
//! LM-O objects (diameters 80–250 mm), so that the core can be tested without any data files.
//!
//! Each [`Part`] is a watertight solid whose faces are counter-clockwise seen from outside and
//! whose vertex normals are outward and unit. Normals are smoothed only across edges flatter than
//! [`CREASE_ANGLE_DEG`]: sharp edges have one vertex per side, each with its own face's normal,
//! so sampling the surface near an edge gives the right orientation. Every part carries an
//! off-axis feature (hole, boss, keyway, unequal arms) so that its pose is well defined.
//!
//! Besides the parts, [`box_mesh`] and [`cylinder_mesh`] make the primitive solids used as tables
//! and clutter in synthetic scenes.
//!
//! ```
//! use ppfd_models::synthetic::parts::Part;
//! let mesh = Part::ToothedDisc.mesh();
//! assert_eq!(mesh.positions.len(), mesh.normals.len());
//! assert_eq!(Part::ToothedDisc.object_id(), 3);
//! ```

use std::collections::HashMap;
use std::f64::consts::{PI, TAU};

use nalgebra::{Point3, Vector2, Vector3};

use crate::geometry::mesh::{split_creases, Mesh};
use crate::model::symmetry::{Symmetry, SymmetryElement};
use crate::model::{ModelParams, ObjectModel};

/// Edges whose faces meet at a larger angle than this keep one normal per side.
pub const CREASE_ANGLE_DEG: f64 = 35.0;

/// A generated test object. Coordinates are millimetres, centred on the bounding box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Part {
    /// An angle bracket (120 × 60 × 85 mm, 8 mm plate) with two round holes in its base and one
    /// in its upright.
    LBracket,
    /// A pipe socket: a 120 mm flange cut flat on one side, with three unevenly spaced bolt holes
    /// and one locating boss, a 70 mm body with a spanner flat, and a 44 mm bore.
    FlangedCylinder,
    /// A spur gear (24 teeth, 140 mm tip diameter, eight of them cut away to two unequal flats)
    /// with a hub on one side, a keyed bore and two unequal lightening holes.
    ToothedDisc,
    /// A tee fitting: a hub taller than wide with three round pipe stubs of unequal length (the
    /// branch narrower), bored through into a common cavity, and an off-centre foot under it.
    TPipe,
}

impl Part {
    /// Every part, in object-id order.
    pub const ALL: [Part; 4] = [
        Part::LBracket,
        Part::FlangedCylinder,
        Part::ToothedDisc,
        Part::TPipe,
    ];

    /// A short snake-case name, usable in file names.
    pub fn name(&self) -> &'static str {
        match self {
            Part::LBracket => "l_bracket",
            Part::FlangedCylinder => "flanged_cylinder",
            Part::ToothedDisc => "toothed_disc",
            Part::TPipe => "t_pipe",
        }
    }

    /// The object id this part carries in generated scenes, 1..=4.
    pub fn object_id(&self) -> u32 {
        match self {
            Part::LBracket => 1,
            Part::FlangedCylinder => 2,
            Part::ToothedDisc => 3,
            Part::TPipe => 4,
        }
    }

    /// The part with this object id, if any.
    pub fn from_object_id(object_id: u32) -> Option<Part> {
        Part::ALL.into_iter().find(|p| p.object_id() == object_id)
    }

    /// The part's model under its own id and name, built with the default parameters.
    pub fn model(&self) -> crate::Result<ObjectModel> {
        ObjectModel::build(
            &self.mesh(),
            self.object_id(),
            self.name(),
            &ModelParams::default(),
        )
    }

    /// Builds the part's mesh (a few thousand triangles; takes well under a millisecond).
    pub fn mesh(&self) -> Mesh {
        match self {
            Part::LBracket => l_bracket(),
            Part::FlangedCylinder => flanged_cylinder(),
            Part::ToothedDisc => toothed_disc(),
            Part::TPipe => t_pipe(),
        }
    }
}

/// A generated test object with a symmetry (METHOD.md §1.8), for the tests of symmetric objects:
/// unlike the [`Part`]s, these have poses that cannot be told apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SymmetricPart {
    /// A U-channel (90 × 110 × 50 mm, 8 mm walls) with two holes through its floor, diagonally
    /// opposite: a half turn about z is its only symmetry.
    UChannel,
    /// A stepped shaft: a 80 mm collar, 30 mm long, under a 44 mm shaft, 80 mm long; any turn
    /// about z maps it onto itself, and nothing else does.
    SteppedShaft,
}

impl SymmetricPart {
    /// Every symmetric part, in object-id order.
    pub const ALL: [SymmetricPart; 2] = [SymmetricPart::UChannel, SymmetricPart::SteppedShaft];

    /// A short snake-case name, usable in file names.
    pub fn name(&self) -> &'static str {
        match self {
            SymmetricPart::UChannel => "u_channel",
            SymmetricPart::SteppedShaft => "stepped_shaft",
        }
    }

    /// The object id in generated scenes: after the [`Part`]s'.
    pub fn object_id(&self) -> u32 {
        match self {
            SymmetricPart::UChannel => 5,
            SymmetricPart::SteppedShaft => 6,
        }
    }

    /// Builds the part's mesh.
    pub fn mesh(&self) -> Mesh {
        match self {
            SymmetricPart::UChannel => u_channel(),
            SymmetricPart::SteppedShaft => stepped_shaft(),
        }
    }

    /// The part's symmetry, as `ppf model build --symmetry` would give it.
    pub fn symmetry(&self) -> Symmetry {
        let spec = match self {
            SymmetricPart::UChannel => "z:2",
            SymmetricPart::SteppedShaft => "z:inf",
        };
        let element: SymmetryElement = spec.parse().expect("a valid element");
        Symmetry::generated(&[element]).expect("one generator")
    }
}

fn u_channel() -> Mesh {
    const WIDTH: f64 = 90.0; // along x
    const LENGTH: f64 = 110.0; // along y, the extrusion
    const HEIGHT: f64 = 50.0; // along z
    const WALL: f64 = 8.0;
    let mut b = SolidBuilder::default();
    let profile = [
        (0.0, 0.0),
        (WIDTH, 0.0),
        (WIDTH, HEIGHT),
        (WIDTH - WALL, HEIGHT),
        (WIDTH - WALL, WALL),
        (WALL, WALL),
        (WALL, HEIGHT),
        (0.0, HEIGHT),
    ];
    let (front, back) = b.prism_ends(&profile, LENGTH);
    // Diagonally opposite about the centre of the floor: the half turn maps one onto the other.
    let (cx, cy) = (WIDTH / 2.0, LENGTH / 2.0);
    let holes = [(cx - 22.0, cy - 30.0), (cx + 22.0, cy + 30.0)];
    let ring_at = |b: &mut SolidBuilder, z: f64| -> Vec<Vec<u32>> {
        holes
            .iter()
            .map(|&(x, y)| b.ring(Point3::new(x, y, z), Vector3::x(), Vector3::y(), 7.0, 24))
            .collect()
    };
    let bottom_rings = ring_at(&mut b, 0.0);
    let floor_rings = ring_at(&mut b, WALL);
    b.prism_sides(&front, &back, |side| match side {
        0 => &bottom_rings,
        4 => &floor_rings,
        _ => &[],
    });
    for (bottom, floor) in bottom_rings.iter().zip(&floor_rings) {
        b.strip(bottom, floor);
    }
    b.finish(true)
}

fn stepped_shaft() -> Mesh {
    const COLLAR_R: f64 = 40.0;
    const COLLAR_H: f64 = 30.0;
    const SHAFT_R: f64 = 22.0;
    const SHAFT_H: f64 = 80.0;
    const SEGMENTS: usize = 64;
    let mut b = SolidBuilder::default();
    let (x, y) = (Vector3::x(), Vector3::y());
    let ring =
        |b: &mut SolidBuilder, r: f64, z: f64| b.ring(Point3::new(0.0, 0.0, z), x, y, r, SEGMENTS);
    let collar_bottom = ring(&mut b, COLLAR_R, 0.0);
    let collar_top = ring(&mut b, COLLAR_R, COLLAR_H);
    let shaft_bottom = ring(&mut b, SHAFT_R, COLLAR_H);
    let shaft_top = ring(&mut b, SHAFT_R, COLLAR_H + SHAFT_H);
    b.planar(&collar_bottom, &[]);
    b.strip(&collar_bottom, &collar_top);
    b.planar(&collar_top, std::slice::from_ref(&shaft_bottom));
    b.strip(&shaft_bottom, &shaft_top);
    b.planar(&shaft_top, &[]);
    b.finish(true)
}

/// A closed box of the given edge lengths (mm), centred on the origin, axis-aligned; 24 vertices
/// (split at every edge) and 12 triangles.
pub fn box_mesh(size_mm: Vector3<f32>) -> Mesh {
    let h = size_mm.cast::<f64>() / 2.0;
    let mut b = SolidBuilder::default();
    let c: Vec<u32> = (0..8)
        .map(|i| {
            let sx = if i & 1 == 0 { -h.x } else { h.x };
            let sy = if i & 2 == 0 { -h.y } else { h.y };
            let sz = if i & 4 == 0 { -h.z } else { h.z };
            b.vertex(Point3::new(sx, sy, sz))
        })
        .collect();
    for quad in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        b.planar(&quad.map(|i| c[i]), &[]);
    }
    b.finish(false)
}

/// A closed cylinder of the given radius and height (mm) with its axis along z, centred on the
/// origin, its side approximated by `segments` (at least 3) flat facets with smooth normals.
pub fn cylinder_mesh(radius_mm: f32, height_mm: f32, segments: usize) -> Mesh {
    let (r, h) = (radius_mm as f64, height_mm as f64 / 2.0);
    let segments = segments.max(3);
    let mut b = SolidBuilder::default();
    let bottom = b.ring(
        Point3::new(0.0, 0.0, -h),
        Vector3::x(),
        Vector3::y(),
        r,
        segments,
    );
    let top = b.ring(
        Point3::new(0.0, 0.0, h),
        Vector3::x(),
        Vector3::y(),
        r,
        segments,
    );
    b.planar(&bottom, &[]);
    b.planar(&top, &[]);
    b.strip(&bottom, &top);
    b.finish(false)
}

fn l_bracket() -> Mesh {
    const WIDTH: f64 = 120.0; // along x, the base
    const DEPTH: f64 = 60.0; // along y, the extrusion
    const HEIGHT: f64 = 85.0; // along z, the upright
    const PLATE: f64 = 8.0;
    let mut b = SolidBuilder::default();
    let profile = [
        (0.0, 0.0),
        (WIDTH, 0.0),
        (WIDTH, PLATE),
        (PLATE, PLATE),
        (PLATE, HEIGHT),
        (0.0, HEIGHT),
    ];
    let (front, back) = b.prism_ends(&profile, DEPTH);

    // Holes through the base (axis z) and through the upright (axis x), placed off-centre.
    let base_holes = [(48.0, 18.0, 6.0), (96.0, 42.0, 6.0)];
    let bottom_rings: Vec<Vec<u32>> = base_holes
        .iter()
        .map(|&(x, y, r)| b.ring(Point3::new(x, y, 0.0), Vector3::x(), Vector3::y(), r, 24))
        .collect();
    let top_rings: Vec<Vec<u32>> = base_holes
        .iter()
        .map(|&(x, y, r)| b.ring(Point3::new(x, y, PLATE), Vector3::x(), Vector3::y(), r, 24))
        .collect();
    let (hy, hz, hr) = (22.0, 55.0, 9.0);
    let outer_ring = b.ring(Point3::new(0.0, hy, hz), Vector3::y(), Vector3::z(), hr, 28);
    let inner_ring = b.ring(
        Point3::new(PLATE, hy, hz),
        Vector3::y(),
        Vector3::z(),
        hr,
        28,
    );

    b.prism_sides(&front, &back, |side| match side {
        0 => &bottom_rings,
        2 => &top_rings,
        3 => std::slice::from_ref(&inner_ring),
        5 => std::slice::from_ref(&outer_ring),
        _ => &[],
    });
    for (bottom, top) in bottom_rings.iter().zip(&top_rings) {
        b.strip(bottom, top);
    }
    b.strip(&outer_ring, &inner_ring);
    b.finish(true)
}

fn flanged_cylinder() -> Mesh {
    const FLANGE_R: f64 = 60.0;
    const FLANGE_FLAT_X: f64 = -42.0; // the flange is cut flat on its -x side
    const FLANGE_T: f64 = 12.0;
    const BODY_R: f64 = 35.0;
    const BODY_FLAT_X: f64 = 27.0;
    const BORE_R: f64 = 22.0;
    const HEIGHT: f64 = 90.0;
    const BOLT_CIRCLE_R: f64 = 48.0;
    const BOLT_R: f64 = 5.0;
    const BOSS_R: f64 = 10.0;
    const BOSS_H: f64 = 28.0;
    let mut b = SolidBuilder::default();
    let (x, y) = (Vector3::x(), Vector3::y());
    let at = |r: f64, angle: f64, z: f64| Point3::new(r * angle.cos(), r * angle.sin(), z);

    // The flange outline: an arc from one end of the flat round to the other; the loop closes
    // along the flat.
    let flat_half_angle = PI - (-FLANGE_FLAT_X / FLANGE_R).acos();
    let arc_steps = 60;
    let outline: Vec<Vector2<f64>> = (0..=arc_steps)
        .map(|i| {
            let a = -flat_half_angle + 2.0 * flat_half_angle * i as f64 / arc_steps as f64;
            Vector2::new(FLANGE_R * a.cos(), FLANGE_R * a.sin())
        })
        .collect();
    let flange_bottom = b.loop_xy(&outline, 0.0);
    let flange_top = b.loop_xy(&outline, FLANGE_T);
    // The body is cut flat on its +x side (a spanner flat): seen from the side, where the
    // flange is hidden, the body alone still fixes the rotation about the axis.
    let body_flat_half_angle = (BODY_FLAT_X / BODY_R).acos();
    let body_outline: Vec<Vector2<f64>> = (0..=40)
        .map(|i| {
            let a = body_flat_half_angle + (TAU - 2.0 * body_flat_half_angle) * i as f64 / 40.0;
            Vector2::new(BODY_R * a.cos(), BODY_R * a.sin())
        })
        .collect();
    let body_bottom = b.loop_xy(&body_outline, FLANGE_T);
    let body_top = b.loop_xy(&body_outline, HEIGHT);
    let bore_bottom = b.ring(at(0.0, 0.0, 0.0), x, y, BORE_R, 40);
    let bore_top = b.ring(at(0.0, 0.0, HEIGHT), x, y, BORE_R, 40);
    // Three bolt holes at uneven angles, a locating boss on the +x axis and the flat on -x: no
    // rotation maps the part onto itself, and the flat and the boss show from most views.
    let bolt_angles = [0.25 * PI, 0.75 * PI, 1.5 * PI];
    let bolts_bottom: Vec<Vec<u32>> = bolt_angles
        .iter()
        .map(|&a| b.ring(at(BOLT_CIRCLE_R, a, 0.0), x, y, BOLT_R, 16))
        .collect();
    let bolts_top: Vec<Vec<u32>> = bolt_angles
        .iter()
        .map(|&a| b.ring(at(BOLT_CIRCLE_R, a, FLANGE_T), x, y, BOLT_R, 16))
        .collect();
    let boss_bottom = b.ring(at(BOLT_CIRCLE_R, 0.0, FLANGE_T), x, y, BOSS_R, 20);
    let boss_top = b.ring(at(BOLT_CIRCLE_R, 0.0, FLANGE_T + BOSS_H), x, y, BOSS_R, 20);

    let mut bottom_holes = vec![bore_bottom.clone()];
    bottom_holes.extend(bolts_bottom.iter().cloned());
    b.planar(&flange_bottom, &bottom_holes);
    b.strip(&flange_bottom, &flange_top);
    let mut top_holes = vec![body_bottom.clone(), boss_bottom.clone()];
    top_holes.extend(bolts_top.iter().cloned());
    b.planar(&flange_top, &top_holes);
    b.strip(&body_bottom, &body_top);
    b.planar(&body_top, std::slice::from_ref(&bore_top));
    b.strip(&bore_bottom, &bore_top);
    for (lo, hi) in bolts_bottom.iter().zip(&bolts_top) {
        b.strip(lo, hi);
    }
    b.strip(&boss_bottom, &boss_top);
    b.planar(&boss_top, &[]);
    b.finish(true)
}

fn toothed_disc() -> Mesh {
    const TEETH: usize = 24;
    const ROOT_R: f64 = 62.0;
    const TIP_R: f64 = 70.0;
    const WEB_T: f64 = 14.0;
    const HUB_R: f64 = 28.0;
    const HUB_H: f64 = 10.0;
    const BORE_R: f64 = 15.0;
    const KEY_HALF_WIDTH: f64 = 3.0;
    const KEY_DEPTH: f64 = 4.0;
    let mut b = SolidBuilder::default();
    let (x, y) = (Vector3::x(), Vector3::y());

    // Tooth outline in polar form: flat flanks, a slightly rounded tip and root.
    let pitch = TAU / TEETH as f64;
    let mut teeth = Vec::with_capacity(TEETH * 6);
    // Two flats where teeth are left out (22 to 2, and 8 to 10): the outline runs straight
    // across each gap. Unlike 24 equal teeth they fix the rotation about the axis, and any view
    // of the rim sees at least one of them.
    let cut = |k: usize| !(3..=7).contains(&k) && !(11..=21).contains(&k);
    for k in (0..TEETH).filter(|&k| !cut(k)) {
        let c = k as f64 * pitch;
        for (r, offset) in [
            (ROOT_R, -0.25),
            (TIP_R, -0.14),
            (TIP_R, 0.0),
            (TIP_R, 0.14),
            (ROOT_R, 0.25),
            (ROOT_R, 0.5),
        ] {
            let a = c + offset * pitch;
            teeth.push(Vector2::new(r * a.cos(), r * a.sin()));
        }
    }
    // Bore with a keyway on +x.
    let key_start = (KEY_HALF_WIDTH / BORE_R).asin();
    let arc_steps = 36;
    let mut bore: Vec<Vector2<f64>> = (0..=arc_steps)
        .map(|i| {
            let a = key_start + (TAU - 2.0 * key_start) * i as f64 / arc_steps as f64;
            Vector2::new(BORE_R * a.cos(), BORE_R * a.sin())
        })
        .collect();
    bore.push(Vector2::new(BORE_R + KEY_DEPTH, -KEY_HALF_WIDTH));
    bore.push(Vector2::new(BORE_R + KEY_DEPTH, KEY_HALF_WIDTH));

    let teeth_bottom = b.loop_xy(&teeth, 0.0);
    let teeth_top = b.loop_xy(&teeth, WEB_T);
    let bore_bottom = b.loop_xy(&bore, 0.0);
    let bore_top = b.loop_xy(&bore, WEB_T + HUB_H);
    let hub_bottom = b.ring(Point3::new(0.0, 0.0, WEB_T), x, y, HUB_R, 48);
    let hub_top = b.ring(Point3::new(0.0, 0.0, WEB_T + HUB_H), x, y, HUB_R, 48);
    // Two lightening holes of different sizes, not opposite each other.
    let holes = [(44.0, 0.35 * PI, 12.0), (45.0, 1.15 * PI, 7.0)];
    let mut hole_rings = Vec::new();
    for &(r, a, hr) in &holes {
        let centre = |z| Point3::new(r * a.cos(), r * a.sin(), z);
        let lo = b.ring(centre(0.0), x, y, hr, 20);
        let hi = b.ring(centre(WEB_T), x, y, hr, 20);
        hole_rings.push((lo, hi));
    }

    let mut bottom_holes = vec![bore_bottom.clone()];
    bottom_holes.extend(hole_rings.iter().map(|(lo, _)| lo.clone()));
    b.planar(&teeth_bottom, &bottom_holes);
    let mut top_holes = vec![hub_bottom.clone()];
    top_holes.extend(hole_rings.iter().map(|(_, hi)| hi.clone()));
    b.planar(&teeth_top, &top_holes);
    b.planar(&hub_top, std::slice::from_ref(&bore_top));
    b.strip(&teeth_bottom, &teeth_top);
    b.strip(&hub_bottom, &hub_top);
    b.strip(&bore_bottom, &bore_top);
    for (lo, hi) in &hole_rings {
        b.strip(lo, hi);
    }
    b.finish(true)
}

fn t_pipe() -> Mesh {
    const HUB: f64 = 30.0; // half-size of the hub along x and y
    const HUB_Z: f64 = 38.0; // ... and along z: taller than wide, so no quarter turn about the run
                             // axis maps it onto itself
    const CAVITY: f64 = 18.0; // half-size of the cavity where the bores meet
    const RUN_R: f64 = 22.0;
    const RUN_BORE_R: f64 = 15.0;
    const RUN_PLUS_X: f64 = 100.0;
    const RUN_MINUS_X: f64 = -75.0;
    const BRANCH_R: f64 = 18.0;
    const BRANCH_BORE_R: f64 = 11.0;
    const BRANCH_Z: f64 = 80.0;
    const FOOT_R: f64 = 8.0;
    const FOOT_H: f64 = 12.0;
    let mut b = SolidBuilder::default();
    let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
    let o = Point3::origin();

    // Three stubs: +x, -x (shorter) and +z (narrower). Each is a ring on the hub face, an outer
    // wall, an end annulus, and a bore back to the cavity.
    struct Stub {
        axis: Vector3<f64>,
        u: Vector3<f64>,
        v: Vector3<f64>,
        end: f64,
        outer_r: f64,
        bore_r: f64,
    }
    let stubs = [
        Stub {
            axis: x,
            u: y,
            v: z,
            end: RUN_PLUS_X,
            outer_r: RUN_R,
            bore_r: RUN_BORE_R,
        },
        Stub {
            axis: -x,
            u: y,
            v: z,
            end: -RUN_MINUS_X,
            outer_r: RUN_R,
            bore_r: RUN_BORE_R,
        },
        Stub {
            axis: z,
            u: x,
            v: y,
            end: BRANCH_Z,
            outer_r: BRANCH_R,
            bore_r: BRANCH_BORE_R,
        },
    ];
    let mut hub_holes: Vec<(Vector3<f64>, Vec<u32>)> = Vec::new();
    let mut cavity_holes: Vec<(Vector3<f64>, Vec<u32>)> = Vec::new();
    for s in &stubs {
        let hub_half = if s.axis.z != 0.0 { HUB_Z } else { HUB };
        let root = b.ring(o + s.axis * hub_half, s.u, s.v, s.outer_r, 40);
        let end_outer = b.ring(o + s.axis * s.end, s.u, s.v, s.outer_r, 40);
        let end_bore = b.ring(o + s.axis * s.end, s.u, s.v, s.bore_r, 32);
        let bore_root = b.ring(o + s.axis * CAVITY, s.u, s.v, s.bore_r, 32);
        b.strip(&root, &end_outer);
        b.planar(&end_outer, std::slice::from_ref(&end_bore));
        b.strip(&end_bore, &bore_root);
        hub_holes.push((s.axis, root));
        cavity_holes.push((s.axis, bore_root));
    }
    // A mounting foot off-centre under the hub: from below, where the branch is hidden, the run
    // and the square hub alone would repeat every half turn about x.
    let foot_centre = Point3::new(10.0, 12.0, -HUB_Z);
    let foot_root = b.ring(foot_centre, x, y, FOOT_R, 24);
    let foot_end = b.ring(foot_centre - z * FOOT_H, x, y, FOOT_R, 24);
    b.strip(&foot_root, &foot_end);
    b.planar(&foot_end, &[]);
    hub_holes.push((-z, foot_root));
    for (half, holes) in [
        (Vector3::new(HUB, HUB, HUB_Z), &hub_holes),
        (Vector3::repeat(CAVITY), &cavity_holes),
    ] {
        let corners: Vec<u32> = (0..8)
            .map(|i| {
                let s = |bit: usize, h: f64| if i & bit == 0 { -h } else { h };
                b.vertex(Point3::new(s(1, half.x), s(2, half.y), s(4, half.z)))
            })
            .collect();
        let faces = [
            (-x, [0, 2, 6, 4]),
            (x, [1, 5, 7, 3]),
            (-y, [0, 4, 5, 1]),
            (y, [2, 3, 7, 6]),
            (-z, [0, 1, 3, 2]),
            (z, [4, 6, 7, 5]),
        ];
        for (normal, quad) in faces {
            let face_holes: Vec<Vec<u32>> = holes
                .iter()
                .filter(|(axis, _)| *axis == normal)
                .map(|(_, r)| r.clone())
                .collect();
            b.planar(&quad.map(|i| corners[i]), &face_holes);
        }
    }
    b.finish(true)
}

/// Assembles a closed solid from shared vertices: planar faces (polygons with holes) and strips
/// between two loops. Winding is made consistent and outward at the end, so callers need not
/// care about loop directions.
#[derive(Default)]
struct SolidBuilder {
    positions: Vec<Point3<f64>>,
    faces: Vec<[u32; 3]>,
}

impl SolidBuilder {
    fn vertex(&mut self, p: Point3<f64>) -> u32 {
        self.positions.push(p);
        (self.positions.len() - 1) as u32
    }

    /// `segments` points on the circle `centre + r (cos φ u + sin φ v)`, starting at φ = 0.
    fn ring(
        &mut self,
        centre: Point3<f64>,
        u: Vector3<f64>,
        v: Vector3<f64>,
        radius: f64,
        segments: usize,
    ) -> Vec<u32> {
        (0..segments)
            .map(|i| {
                let a = TAU * i as f64 / segments as f64;
                self.vertex(centre + (u * a.cos() + v * a.sin()) * radius)
            })
            .collect()
    }

    /// The two ends of a prism: the `profile`'s (x, z) points at y = 0 and at y = `length`,
    /// each end a planar face. [`Self::prism_sides`] closes it.
    fn prism_ends(&mut self, profile: &[(f64, f64)], length: f64) -> (Vec<u32>, Vec<u32>) {
        let mut end = |y: f64| -> Vec<u32> {
            profile
                .iter()
                .map(|&(x, z)| self.vertex(Point3::new(x, y, z)))
                .collect()
        };
        let (front, back) = (end(0.0), end(length));
        self.planar(&front, &[]);
        self.planar(&back, &[]);
        (front, back)
    }

    /// The side faces of a prism between its two ends, side `i` joining the profile's points
    /// `i` and `i + 1`, with the holes `holes(i)`.
    fn prism_sides<'h>(
        &mut self,
        front: &[u32],
        back: &[u32],
        holes: impl Fn(usize) -> &'h [Vec<u32>],
    ) {
        let n = front.len();
        for i in 0..n {
            let j = (i + 1) % n;
            self.planar(&[front[i], front[j], back[j], back[i]], holes(i));
        }
    }

    /// A closed loop of points given in the plane `z = const`.
    fn loop_xy(&mut self, points: &[Vector2<f64>], z: f64) -> Vec<u32> {
        points
            .iter()
            .map(|p| self.vertex(Point3::new(p.x, p.y, z)))
            .collect()
    }

    /// Triangulates the planar polygon `outer` minus the `holes` (all loops of existing vertices).
    fn planar(&mut self, outer: &[u32], holes: &[Vec<u32>]) {
        let p = |i: u32| self.positions[i as usize];
        // Newell's normal of the outer loop, and a basis of its plane.
        let mut n = Vector3::zeros();
        for k in 0..outer.len() {
            let (a, b) = (p(outer[k]), p(outer[(k + 1) % outer.len()]));
            n += Vector3::new(
                (a.y - b.y) * (a.z + b.z),
                (a.z - b.z) * (a.x + b.x),
                (a.x - b.x) * (a.y + b.y),
            );
        }
        let n = n.normalize();
        let helper = if n.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let e1 = n.cross(&helper).normalize();
        let e2 = n.cross(&e1);
        let mut ids: Vec<u32> = Vec::new();
        let mut points: Vec<Vector2<f64>> = Vec::new();
        let mut add_loop = |lp: &[u32]| -> Vec<usize> {
            lp.iter()
                .map(|&i| {
                    let q = p(i).coords;
                    ids.push(i);
                    points.push(Vector2::new(q.dot(&e1), q.dot(&e2)));
                    ids.len() - 1
                })
                .collect()
        };
        let outer_local = add_loop(outer);
        let holes_local: Vec<Vec<usize>> = holes.iter().map(|h| add_loop(h)).collect();
        for [a, b, c] in triangulate(&points, outer_local, holes_local) {
            self.faces.push([ids[a], ids[b], ids[c]]);
        }
    }

    /// Quads between two closed loops of equal length, `a[k]` facing `b[k]`.
    fn strip(&mut self, a: &[u32], b: &[u32]) {
        debug_assert_eq!(a.len(), b.len());
        let n = a.len();
        for k in 0..n {
            let l = (k + 1) % n;
            self.faces.push([a[k], a[l], b[l]]);
            self.faces.push([a[k], b[l], b[k]]);
        }
    }

    /// Orients the faces outward, optionally centres the solid on its bounding box, and splits
    /// vertices along creases.
    fn finish(mut self, centre: bool) -> Mesh {
        orient_outward(&self.positions, &mut self.faces);
        if centre {
            let (mut lo, mut hi) = (self.positions[0], self.positions[0]);
            for p in &self.positions {
                lo = lo.inf(p);
                hi = hi.sup(p);
            }
            let c = nalgebra::center(&lo, &hi).coords;
            for p in &mut self.positions {
                *p -= c;
            }
        }
        split_creases(&self.positions, &self.faces, CREASE_ANGLE_DEG.to_radians())
    }
}

/// Makes neighbouring faces traverse their shared edge in opposite directions, then turns each
/// connected component so that its enclosed volume is positive (normals outward).
fn orient_outward(positions: &[Point3<f64>], faces: &mut [[u32; 3]]) {
    let mut edge_faces: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
    for (f, tri) in faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            edge_faces.entry((a.min(b), a.max(b))).or_default().push(f);
        }
    }
    let has_directed =
        |tri: &[u32; 3], a: u32, b: u32| (0..3).any(|k| tri[k] == a && tri[(k + 1) % 3] == b);
    let mut visited = vec![false; faces.len()];
    for seed in 0..faces.len() {
        if visited[seed] {
            continue;
        }
        visited[seed] = true;
        let mut component = vec![seed];
        let mut stack = vec![seed];
        while let Some(f) = stack.pop() {
            let tri = faces[f];
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                for &g in &edge_faces[&(a.min(b), a.max(b))] {
                    if g == f || visited[g] {
                        continue;
                    }
                    if has_directed(&faces[g], a, b) {
                        faces[g].swap(1, 2);
                    }
                    visited[g] = true;
                    component.push(g);
                    stack.push(g);
                }
            }
        }
        let volume: f64 = component
            .iter()
            .map(|&f| {
                let [a, b, c] = faces[f].map(|i| positions[i as usize].coords);
                a.dot(&b.cross(&c))
            })
            .sum();
        if volume < 0.0 {
            for &f in &component {
                faces[f].swap(1, 2);
            }
        }
    }
}

fn cross2(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

fn signed_area(points: &[Vector2<f64>], lp: &[usize]) -> f64 {
    (0..lp.len())
        .map(|k| cross2(points[lp[k]], points[lp[(k + 1) % lp.len()]]))
        .sum::<f64>()
        / 2.0
}

/// Ear-clipping triangulation of a simple polygon with holes. Holes are first joined to the outer
/// loop by bridges (to the nearest vertex that sees the hole's rightmost vertex), then ears are cut.
/// Returns counter-clockwise triangles of indices into `points`.
fn triangulate(
    points: &[Vector2<f64>],
    mut outer: Vec<usize>,
    mut holes: Vec<Vec<usize>>,
) -> Vec<[usize; 3]> {
    if signed_area(points, &outer) < 0.0 {
        outer.reverse();
    }
    for h in &mut holes {
        if signed_area(points, h) > 0.0 {
            h.reverse();
        }
    }
    let max_x = |h: &Vec<usize>| h.iter().map(|&i| points[i].x).fold(f64::MIN, f64::max);
    holes.sort_by(|a, b| max_x(b).total_cmp(&max_x(a)));

    let mut poly = outer;
    for hi in 0..holes.len() {
        let hole = &holes[hi];
        let m = (0..hole.len())
            .max_by(|&a, &b| points[hole[a]].x.total_cmp(&points[hole[b]].x))
            .unwrap_or(0);
        let mp = points[hole[m]];
        let mut candidates: Vec<usize> = (0..poly.len()).collect();
        candidates.sort_by(|&a, &b| {
            (points[poly[a]] - mp)
                .norm()
                .total_cmp(&(points[poly[b]] - mp).norm())
        });
        let blocked = |j: usize| {
            let vp = points[poly[j]];
            let loops = std::iter::once(&poly).chain(holes[hi..].iter());
            for lp in loops {
                for k in 0..lp.len() {
                    let (a, b) = (points[lp[k]], points[lp[(k + 1) % lp.len()]]);
                    if a == vp || b == vp || a == mp || b == mp {
                        continue;
                    }
                    if segments_touch(mp, vp, a, b) {
                        return true;
                    }
                }
            }
            false
        };
        let in_wedge = |j: usize| {
            let n = poly.len();
            let v = points[poly[j]];
            let a = points[poly[(j + 1) % n]] - v;
            let b = points[poly[(j + n - 1) % n]] - v;
            let d = mp - v;
            if cross2(a, b) > 0.0 {
                cross2(a, d) > 0.0 && cross2(d, b) > 0.0
            } else {
                !(cross2(b, d) >= 0.0 && cross2(d, a) >= 0.0)
            }
        };
        let bridge = candidates
            .iter()
            .copied()
            .find(|&j| in_wedge(j) && !blocked(j))
            .or_else(|| candidates.iter().copied().find(|&j| in_wedge(j)))
            .unwrap_or(candidates[0]);
        let mut merged = Vec::with_capacity(poly.len() + hole.len() + 2);
        merged.extend_from_slice(&poly[..=bridge]);
        merged.extend(hole[m..].iter().chain(&hole[..=m]));
        merged.extend_from_slice(&poly[bridge..]);
        poly = merged;
    }
    ear_clip(points, &poly)
}

/// Whether segment `p–q` crosses or touches segment `a–b` (endpoints shared by position are
/// excluded by the caller).
fn segments_touch(p: Vector2<f64>, q: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>) -> bool {
    let o = |u: Vector2<f64>, v: Vector2<f64>, w: Vector2<f64>| cross2(v - u, w - u);
    let (o1, o2, o3, o4) = (o(p, q, a), o(p, q, b), o(a, b, p), o(a, b, q));
    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
        return true;
    }
    let on = |u: Vector2<f64>, v: Vector2<f64>, w: Vector2<f64>, ow: f64| {
        ow.abs() <= 1e-9 * (v - u).norm_squared().max(1.0)
            && (w - u).dot(&(v - u)) > 0.0
            && (w - v).dot(&(u - v)) > 0.0
    };
    on(p, q, a, o1) || on(p, q, b, o2) || on(a, b, p, o3) || on(a, b, q, o4)
}

fn ear_clip(points: &[Vector2<f64>], poly: &[usize]) -> Vec<[usize; 3]> {
    let n = poly.len();
    let mut out = Vec::with_capacity(n.saturating_sub(2));
    if n < 3 {
        return out;
    }
    let mut next: Vec<usize> = (0..n).map(|i| (i + 1) % n).collect();
    let mut prev: Vec<usize> = (0..n).map(|i| (i + n - 1) % n).collect();
    let mut alive = vec![true; n];
    let pt = |i: usize| points[poly[i]];
    let convexity = |p: usize, i: usize, q: usize| cross2(pt(i) - pt(p), pt(q) - pt(i));
    let inside = |x: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>| {
        cross2(b - a, x - a) >= 0.0 && cross2(c - b, x - b) >= 0.0 && cross2(a - c, x - c) >= 0.0
    };
    let mut remaining = n;
    let mut i = 0;
    let mut misses = 0;
    while remaining > 3 {
        let (p, q) = (prev[i], next[i]);
        let (a, b, c) = (pt(p), pt(i), pt(q));
        let mut ear = convexity(p, i, q) > 0.0;
        if ear {
            let mut k = next[q];
            while k != p {
                let x = pt(k);
                if x != a && x != b && x != c && inside(x, a, b, c) {
                    ear = false;
                    break;
                }
                k = next[k];
            }
        }
        // After a full lap without an ear (only possible through rounding), cut the most convex
        // corner so the loop always ends.
        if !ear && misses > remaining {
            let mut best = i;
            let mut k = next[i];
            while k != i {
                if convexity(prev[k], k, next[k]) > convexity(prev[best], best, next[best]) {
                    best = k;
                }
                k = next[k];
            }
            i = best;
            ear = true;
        }
        if ear {
            let (p, q) = (prev[i], next[i]);
            out.push([poly[p], poly[i], poly[q]]);
            alive[i] = false;
            next[p] = q;
            prev[q] = p;
            remaining -= 1;
            misses = 0;
            i = p;
        } else {
            misses += 1;
            i = next[i];
        }
    }
    let i = (0..n).find(|&k| alive[k]).unwrap_or(0);
    out.push([poly[prev[i]], poly[i], poly[next[i]]]);
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use nalgebra::{Rotation3, Unit};

    fn key(p: &Point3<f32>) -> [i64; 3] {
        [p.x, p.y, p.z].map(|c| (c as f64 * 1000.0).round() as i64)
    }

    /// Every edge (by position) is used exactly once in each direction.
    pub(crate) fn assert_closed(mesh: &Mesh, what: &str) {
        let mut directed: HashMap<([i64; 3], [i64; 3]), u32> = HashMap::new();
        for t in &mesh.faces {
            for k in 0..3 {
                let a = key(&mesh.positions[t[k] as usize]);
                let b = key(&mesh.positions[t[(k + 1) % 3] as usize]);
                assert_ne!(a, b, "{what}: degenerate edge");
                *directed.entry((a, b)).or_default() += 1;
            }
        }
        for (&(a, b), &count) in &directed {
            assert_eq!(
                count, 1,
                "{what}: edge {a:?}->{b:?} used {count} times in one direction"
            );
            assert_eq!(
                directed.get(&(b, a)),
                Some(&1),
                "{what}: edge {a:?}->{b:?} has no opposite"
            );
        }
    }

    fn volume_and_outwardness(mesh: &Mesh) -> (f64, f64) {
        let centre = mesh
            .positions
            .iter()
            .fold(Vector3::zeros(), |s, p| s + p.coords.cast::<f64>())
            / mesh.positions.len() as f64;
        let (mut volume, mut outward) = (0.0, 0.0);
        for t in &mesh.faces {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize].coords.cast::<f64>());
            volume += a.dot(&b.cross(&c)) / 6.0;
            let area_normal = (b - a).cross(&(c - a)) / 2.0;
            outward += area_normal.dot(&((a + b + c) / 3.0 - centre));
        }
        (volume, outward)
    }

    fn diameter(mesh: &Mesh) -> f32 {
        let mut d2 = 0.0f32;
        for (i, p) in mesh.positions.iter().enumerate() {
            for q in &mesh.positions[i + 1..] {
                d2 = d2.max((p - q).norm_squared());
            }
        }
        d2.sqrt()
    }

    #[test]
    fn parts_are_closed_outward_and_lm_o_sized() {
        for part in Part::ALL {
            let mesh = part.mesh();
            let name = part.name();
            assert_eq!(mesh.positions.len(), mesh.normals.len());
            assert!(
                mesh.faces.len() > 100,
                "{name}: only {} faces",
                mesh.faces.len()
            );
            assert_closed(&mesh, name);
            let (volume, outward) = volume_and_outwardness(&mesh);
            assert!(volume > 1e4, "{name}: volume {volume} mm³");
            assert!(outward > 0.0, "{name}: faces point inward ({outward})");
            let d = diameter(&mesh);
            assert!((80.0..=250.0).contains(&d), "{name}: diameter {d} mm");
            for n in &mesh.normals {
                assert!(
                    (n.norm() - 1.0).abs() < 1e-4,
                    "{name}: normal {n:?} not unit"
                );
            }
            // Each corner's vertex normal agrees with its face: no inverted or smeared normals.
            for t in &mesh.faces {
                let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
                let Some(fn_) = (b - a).cross(&(c - a)).try_normalize(1e-9) else {
                    continue;
                };
                for &i in t {
                    let dot = mesh.normals[i as usize].dot(&fn_);
                    assert!(
                        dot > CREASE_ANGLE_DEG.to_radians().cos() as f32 - 1e-3,
                        "{name}: corner normal off its face ({dot})"
                    );
                }
            }
        }
    }

    #[test]
    fn sharp_edges_split_vertices() {
        let cube = box_mesh(Vector3::new(10.0, 20.0, 30.0));
        assert_eq!(cube.positions.len(), 24);
        assert_eq!(cube.faces.len(), 12);
        assert_closed(&cube, "box");
        // A cylinder's side is smooth: one vertex per rim point on the side, one per cap.
        let cyl = cylinder_mesh(20.0, 50.0, 32);
        assert_eq!(cyl.positions.len(), 4 * 32);
        assert_closed(&cyl, "cylinder");
        for (p, n) in cyl.positions.iter().zip(&cyl.normals) {
            let radial = Vector3::new(p.x, p.y, 0.0).normalize();
            let ok = (n.z.abs() - 1.0).abs() < 1e-5 || (n.dot(&radial) - 1.0).abs() < 1e-5;
            assert!(
                ok,
                "cylinder normal {n:?} at {p:?} is neither axial nor radial"
            );
        }
    }

    #[test]
    fn parts_have_no_rotational_symmetry() {
        for part in Part::ALL {
            let mesh = part.mesh();
            let sample: Vec<Point3<f32>> = mesh.positions.iter().step_by(3).copied().collect();
            let mut rotations = Vec::new();
            for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
                for angle in [0.5 * PI, PI, TAU / 3.0, TAU / 24.0] {
                    rotations.push(Rotation3::from_axis_angle(
                        &Unit::new_normalize(axis),
                        angle as f32,
                    ));
                }
            }
            for r in rotations {
                let moved = sample
                    .iter()
                    .filter(|p| {
                        let q = r * **p;
                        mesh.positions.iter().all(|m| (m - q).norm_squared() > 1.0)
                    })
                    .count();
                let fraction = moved as f32 / sample.len() as f32;
                assert!(
                    fraction > 0.01,
                    "{}: {:?} maps it onto itself ({fraction})",
                    part.name(),
                    r.scaled_axis()
                );
            }
        }
    }

    /// The symmetric parts are closed, and have the symmetry they claim and no other turn of
    /// those the plain parts are checked for.
    #[test]
    fn symmetric_parts_have_their_symmetry_and_no_other() {
        for part in SymmetricPart::ALL {
            let mesh = part.mesh();
            let sanity = crate::model::sanity::check_mesh(&mesh).unwrap();
            assert!(sanity.closed && !sanity.inward_normals, "{part:?}");
            let symmetry = part.symmetry();
            let points = crate::model::sampling::sample_surface(&mesh, 20_000, 1).unwrap();
            let d = sanity.diameter_mm;
            for (what, off) in symmetry.misfits(&points) {
                assert!(off < 0.01 * d, "{part:?}: {what} moves it {off} mm");
            }
            let mut wrong = Vec::new();
            for axis in [Vector3::x(), Vector3::y()] {
                for angle in [0.5 * PI, PI] {
                    wrong.push(crate::Pose::rotation(axis * angle as f32));
                }
            }
            if part == SymmetricPart::UChannel {
                wrong.push(crate::Pose::rotation(Vector3::z() * (0.5 * PI) as f32));
            }
            let not = Symmetry {
                discrete: wrong,
                continuous: None,
            };
            for (what, off) in not.misfits(&points) {
                assert!(off > 0.1 * d, "{part:?}: {what} moves it only {off} mm");
            }
        }
    }

    #[test]
    fn triangulates_square_with_two_holes() {
        let mut pts = vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(10.0, 0.0),
            Vector2::new(10.0, 10.0),
            Vector2::new(0.0, 10.0),
        ];
        let mut holes = Vec::new();
        for c in [Vector2::new(3.0, 3.0), Vector2::new(7.0, 6.0)] {
            let start = pts.len();
            for k in 0..8 {
                let a = TAU * k as f64 / 8.0;
                pts.push(c + Vector2::new(a.cos(), a.sin()) * 1.5);
            }
            holes.push((start..start + 8).collect::<Vec<_>>());
        }
        let tris = triangulate(&pts, vec![0, 1, 2, 3], holes);
        assert_eq!(tris.len(), 4 + 2 * 8 + 2 * 2 - 2);
        let area: f64 = tris
            .iter()
            .map(|t| {
                let a = cross2(pts[t[1]] - pts[t[0]], pts[t[2]] - pts[t[0]]) / 2.0;
                assert!(a >= 0.0, "triangle {t:?} is clockwise");
                a
            })
            .sum();
        let octagon = 2.0 * 8.0 * 0.5 * 1.5 * 1.5 * (TAU / 8.0).sin();
        assert!((area - (100.0 - octagon)).abs() < 1e-9, "area {area}");
    }
}
