//! Global modelling (offline, once per object): from a mesh to an [`ObjectModel`] holding the
//! subsampled oriented points, the PPF lookup table, what rendering needs and the object's
//! [`symmetry`].
//!
//! [`ObjectModel`] is the same in memory whether just built or read from a model file
//! ([`crate::model::store`], into a private memory map): a byte buffer holding an rkyv archive of
//! [`ModelData`], read in place.

pub mod feature;
pub mod sampling;
pub mod sanity;
pub mod store;
pub mod subsample;
pub mod symmetry;
pub mod table;

use std::sync::{Arc, Mutex};

use memmap2::Mmap;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use rkyv::util::AlignedVec;

use crate::geometry::mesh::Mesh;
use crate::limits;
use crate::model::feature::{key_count, LocalFrame, PointPairFeature, Quantizer};
use crate::model::sampling::sample_surface;
use crate::model::subsample::{subsample, OrientedPoints, SubsampleParams};
use crate::model::symmetry::Symmetry;
use crate::model::table::{pack_entry, LookupTable};
use crate::{Error, Result};

/// Parameters of model building. Defaults are the paper's (Vidal et al. 2018, §V) where it gives
/// them.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    rkyv::Archive,
    rkyv::Serialize,
    rkyv::Deserialize,
    serde::Serialize,
)]
#[rkyv(derive(Debug))]
pub struct ModelParams {
    /// Voxel leaf as a fraction of the model diameter. The paper: 0.05.
    pub leaf_fraction: f32,
    /// Normal clustering angle, degrees. The paper: 30°.
    pub cluster_angle_deg: f32,
    /// Remove non-discriminative neighbouring clusters after clustering. The paper: yes.
    pub neighbour_filtering: bool,
    /// Distance bins of the feature over `[0, D]`. The paper: 20.
    pub distance_bins: u32,
    /// Angle bins of each feature angle over `[0, π]`. The paper: 15.
    pub angle_bins: u32,
    /// Bins of the rotation angle α over `[−π, π)` used when voting. Not in the paper; 30 bins of
    /// 12° match the angle bins, and ≤ 32 lets one `u32` hold the vote-once flags.
    pub alpha_bins: u32,
    /// Spacing of the dense surface samples taken before subsampling, as a fraction of the
    /// diameter: 0.01 gives 5 samples along a voxel's edge (leaf 0.05), about 25 on each voxel
    /// face a surface crosses, enough for stable voxel means.
    pub sampling_step_fraction: f32,
    /// Voxel leaf, as a fraction of the diameter, of the denser surface points kept for
    /// re-scoring, ICP and the filters (not used for voting). 0.025 keeps about 4× the voting
    /// points: enough to measure a fit to a few millimetres, cheap enough for 500 poses.
    pub surface_leaf_fraction: f32,
}

impl Default for ModelParams {
    fn default() -> Self {
        Self {
            leaf_fraction: 0.05,
            cluster_angle_deg: 30.0,
            neighbour_filtering: true,
            distance_bins: 20,
            angle_bins: 15,
            alpha_bins: 30,
            sampling_step_fraction: 0.01,
            surface_leaf_fraction: 0.025,
        }
    }
}

impl ModelParams {
    /// Refuses values the method cannot work with.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidParameter(what));
        if !(self.leaf_fraction > 0.0 && self.leaf_fraction < 1.0) {
            return bad(format!(
                "leaf_fraction must be in (0, 1), got {}",
                self.leaf_fraction
            ));
        }
        if !(self.cluster_angle_deg > 0.0 && self.cluster_angle_deg < 180.0) {
            return bad(format!(
                "cluster_angle_deg must be in (0, 180), got {}",
                self.cluster_angle_deg
            ));
        }
        if !(1..=64).contains(&self.distance_bins) || !(1..=64).contains(&self.angle_bins) {
            return bad(format!(
                "distance_bins and angle_bins must be in 1..=64, got {} and {}",
                self.distance_bins, self.angle_bins
            ));
        }
        if !(2..=32).contains(&self.alpha_bins) {
            return bad(format!(
                "alpha_bins must be in 2..=32, got {}",
                self.alpha_bins
            ));
        }
        if !(self.sampling_step_fraction > 0.0 && self.sampling_step_fraction <= self.leaf_fraction)
        {
            return bad(format!(
                "sampling_step_fraction must be in (0, leaf_fraction], got {}",
                self.sampling_step_fraction
            ));
        }
        if !(self.surface_leaf_fraction >= self.sampling_step_fraction
            && self.surface_leaf_fraction < 1.0)
        {
            return bad(format!(
                "surface_leaf_fraction must be in [sampling_step_fraction, 1), got {}",
                self.surface_leaf_fraction
            ));
        }
        Ok(())
    }

    /// The subsampling parameters for an object of diameter `diameter_mm`.
    pub fn subsample_params(&self, diameter_mm: f32) -> SubsampleParams {
        SubsampleParams {
            leaf_mm: self.leaf_fraction * diameter_mm,
            cluster_angle: self.cluster_angle_deg.to_radians(),
            neighbour_filtering: self.neighbour_filtering,
        }
    }

    /// The feature quantiser for an object of diameter `diameter_mm`.
    pub fn quantizer(&self, diameter_mm: f32) -> Quantizer {
        Quantizer::new(diameter_mm, self.distance_bins, self.angle_bins)
    }
}

