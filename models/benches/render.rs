//! Depth rendering of an LM-O-sized part at about 1 m: the whole 640×480 frame, and a 128×128
//! region of interest around the object (what re-scoring renders per hypothesis).

use std::collections::HashMap;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion};
use ppfd_models::geometry::camera::Intrinsics;
use ppfd_models::geometry::mesh::Mesh;
use ppfd_models::geometry::render::{bounding_sphere, Renderer, Roi};
use ppfd_models::synthetic::parts::Part;

/// Splits every triangle into four (midpoints shared between neighbours), `levels` times: the
/// part's shape at LM-O's mesh density (10k–45k triangles, about half as many vertices).
fn subdivide(mesh: &Mesh, levels: u32) -> Mesh {
    let mut m = mesh.clone();
    for _ in 0..levels {
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::new();
        let mut faces = Vec::with_capacity(m.faces.len() * 4);
        for f in m.faces.clone() {
            let mut mid = |a: u32, b: u32| {
                *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (pa, pb) = (m.positions[a as usize], m.positions[b as usize]);
                    let n = (m.normals[a as usize] + m.normals[b as usize]).normalize();
                    m.positions
                        .push(Point3::from((pa.coords + pb.coords) / 2.0));
                    m.normals.push(n);
                    m.positions.len() as u32 - 1
                })
            };
            let [a, b, c] = f;
            let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
            faces.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        m.faces = faces;
    }
    m
}

fn bench_render(c: &mut Criterion) {
    let k = Intrinsics::LMO;
    let pose = Isometry3::from_parts(
        Translation3::new(40.0, -30.0, 1000.0),
        UnitQuaternion::from_euler_angles(0.7, -0.4, 0.3),
    );
    let coarse = Part::TPipe.mesh();
    let dense = subdivide(&coarse, 2);
    for (label, mesh) in [("t_pipe_900_faces", &coarse), ("t_pipe_14k_faces", &dense)] {
        let mut renderer = Renderer::new();
        c.bench_function(&format!("render/{label}/640x480"), |b| {
            b.iter(|| {
                renderer
                    .render_into(mesh, &pose, &k, Roi::full(640, 480))
                    .unwrap()
            })
        });
        let (centre, radius) = bounding_sphere(mesh);
        let around = Roi::around_sphere(&(pose * centre), radius, &k, 640, 480).unwrap();
        let roi = Roi {
            u0: around.u0 + around.width / 2 - 64,
            v0: around.v0 + around.height / 2 - 64,
            width: 128,
            height: 128,
        };
        c.bench_function(&format!("render/{label}/roi128"), |b| {
            b.iter(|| renderer.render_into(mesh, &pose, &k, roi).unwrap())
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(50).measurement_time(std::time::Duration::from_secs(3));
    targets = bench_render
}
criterion_main!(benches);