/// Everything a model file holds. Read in place as [`ArchivedModelData`] through
/// [`ObjectModel::data`].
#[derive(rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct ModelData {
    /// The object's id (BOP `obj_id` for dataset models).
    pub object_id: u32,
    /// A human-readable name (file stem or part name).
    pub name: String,
    /// `D`, the largest distance between two model points, mm.
    pub diameter_mm: f32,
    /// The parameters it was built with.
    pub params: ModelParams,
    /// [`Mesh::fingerprint`] of the mesh it was built from: a cached model is reused only for
    /// the same mesh ([`crate::model::store::load_expecting`]).
    pub mesh_fingerprint: u32,
    /// CRC-32 of the bytes of the file the mesh was read from, 0 when unknown: a cached model
    /// whose file is unchanged is reused without reading the mesh again
    /// ([`crate::model::store::load_built_from_file`]). Set with [`ObjectModel::with_source_crc`].
    pub source_crc: u32,
    /// Subsampled oriented points (mm, unit normals): the model points of the lookup table.
    pub points: Vec<[f32; 3]>,
    /// Unit normals of `points`, index-aligned.
    pub normals: Vec<[f32; 3]>,
    /// Denser oriented points of the surface (see [`ModelParams::surface_leaf_fraction`]).
    pub surface_points: Vec<[f32; 3]>,
    /// Unit normals of `surface_points`, index-aligned.
    pub surface_normals: Vec<[f32; 3]>,
    /// Lookup table offsets: `key_count + 1` values.
    pub table_offsets: Vec<u32>,
    /// Lookup table entries (see [`crate::model::table::pack_entry`]).
    pub table_entries: Vec<u32>,
    /// The mesh, for rendering: vertex positions (mm) and triangles.
    pub mesh_positions: Vec<[f32; 3]>,
    /// Triangles, as indices into `mesh_positions`.
    pub mesh_faces: Vec<[u32; 3]>,
    /// The object's discrete symmetries, [`Symmetry::stored_discrete`]; empty without.
    pub symmetries_discrete: Vec<[f32; 7]>,
    /// Its continuous symmetry axis, [`Symmetry::stored_continuous`]: at most one.
    pub symmetries_continuous: Vec<[f32; 6]>,
}

enum Backing {
    Owned(AlignedVec),
    Mapped { map: Mmap, offset: usize },
}

/// An object model ready for matching: built in memory or read from a model file.
pub struct ObjectModel {
    backing: Backing,
    /// The coarse mesh of silhouettes and the cell it was made with, made on first use
    /// ([`ObjectModel::silhouette_mesh`]): a resident daemon makes it once, not per detection.
    silhouette: Mutex<Option<(f32, Arc<Mesh>)>>,
}

impl std::fmt::Debug for ObjectModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObjectModel")
            .field("object_id", &self.object_id())
            .field("name", &self.name())
            .field("diameter_mm", &self.diameter_mm())
            .field(
                "mesh_fingerprint",
                &format_args!("{:08x}", self.mesh_fingerprint()),
            )
            .field("points", &self.point_count())
            .field("table_entries", &self.table_entry_count())
            .finish()
    }
}

#[inline]
fn point(p: &[rkyv::Archived<f32>; 3]) -> Point3<f32> {
    Point3::new(p[0].to_native(), p[1].to_native(), p[2].to_native())
}

impl ObjectModel {
    /// Builds the model of `mesh` (METHOD.md §1): dense area-uniform samples, the diameter,
    /// voxel subsampling with normal clustering and neighbour filtering, and the lookup table
    /// of every ordered pair of the subsampled points.
    ///
    /// A mesh that makes no sense in millimetres is refused ([`sanity::check_mesh`]); a closed
    /// mesh whose normals point inward is built with them flipped, and a warning is logged, as
    /// it is for a diameter below [`crate::limits::SMALL_DIAMETER_MM`].
    pub fn build(mesh: &Mesh, object_id: u32, name: &str, params: &ModelParams) -> Result<Self> {
        let (model, report) = Self::build_with_report(mesh, object_id, name, params)?;
        if report.inward_normals {
            tracing::warn!(
                name,
                "the normals of this closed mesh point inward: flipped to point outward"
            );
        }
        if let Some(warning) = report.small_warning() {
            tracing::warn!(name, "{warning}");
        }
        Ok(model)
    }

    /// [`ObjectModel::build`], and what [`sanity::check_mesh`] found in the mesh (its
    /// diameter, size, and whether its normals were flipped), for a caller that reports it.
    pub fn build_with_report(
        mesh: &Mesh,
        object_id: u32,
        name: &str,
        params: &ModelParams,
    ) -> Result<(Self, sanity::MeshReport)> {
        params.validate()?;
        if mesh.positions.is_empty() || mesh.faces.is_empty() {
            return Err(Error::InvalidMesh(format!(
                "{name}: a model needs a mesh with faces, got {} vertices and {} faces",
                mesh.positions.len(),
                mesh.faces.len()
            )));
        }
        let report = sanity::check_mesh(mesh).map_err(|e| match e {
            Error::InvalidMesh(reason) => Error::InvalidMesh(format!("{name}: {reason}")),
            other => other,
        })?;
        let fingerprint = mesh.fingerprint();
        let flipped;
        let mesh = if report.inward_normals {
            let mut copy = mesh.clone();
            copy.flip_normals();
            flipped = copy;
            &flipped
        } else {
            mesh
        };
        let diameter_mm = report.diameter_mm;
        let area: f32 = mesh
            .faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| mesh.positions[i as usize]);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum();
        let step = params.sampling_step_fraction * diameter_mm;
        let count = ((area / (step * step)) as usize).clamp(1_000, 2_000_000);
        let dense = sample_surface(mesh, count, 0x5eed ^ object_id as u64)?;
        let points = subsample(&dense, &params.subsample_params(diameter_mm));
        if points.len() < limits::MIN_MODEL_POINTS {
            return Err(Error::InvalidMesh(format!(
                "{name}: {} model points after subsampling, at least {} needed: the faces cover \
                 too little of the extent of the mesh's vertices ({diameter_mm} mm across); remove \
                 stray vertices and degenerate faces",
                points.len(),
                limits::MIN_MODEL_POINTS
            )));
        }
        if points.len() > u16::MAX as usize {
            return Err(Error::InvalidParameter(format!(
                "{name}: {} model points after subsampling, at most {} fit a table entry",
                points.len(),
                u16::MAX
            )));
        }
        let table = build_table(&points, &params.quantizer(diameter_mm));
        let surface = subsample(
            &dense,
            &SubsampleParams {
                leaf_mm: params.surface_leaf_fraction * diameter_mm,
                cluster_angle: params.cluster_angle_deg.to_radians(),
                neighbour_filtering: false,
            },
        );
        let data = ModelData {
            object_id,
            name: name.to_string(),
            diameter_mm,
            params: *params,
            mesh_fingerprint: fingerprint,
            source_crc: 0,
            points: points.positions.iter().map(|p| [p.x, p.y, p.z]).collect(),
            normals: points.normals.iter().map(|n| [n.x, n.y, n.z]).collect(),
            surface_points: surface.positions.iter().map(|p| [p.x, p.y, p.z]).collect(),
            surface_normals: surface.normals.iter().map(|n| [n.x, n.y, n.z]).collect(),
            table_offsets: table.offsets,
            table_entries: table.entries,
            mesh_positions: mesh.positions.iter().map(|p| [p.x, p.y, p.z]).collect(),
            mesh_faces: mesh.faces.clone(),
            symmetries_discrete: Vec::new(),
            symmetries_continuous: Vec::new(),
        };
        let bytes = rkyv::to_bytes::<rkyv::rancor::Error>(&data)
            .map_err(|e| Error::InvalidParameter(format!("{name}: cannot archive model: {e}")))?;
        let model = Self {
            backing: Backing::Owned(bytes),
            silhouette: Mutex::new(None),
        };
        Ok((model, report))
    }

    /// A model over an already validated archive in a private memory map (see [`crate::model::store`]).
    pub(crate) fn from_validated_map(map: Mmap, offset: usize) -> Self {
        Self {
            backing: Backing::Mapped { map, offset },
            silhouette: Mutex::new(None),
        }
    }

    /// The archived bytes (what a model file stores after its header).
    pub fn archive_bytes(&self) -> &[u8] {
        match &self.backing {
            Backing::Owned(v) => v.as_slice(),
            Backing::Mapped { map, offset } => &map[*offset..],
        }
    }

    /// The model's data, read in place.
    #[inline]
    pub fn data(&self) -> &ArchivedModelData {
        // SAFETY: an `Owned` buffer was produced by `rkyv::to_bytes` from a `ModelData`, and a
        // `Mapped` one passed `rkyv::access` validation in `store::load` before construction;
        // neither is mutated afterwards (the map is a private read-only copy, not the file).
        unsafe { rkyv::access_unchecked::<ArchivedModelData>(self.archive_bytes()) }
    }

    /// The object's id (BOP `obj_id` for dataset models).
    pub fn object_id(&self) -> u32 {
        self.data().object_id.to_native()
    }

    /// A human-readable name (file stem or part name).
    pub fn name(&self) -> &str {
        self.data().name.as_str()
    }

    /// `D`, mm.
    pub fn diameter_mm(&self) -> f32 {
        self.data().diameter_mm.to_native()
    }

    /// The parameters the model was built with.
    pub fn params(&self) -> ModelParams {
        rkyv::deserialize::<ModelParams, rkyv::rancor::Error>(&self.data().params)
            .expect("plain data deserialises")
    }

    /// [`Mesh::fingerprint`] of the mesh the model was built from.
    pub fn mesh_fingerprint(&self) -> u32 {
        self.data().mesh_fingerprint.to_native()
    }

    /// CRC-32 of the mesh file's bytes the model was built from (0: unknown).
    pub fn source_crc(&self) -> u32 {
        self.data().source_crc.to_native()
    }

    /// The same model, recording that its mesh was read from a file whose bytes have the CRC-32
    /// `crc` ([`crate::model::store::source_crc`]).
    pub fn with_source_crc(self, crc: u32) -> Result<Self> {
        Self::clone_with_source_crc(&self, crc)
    }

    /// A copy of `model` recording `crc` as its mesh file's CRC (see
    /// [`ObjectModel::with_source_crc`]).
    pub fn clone_with_source_crc(model: &ObjectModel, crc: u32) -> Result<Self> {
        let mut data = rkyv::deserialize::<ModelData, rkyv::rancor::Error>(model.data())
            .map_err(|e| Error::InvalidParameter(format!("cannot read the model back: {e}")))?;
        data.source_crc = crc;
        let bytes = rkyv::to_bytes::<rkyv::rancor::Error>(&data)
            .map_err(|e| Error::InvalidParameter(format!("cannot archive model: {e}")))?;
        Ok(Self {
            backing: Backing::Owned(bytes),
            silhouette: Mutex::new(None),
        })
    }

    /// The object's symmetries (none unless set with [`ObjectModel::with_symmetry`]).
    pub fn symmetry(&self) -> Symmetry {
        // Checked when the model was built or its file loaded.
        stored_symmetry(self.data()).unwrap_or_default()
    }

    /// A copy of the model recording `symmetry` as the object's (METHOD.md §1.8). Refuses a
    /// symmetry that fails [`Symmetry::validate`] or that the model's surface does not have
    /// ([`Symmetry::check_holds`]). The table is unchanged: symmetries act after voting.
    pub fn with_symmetry(&self, symmetry: &Symmetry) -> Result<Self> {
        let name = self.name().to_owned();
        let d = self.diameter_mm();
        let named = |e: Error| match e {
            Error::InvalidParameter(reason) => Error::InvalidParameter(format!("{name}: {reason}")),
            other => other,
        };
        symmetry.validate(d).map_err(named)?;
        symmetry
            .check_holds(&self.surface_points(), d)
            .map_err(named)?;
        let mut data = rkyv::deserialize::<ModelData, rkyv::rancor::Error>(self.data())
            .map_err(|e| Error::InvalidParameter(format!("cannot read the model back: {e}")))?;
        data.symmetries_discrete = symmetry.stored_discrete();
        data.symmetries_continuous = symmetry.stored_continuous();
        let bytes = rkyv::to_bytes::<rkyv::rancor::Error>(&data)
            .map_err(|e| Error::InvalidParameter(format!("cannot archive model: {e}")))?;
        Ok(Self {
            backing: Backing::Owned(bytes),
            silhouette: Mutex::new(None),
        })
    }

    /// Number of subsampled model points.
    pub fn point_count(&self) -> usize {
        self.data().points.len()
    }

    /// Number of lookup table entries (ordered pairs).
    pub fn table_entry_count(&self) -> usize {
        self.data().table_entries.len()
    }

    /// Size of the archive, bytes.
    pub fn byte_size(&self) -> usize {
        self.archive_bytes().len()
    }

    /// Whether the archive was read from a model file (into a private memory map) rather than
    /// built in memory.
    pub fn is_mapped(&self) -> bool {
        matches!(self.backing, Backing::Mapped { .. })
    }

    /// Model point `i`, mm.
    #[inline]
    pub fn point(&self, i: usize) -> Point3<f32> {
        point(&self.data().points[i])
    }

    /// Unit normal of model point `i`.
    #[inline]
    pub fn normal(&self, i: usize) -> Vector3<f32> {
        point(&self.data().normals[i]).coords
    }

    /// The subsampled oriented points, copied out.
    pub fn oriented_points(&self) -> OrientedPoints {
        let d = self.data();
        OrientedPoints {
            positions: d.points.iter().map(point).collect(),
            normals: d.normals.iter().map(|n| point(n).coords).collect(),
        }
    }

    /// The denser surface points used after voting, copied out.
    pub fn surface_points(&self) -> OrientedPoints {
        let d = self.data();
        OrientedPoints {
            positions: d.surface_points.iter().map(point).collect(),
            normals: d.surface_normals.iter().map(|n| point(n).coords).collect(),
        }
    }

    /// The mesh for rendering (normals are not needed by the renderer and are left empty).
    pub fn render_mesh(&self) -> Mesh {
        let d = self.data();
        Mesh {
            positions: d.mesh_positions.iter().map(point).collect(),
            normals: Vec::new(),
            faces: d
                .mesh_faces
                .iter()
                .map(|f| f.map(|i| i.to_native()))
                .collect(),
        }
    }

    /// The mesh with vertices merged on a grid of `cell_mm` ([`crate::geometry::simplify::simplified_mesh`])
    /// that silhouettes are rendered from; kept after the first call for the same cell.
    pub fn silhouette_mesh(&self, cell_mm: f32) -> Arc<Mesh> {
        let mut kept = self.silhouette.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((cell, mesh)) = &*kept {
            if cell.to_bits() == cell_mm.to_bits() {
                return mesh.clone();
            }
        }
        let mesh = Arc::new(crate::geometry::simplify::simplified_mesh(
            &self.render_mesh(),
            cell_mm,
        ));
        *kept = Some((cell_mm, mesh.clone()));
        mesh
    }

    /// The feature quantiser of this model.
    pub fn quantizer(&self) -> Quantizer {
        let p = &self.data().params;
        Quantizer::new(
            self.diameter_mm(),
            p.distance_bins.to_native(),
            p.angle_bins.to_native(),
        )
    }

    /// The lookup table, copied out (for tests and tools).
    pub fn table(&self) -> LookupTable {
        let d = self.data();
        LookupTable {
            offsets: d.table_offsets.iter().map(|v| v.to_native()).collect(),
            entries: d.table_entries.iter().map(|v| v.to_native()).collect(),
        }
    }
}

/// The lookup table of every ordered pair `(i, j)`, `i ≠ j`, of `points`: under the key of
/// `F(m_i, m_j)`, the entry `(i, α_m)`. Pairs farther apart than the quantiser's last distance
/// bin (possible only by rounding) go into that last bin.
fn build_table(points: &OrientedPoints, quantizer: &Quantizer) -> LookupTable {
    let n = points.len();
    let pairs: Vec<(u32, u32)> = (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let (pi, ni) = (points.positions[i], points.normals[i]);
            let frame = LocalFrame::new(&pi, &ni);
            (0..n).filter(move |&j| j != i).filter_map(move |j| {
                let (pj, nj) = (points.positions[j], points.normals[j]);
                let mut f = PointPairFeature::compute(&pi, &ni, &pj, &nj)?;
                let max = quantizer.distance_step_mm * quantizer.distance_bins as f32;
                f.distance_mm = f.distance_mm.min(max);
                let key = quantizer.key(&f)?;
                Some((key, pack_entry(i as u16, frame.alpha(&pj))))
            })
        })
        .collect();
    LookupTable::from_pairs(
        key_count(quantizer.distance_bins, quantizer.angle_bins),
        &pairs,
    )
}

/// The symmetry a model's data holds, read back from its archived form.
pub(crate) fn stored_symmetry(d: &ArchivedModelData) -> Result<Symmetry> {
    let discrete: Vec<[f32; 7]> = d
        .symmetries_discrete
        .iter()
        .map(|s| s.map(|v| v.to_native()))
        .collect();
    let continuous: Vec<[f32; 6]> = d
        .symmetries_continuous
        .iter()
        .map(|a| a.map(|v| v.to_native()))
        .collect();
    Symmetry::from_stored(&discrete, &continuous)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::table::{entry_alpha, entry_model_point};

    /// A closed box with split vertices per face (so normals are exact), for tests that must not
    /// depend on the mesh reader or the generated parts.
    pub(crate) fn box_mesh(sx: f32, sy: f32, sz: f32) -> Mesh {
        let mut m = Mesh::default();
        let h = Vector3::new(sx / 2.0, sy / 2.0, sz / 2.0);
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut n = Vector3::zeros();
                n[axis] = sign;
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let base = m.positions.len() as u32;
                for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let mut p = Vector3::zeros();
                    p[axis] = sign * h[axis];
                    p[u] = a * h[u];
                    p[v] = b * h[v];
                    m.positions.push(Point3::from(p));
                    m.normals.push(n);
                }
                if sign > 0.0 {
                    m.faces.push([base, base + 1, base + 2]);
                    m.faces.push([base, base + 2, base + 3]);
                } else {
                    m.faces.push([base, base + 2, base + 1]);
                    m.faces.push([base, base + 3, base + 2]);
                }
            }
        }
        m
    }

    #[test]
    fn the_silhouette_mesh_is_made_once_per_cell() {
        let model = ObjectModel::build(
            &box_mesh(50.0, 30.0, 20.0),
            1,
            "box",
            &ModelParams::default(),
        )
        .unwrap();
        let first = model.silhouette_mesh(4.0);
        let made = crate::geometry::simplify::simplified_mesh(&model.render_mesh(), 4.0);
        assert_eq!(first.positions, made.positions);
        assert_eq!(first.faces, made.faces);
        assert!(Arc::ptr_eq(&first, &model.silhouette_mesh(4.0)), "kept");
        let finer = model.silhouette_mesh(1.0);
        assert!(!Arc::ptr_eq(&first, &finer), "another cell, another mesh");
        assert_eq!(
            finer.faces,
            crate::geometry::simplify::simplified_mesh(&model.render_mesh(), 1.0).faces
        );
    }

    #[test]
    fn table_holds_every_ordered_pair_exactly_once() {
        let mesh = box_mesh(60.0, 40.0, 25.0);
        let model = ObjectModel::build(&mesh, 7, "box", &ModelParams::default()).unwrap();
        let n = model.point_count();
        assert!(n > 50, "{n} points");
        assert_eq!(model.table_entry_count(), n * (n - 1));
        let table = model.table();
        assert_eq!(table.offsets.len(), 67_501);
        assert_eq!(*table.offsets.last().unwrap() as usize, n * (n - 1));
        // Every (i, j) pair appears once: count entries per reference point i.
        let mut per_point = vec![0usize; n];
        for &e in &table.entries {
            per_point[entry_model_point(e) as usize] += 1;
        }
        assert!(per_point.iter().all(|&c| c == n - 1));
        // And each entry sits under the key of its own feature: re-derive one key's entries.
        let pts = model.oriented_points();
        let q = model.quantizer();
        let (i, j) = (3usize, n / 2);
        let f = PointPairFeature::compute(
            &pts.positions[i],
            &pts.normals[i],
            &pts.positions[j],
            &pts.normals[j],
        )
        .unwrap();
        let alpha = LocalFrame::new(&pts.positions[i], &pts.normals[i]).alpha(&pts.positions[j]);
        let under_key = table.get(q.key(&f).unwrap());
        assert!(under_key
            .iter()
            .any(|&e| entry_model_point(e) == i as u32 && (entry_alpha(e) - alpha).abs() < 1e-3));
    }

    #[test]
    fn diameter_and_metadata() {
        let mesh = box_mesh(60.0, 40.0, 25.0);
        let model = ObjectModel::build(&mesh, 7, "box", &ModelParams::default()).unwrap();
        let expected = (60f32 * 60.0 + 40.0 * 40.0 + 25.0 * 25.0).sqrt();
        assert!((model.diameter_mm() - expected).abs() < 1e-3);
        assert_eq!(model.object_id(), 7);
        assert_eq!(model.name(), "box");
        assert_eq!(model.params(), ModelParams::default());
        assert_eq!(model.mesh_fingerprint(), mesh.fingerprint());
        assert!(!model.is_mapped());
        // Corners keep three points (one per face), so the box keeps its edges densely.
        let pts = model.oriented_points();
        assert!(pts.normals.iter().all(|n| (n.norm() - 1.0).abs() < 1e-4));
    }

    #[test]
    fn bad_params_and_meshes_are_refused() {
        let mesh = box_mesh(10.0, 10.0, 10.0);
        let bad = ModelParams {
            alpha_bins: 40,
            ..Default::default()
        };
        assert!(matches!(
            ObjectModel::build(&mesh, 1, "b", &bad),
            Err(Error::InvalidParameter(m)) if m.contains("alpha_bins")
        ));
        let empty = Mesh::default();
        assert!(matches!(
            ObjectModel::build(&empty, 1, "e", &ModelParams::default()),
            Err(Error::InvalidMesh(_))
        ));
    }

    /// Faces that cover almost nothing of the extent their mesh's vertices claim give a
    /// handful of model points, and such a model is refused rather than built.
    #[test]
    fn a_mesh_whose_faces_cover_almost_nothing_of_its_extent_is_refused() {
        // A 1 mm tetrahedron, and the corners of a 100 mm cube as stray vertices with normals
        // (as a PLY may carry them) that no face uses.
        let mut mesh = Mesh::from_triangles(
            vec![
                Point3::new(50.0, 50.0, 50.0),
                Point3::new(51.0, 50.0, 50.0),
                Point3::new(50.0, 51.0, 50.0),
                Point3::new(50.0, 50.0, 51.0),
            ],
            &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
        .unwrap();
        for i in 0..8 {
            let c = |bit: u32| if i & (1 << bit) != 0 { 100.0 } else { 0.0 };
            let corner = Point3::new(c(0), c(1), c(2));
            mesh.positions.push(corner);
            mesh.normals
                .push((corner - Point3::new(50.0, 50.0, 50.0)).normalize());
        }
        let m = match ObjectModel::build(&mesh, 1, "speck", &ModelParams::default()) {
            Err(Error::InvalidMesh(m)) => m,
            other => panic!("{:?}", other.map(|m| m.point_count())),
        };
        assert!(
            m.contains("speck") && m.contains("model points after subsampling"),
            "{m}"
        );
        // The same tetrahedron at its own size builds.
        let alone = Mesh::from_triangles(
            vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(40.0, 0.0, 0.0),
                Point3::new(0.0, 40.0, 0.0),
                Point3::new(0.0, 0.0, 40.0),
            ],
            &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
        .unwrap();
        let model = ObjectModel::build(&alone, 1, "tetrahedron", &ModelParams::default()).unwrap();
        assert!(model.point_count() >= limits::MIN_MODEL_POINTS);
    }
}
