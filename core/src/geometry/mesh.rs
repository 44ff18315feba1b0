//! Triangle meshes: OBJ and PLY loading, validation and repair (docs/DESIGN.md section 6:
//! NaN/Inf never propagates silently; zero-area and sliver triangles and duplicate vertices
//! are first-class inputs).
//!
//! Every mesh enters the pipeline through one validation ([`Mesh::from_parts`], which
//! [`Mesh::load_obj`] shares after parsing with tobj, and [`Mesh::load_ply`] after its own
//! strict reader, `ply.rs`; [`Mesh::load`] picks one by extension), which
//!
//! * rejects what cannot be repaired with a [`CoreError::Input`] that says what and where:
//!   a non-finite position or uv (naming the vertex), a triangle index out of range (naming
//!   the triangle), and a mesh with no faces (left);
//! * repairs the rest, one human-readable line per kind of repair in [`MeshLoad::repairs`]:
//!   exactly duplicated vertices (same position and same uv bits) are welded, degenerate
//!   triangles (a repeated vertex, or area `<= 1e-12 * diagonal^2`: zero-area and slivers)
//!   are dropped, then unreferenced vertices are dropped and the rest renumbered in their
//!   original order;
//! * and, changing nothing, checks the winding ([`super::winding`]): when faces look reversed
//!   (wound against their edge-neighbours, or a closed part inside out) the last line of
//!   `repairs` says how many, in how many connected components, and what to do.
//!
//! Materials: [`Mesh::load_obj`] records each triangle's `usemtl` name (or, in a file without
//! `usemtl`, its `g`/`o` group name) in [`Mesh::materials`]; the `.mtl` library itself is
//! never read (the BTFs come from the experiment config). Faces before the first `usemtl`
//! are named [`MaterialIds::DEFAULT_NAME`]. Repairs keep every kept triangle's material.
//!
//! Why repair at all: degenerate triangles have no normal and no area, so they only add
//! noise to the area-weighted vertex normals and dead weight to the BVH; duplicated vertices
//! split the smooth normal of a surface into several frames (visible seams in `T`).

use super::{polygon, winding};
use crate::error::{CoreError, Result};
use glam::{DVec3, Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Triangles whose area is at most this fraction of the squared bounding-box diagonal are
/// dropped as degenerate (zero-area and slivers). 1e-12 is about the f32 rounding of a cross
/// product of two edges of diagonal length (`eps_f32^2 ~ 1.4e-14` times a few), i.e. the
/// area is indistinguishable from zero at f32 precision.
pub const DEGENERATE_AREA_FRACTION: f64 = 1e-12;

/// An indexed triangle mesh, +Y up, counter-clockwise triangles facing outward.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex texture coordinates, when the mesh has them (used for tangents).
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
    /// Which material each triangle uses, when the source names materials (OBJ `usemtl`, or
    /// OBJ groups when there is no `usemtl`). `None`: one material for the whole mesh.
    pub materials: Option<MaterialIds>,
}

/// Per-triangle material names, stored as indices into `names` (first-appearance order).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialIds {
    /// Distinct material names, in the order they first appear.
    pub names: Vec<String>,
    /// One index into `names` per triangle of the mesh.
    pub per_triangle: Vec<u16>,
}

impl MaterialIds {
    /// Name of the material used by faces that come before any `usemtl` (or outside any group).
    pub const DEFAULT_NAME: &'static str = "default";

    /// The index of `name`, appended to `names` when new; `None` when a new name would not fit
    /// a `u16` index (more than 65,536 names).
    pub fn intern(&mut self, name: &str) -> Option<u16> {
        match self.names.iter().position(|n| n == name) {
            Some(i) => Some(i as u16),
            None if self.names.len() > u16::MAX as usize => None,
            None => {
                self.names.push(name.to_string());
                Some((self.names.len() - 1) as u16)
            }
        }
    }

    /// Triangles per material name, in `names` order.
    pub fn counts(&self) -> Vec<usize> {
        let mut c = vec![0; self.names.len()];
        for &i in &self.per_triangle {
            if let Some(x) = c.get_mut(i as usize) {
                *x += 1;
            }
        }
        c
    }
}

/// A loaded (and possibly repaired) mesh with a human-readable line per repair made.
#[derive(Clone, Debug)]
pub struct MeshLoad {
    pub mesh: Mesh,
    /// One line per kind of repair, then, when faces look reversed, a warning about their
    /// winding (the faces are left as they are; see the module docs).
    pub repairs: Vec<String>,
}

/// What [`validate_and_repair`] found unrepairable, before it is turned into a message
/// (so that [`Mesh::load_obj`] can translate vertex numbers back to the OBJ file).
enum Issue {
    NonFinitePosition { vertex: usize, value: Vec3 },
    NonFiniteUv { vertex: usize, value: Vec2 },
    UvCount { uvs: usize, positions: usize },
    IndexOutOfRange { triangle: usize, index: u32, vertices: usize },
    NoFaces(String),
    Materials(String),
}

impl Issue {
    fn message(&self) -> String {
        match self {
            Issue::NonFinitePosition { vertex, value } => {
                format!("vertex {vertex} has a non-finite position {value}")
            }
            Issue::NonFiniteUv { vertex, value } => {
                format!("vertex {vertex} has a non-finite texture coordinate {value}")
            }
            Issue::UvCount { uvs, positions } => {
                format!("{uvs} texture coordinates for {positions} vertices (need one per vertex)")
            }
            Issue::IndexOutOfRange { triangle, index, vertices } => {
                format!("triangle {triangle} refers to vertex {index}, out of range (the mesh has {vertices} vertices)")
            }
            Issue::NoFaces(detail) => format!("no faces{detail}"),
            Issue::Materials(detail) => format!("bad material ids: {detail}"),
        }
    }
}

impl Mesh {
    /// Load a Wavefront OBJ file: all models merged into one mesh, faces triangulated
    /// (convex polygons as fans from their first corner, non-convex ones by ear clipping in
    /// their plane, with a line in `repairs`), one index per vertex (a vertex is a
    /// position/uv pair). UVs are kept when every vertex has them (otherwise dropped, with a
    /// line in `repairs`); normals and materials are ignored. Then validated and repaired as
    /// in [`Mesh::from_parts`].
    pub fn load_obj(path: &Path) -> Result<MeshLoad> {
        Self::parse_obj(&read_mesh_file(path)?, path)
    }

    /// Load a mesh file by its extension: `.obj` ([`Mesh::load_obj`]) or `.ply`
    /// ([`Mesh::load_ply`]), in any letter case.
    pub fn load(path: &Path) -> Result<MeshLoad> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Self::load_obj(path),
            "ply" => Self::load_ply(path),
            _ => Err(CoreError::Input {
                path: path.to_path_buf(),
                message: format!("unsupported mesh format '.{ext}' (expected .obj or .ply)"),
            }),
        }
    }

    /// Load a Stanford PLY file (ASCII or binary, either byte order): vertex positions and,
    /// when the vertices have them, texture coordinates; faces from the `vertex_indices` (or
    /// `vertex_index`) lists, triangulated as OBJ polygons are. Vertices keep their file
    /// order. Then validated and repaired as in [`Mesh::from_parts`]. The reader is strict
    /// (module `ply`): a bad file is an error naming it and the element, line or byte offset.
    pub fn load_ply(path: &Path) -> Result<MeshLoad> {
        Self::parse_ply(&read_mesh_file(path)?, path)
    }

    /// [`Mesh::load_ply`] on the bytes of a PLY file already in memory (`path` names it in
    /// errors).
    pub fn parse_ply(bytes: &[u8], path: &Path) -> Result<MeshLoad> {
        let input_err = |message: String| CoreError::Input { path: path.to_path_buf(), message };
        let ply = super::ply::parse(bytes).map_err(|m| input_err(format!("PLY: {m}")))?;
        let mut triangles = Vec::with_capacity(ply.arities.len());
        let (mut at, mut nonconvex_faces) = (0usize, 0usize);
        let mut corners: Vec<Vec3> = vec![];
        for &n in &ply.arities {
            let face = &ply.indices[at..at + n as usize];
            at += n as usize;
            corners.clear();
            corners.extend(face.iter().map(|&i| ply.positions[i as usize]));
            if polygon::triangulate(&corners, |[a, b, c]| triangles.push([face[a], face[b], face[c]])) {
                nonconvex_faces += 1;
            }
        }
        let mut repairs = Vec::new();
        if nonconvex_faces > 0 {
            repairs.push(format!(
                "triangulated {nonconvex_faces} non-convex polygon(s) by ear clipping (a fan would leave the polygon)"
            ));
        }
        let mut load = validate_and_repair(ply.positions, ply.uvs, triangles, None)
            .map_err(|issue| input_err(format!("PLY: {}", issue.message())))?;
        repairs.append(&mut load.repairs);
        load.repairs = repairs;
        Ok(load)
    }

    /// [`Mesh::load_obj`] on the bytes of an OBJ file already in memory (`path` names it in
    /// errors): the one parser, which the fuzzing suite drives without a file.
    pub fn parse_obj(bytes: &[u8], path: &Path) -> Result<MeshLoad> {
        let input_err = |message: String| CoreError::Input { path: path.to_path_buf(), message };
        let options =
            tobj::LoadOptions { triangulate: false, single_index: true, ignore_points: true, ignore_lines: true };
        // Material names, not material libraries: tobj only resolves `usemtl` names that a
        // loaded `.mtl` defines, so every `mtllib` (and one injected in front of the file)
        // is answered with a synthesized library holding exactly the names the file uses.
        // The `.mtl` files themselves are never opened.
        let text = String::from_utf8_lossy(bytes);
        let used_names = obj_usemtl_names(&text);
        let library: String = used_names.iter().map(|n| format!("newmtl {n}\n")).collect();
        let mut source = b"mtllib biscale-material-names\n".to_vec();
        source.extend_from_slice(bytes);
        if let Some((line, content, e)) = unresolvable_face_index(&text) {
            return Err(input_err(format!("OBJ parse error: {e} at line {line}: `{content}`")));
        }
        let (models, materials) =
            tobj::load_obj_buf(&mut source.as_slice(), &options, |_| tobj::load_mtl_buf(&mut library.as_bytes()))
                .map_err(|e| {
                    let place = match locate_obj_error(&text, &e) {
                        Some((line, content)) => format!(" at line {line}: `{content}`"),
                        None => String::new(),
                    };
                    input_err(format!("OBJ parse error: {e}{place}"))
                })?;
        let materials = materials.unwrap_or_default();
        let has_groups = text.lines().any(|l| matches!(l.split_whitespace().next(), Some("g" | "o")));

        let mut positions = Vec::new();
        let mut uvs = Vec::new();
        let mut triangles = Vec::new();
        let mut material_ids = MaterialIds::default();
        let mut vertices_with_uv = 0usize;
        let mut all_uvs = true;
        let mut nonconvex_faces = 0usize;
        // One face's global vertex ids and corners, reused from face to face.
        let (mut ids, mut corners): (Vec<u32>, Vec<Vec3>) = (vec![], vec![]);
        for model in &models {
            let m = &model.mesh;
            let base = positions.len() as u64;
            let count = m.positions.len() / 3;
            positions.extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
            if m.texcoords.len() == 2 * count {
                uvs.extend(m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], t[1])));
                vertices_with_uv += count;
            } else {
                // tobj only pushes texcoords for vertices that have one: partial coverage.
                all_uvs = false;
                vertices_with_uv += m.texcoords.len() / 2;
            }
            if base + count as u64 > u32::MAX as u64 + 1 {
                return Err(input_err("more than 2^32 vertices".into()));
            }
            let first_triangle = triangles.len();
            let (mut at, mut arities) = (0usize, m.face_arities.iter().map(|&a| a as usize));
            while at < m.indices.len() {
                // tobj leaves `face_arities` empty when every face is a triangle.
                let n = if m.face_arities.is_empty() { 3 } else { arities.next().unwrap_or(0) };
                let Some(face) = m.indices.get(at..at + n).filter(|_| n >= 3) else {
                    return Err(input_err(format!("a face with {n} vertices")));
                };
                at += n;
                ids.clear();
                ids.extend(face.iter().map(|&i| (base + i as u64) as u32));
                corners.clear();
                corners.extend(ids.iter().map(|&i| positions[i as usize]));
                if polygon::triangulate(&corners, |[a, b, c]| triangles.push([ids[a], ids[b], ids[c]])) {
                    nonconvex_faces += 1;
                }
            }
            let model_triangles = triangles.len() - first_triangle;
            // This model's material name: its `usemtl`, else (in a file without any) its group.
            let name = if !used_names.is_empty() {
                match m.material_id.and_then(|i| materials.get(i)) {
                    Some(mat) => mat.name.clone(),
                    None => MaterialIds::DEFAULT_NAME.to_string(),
                }
            } else if has_groups && !model.name.is_empty() && model.name != "unnamed_object" {
                model.name.clone()
            } else {
                MaterialIds::DEFAULT_NAME.to_string()
            };
            let Some(id) = material_ids.intern(&name) else {
                return Err(input_err(format!("more than {} distinct materials", u16::MAX as usize + 1)));
            };
            material_ids.per_triangle.extend(std::iter::repeat_n(id, model_triangles));
        }
        let material_ids = (!used_names.is_empty() || has_groups).then_some(material_ids);
        let mut repairs = Vec::new();
        if nonconvex_faces > 0 {
            repairs.push(format!(
                "triangulated {nonconvex_faces} non-convex polygon(s) by ear clipping (a fan would leave the polygon)"
            ));
        }
        let uvs = if all_uvs && !positions.is_empty() {
            Some(uvs)
        } else {
            if vertices_with_uv > 0 {
                repairs.push(format!(
                    "dropped texture coordinates: only {vertices_with_uv} of {} vertices have one",
                    positions.len()
                ));
            }
            None
        };
        match validate_and_repair(positions, uvs, triangles, material_ids) {
            Ok(mut load) => {
                repairs.append(&mut load.repairs);
                load.repairs = repairs;
                Ok(load)
            }
            Err(Issue::NonFinitePosition { vertex, value }) => {
                // tobj renumbers vertices (single index): name the OBJ's own `v` line.
                let place = match first_nonfinite_obj_vertex(&text) {
                    Some((number, line)) => format!("OBJ vertex {number} (line {line})"),
                    None => format!("vertex {vertex}"),
                };
                Err(input_err(format!("{place} has a non-finite position {value}")))
            }
            Err(issue) => Err(input_err(issue.message())),
        }
    }

    /// Build a mesh from arrays, validating and repairing as described in the module docs.
    /// `source` names the data in error messages (a file name, or e.g. "grid_plane").
    pub fn from_parts(
        positions: Vec<Vec3>,
        uvs: Option<Vec<Vec2>>,
        triangles: Vec<[u32; 3]>,
        source: &str,
    ) -> Result<MeshLoad> {
        Self::from_parts_with_materials(positions, uvs, triangles, None, source)
    }

    /// [`Mesh::from_parts`] with a material per triangle (validated: one id per triangle,
    /// each naming one of `materials.names`, names distinct and non-empty).
    pub fn from_parts_with_materials(
        positions: Vec<Vec3>,
        uvs: Option<Vec<Vec2>>,
        triangles: Vec<[u32; 3]>,
        materials: Option<MaterialIds>,
        source: &str,
    ) -> Result<MeshLoad> {
        validate_and_repair(positions, uvs, triangles, materials)
            .map_err(|issue| CoreError::Input { path: PathBuf::from(source), message: issue.message() })
    }

    /// Axis-aligned bounds `(min, max)` of the vertices; `(0, 0)` for an empty mesh.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        if self.positions.is_empty() {
            return (Vec3::ZERO, Vec3::ZERO);
        }
        self.positions
            .iter()
            .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
    }

    /// The mesh as OBJ text (`v`, optional `vt`, `usemtl` when it has materials, and 1-based
    /// `f` lines).
    pub fn to_obj(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        for p in &self.positions {
            let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
        }
        if let Some(uvs) = &self.uvs {
            for t in uvs {
                let _ = writeln!(s, "vt {} {}", t.x, t.y);
            }
        }
        let mut current = None;
        for (k, t) in self.triangles.iter().enumerate() {
            if let Some(m) = &self.materials {
                let id = m.per_triangle[k];
                if current != Some(id) {
                    let _ = writeln!(s, "usemtl {}", m.names[id as usize]);
                    current = Some(id);
                }
            }
            let [a, b, c] = t.map(|i| i + 1);
            if self.uvs.is_some() {
                let _ = writeln!(s, "f {a}/{a} {b}/{b} {c}/{c}");
            } else {
                let _ = writeln!(s, "f {a} {b} {c}");
            }
        }
        s
    }

    /// Length of the bounding box diagonal (the mesh's scale; 0 for an empty mesh).
    pub fn diagonal(&self) -> f32 {
        let (lo, hi) = self.bounds();
        // In f64: the squares overflow f32 for coordinates past about 1e19.
        (hi.as_dvec3() - lo.as_dvec3()).length() as f32
    }

    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }
}

/// The bytes of a mesh file (a regular file only: a device or FIFO is named as such), or an
/// input error naming it.
fn read_mesh_file(path: &Path) -> Result<Vec<u8>> {
    crate::io::read_regular(path, u64::MAX, "mesh").map_err(|e| CoreError::Input {
        path: path.to_path_buf(),
        message: match e.kind() {
            std::io::ErrorKind::NotFound => "file not found".to_string(),
            _ => format!("cannot read: {e}"),
        },
    })
}

/// Validation and the repairs of the module docs.
fn validate_and_repair(
    positions: Vec<Vec3>,
    uvs: Option<Vec<Vec2>>,
    triangles: Vec<[u32; 3]>,
    materials: Option<MaterialIds>,
) -> std::result::Result<MeshLoad, Issue> {
    let n = positions.len();
    if let Some(m) = &materials {
        if m.per_triangle.len() != triangles.len() {
            return Err(Issue::Materials(format!(
                "{} material ids for {} triangles",
                m.per_triangle.len(),
                triangles.len()
            )));
        }
        if let Some(t) = m.per_triangle.iter().position(|&i| i as usize >= m.names.len()) {
            return Err(Issue::Materials(format!(
                "triangle {t} uses material {} but only {} are named",
                m.per_triangle[t],
                m.names.len()
            )));
        }
        for (i, name) in m.names.iter().enumerate() {
            if name.trim().is_empty() || m.names[..i].contains(name) {
                return Err(Issue::Materials(format!("material name {name:?} is empty or repeated")));
            }
        }
    }
    // 1. Validation: what cannot be repaired.
    if let Some(uv) = &uvs {
        if uv.len() != n {
            return Err(Issue::UvCount { uvs: uv.len(), positions: n });
        }
    }
    if let Some(vertex) = positions.iter().position(|p| !p.is_finite()) {
        return Err(Issue::NonFinitePosition { vertex, value: positions[vertex] });
    }
    if let Some(uv) = &uvs {
        if let Some(vertex) = uv.iter().position(|t| !t.is_finite()) {
            return Err(Issue::NonFiniteUv { vertex, value: uv[vertex] });
        }
    }
    for (triangle, t) in triangles.iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&i| i as usize >= n) {
            return Err(Issue::IndexOutOfRange { triangle, index, vertices: n });
        }
    }
    if triangles.is_empty() {
        return Err(Issue::NoFaces(String::new()));
    }
    let mut repairs = Vec::new();

    // 2. Weld exactly duplicated vertices (bit-equal position and uv; -0.0 counts as 0.0).
    let key = |i: usize| {
        let bits = |x: f32| (x + 0.0).to_bits();
        let p = positions[i];
        let t = uvs.as_ref().map_or(Vec2::ZERO, |u| u[i]);
        [bits(p.x), bits(p.y), bits(p.z), bits(t.x), bits(t.y)]
    };
    let mut first_of: HashMap<[u32; 5], u32> = HashMap::with_capacity(n);
    let remap: Vec<u32> = (0..n).map(|i| *first_of.entry(key(i)).or_insert(i as u32)).collect();
    let welded = remap.iter().enumerate().filter(|(i, &r)| *i as u32 != r).count();
    if welded > 0 {
        repairs.push(format!("welded {welded} exactly duplicated vertices (same position and uv)"));
    }

    // 3. Drop degenerate triangles. The scale is the bounding box of the referenced vertices.
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in &triangles {
        for &i in t {
            let p = positions[i as usize].as_dvec3();
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let min_area = DEGENERATE_AREA_FRACTION * (hi - lo).length_squared();
    let (mut repeated, mut flat) = (0usize, 0usize);
    let mut kept_materials = materials.as_ref().map(|_| Vec::with_capacity(triangles.len()));
    let kept: Vec<[u32; 3]> = triangles
        .iter()
        .enumerate()
        .filter_map(|(k, t)| {
            let t = t.map(|i| remap[i as usize]);
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                repeated += 1;
                return None;
            }
            let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
            if 0.5 * (b - a).cross(c - a).length() <= min_area {
                flat += 1;
                return None;
            }
            if let (Some(out), Some(m)) = (&mut kept_materials, &materials) {
                out.push(m.per_triangle[k]);
            }
            Some(t)
        })
        .collect();
    if repeated + flat > 0 {
        repairs.push(format!(
            "dropped {} degenerate triangles ({repeated} with a repeated vertex, {flat} with area <= {DEGENERATE_AREA_FRACTION:e} x bbox diagonal^2)",
            repeated + flat
        ));
    }
    if kept.is_empty() {
        return Err(Issue::NoFaces(format!(
            " left: all {} triangles are degenerate ({repeated} with a repeated vertex, {flat} zero-area or sliver)",
            triangles.len()
        )));
    }

    // 4. Drop unreferenced vertices, renumber the rest in their original order.
    let mut new_index = vec![u32::MAX; n];
    for t in &kept {
        for &i in t {
            new_index[i as usize] = 0;
        }
    }
    let mut next = 0u32;
    let mut out_positions = Vec::with_capacity(n);
    let mut out_uvs = uvs.as_ref().map(|_| Vec::with_capacity(n));
    for i in 0..n {
        if new_index[i] == 0 {
            new_index[i] = next;
            next += 1;
            out_positions.push(positions[i]);
            if let (Some(out), Some(src)) = (&mut out_uvs, &uvs) {
                out.push(src[i]);
            }
        }
    }
    // Welded-away vertices are never referenced any more: count only the others.
    let unreferenced = n - welded - out_positions.len();
    if unreferenced > 0 {
        repairs.push(format!("dropped {unreferenced} unreferenced vertices"));
    }
    let triangles: Vec<[u32; 3]> = kept.into_iter().map(|t| t.map(|i| new_index[i as usize])).collect();
    // 5. Check the winding, change nothing (a line when faces look reversed).
    if let Some(w) = winding::warning(&out_positions, &triangles) {
        repairs.push(w);
    }
    let materials = match (materials, kept_materials) {
        (Some(m), Some(per_triangle)) => Some(MaterialIds { names: m.names, per_triangle }),
        _ => None,
    };
    Ok(MeshLoad { mesh: Mesh { positions: out_positions, uvs: out_uvs, triangles, materials }, repairs })
}

/// The distinct `usemtl` names of an OBJ text, in first-appearance order (parsed as tobj
/// does: everything after the keyword, trimmed).
fn obj_usemtl_names(text: &str) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.split_whitespace().next() == Some("usemtl") {
            let name = line.split_once(' ').map_or("", |x| x.1).trim();
            if !name.is_empty() && !names.iter().any(|n| n == name) {
                names.push(name.to_string());
            }
        }
    }
    names
}

/// The 1-based number and line of the first OBJ `v` record with a non-finite coordinate.
fn first_nonfinite_obj_vertex(text: &str) -> Option<(usize, usize)> {
    let mut number = 0;
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() == Some("v") {
            number += 1;
            if words.take(3).any(|w| w.parse::<f32>().is_ok_and(|x| !x.is_finite())) {
                return Some((number, line_no + 1));
            }
        }
    }
    None
}

/// The first face record (1-based line, its text, the error) with a texture-coordinate or
/// normal index that names no record: counting back past the first one read so far, or
/// beyond the last one in the file. tobj resolves such an index to a huge offset and
/// multiplies it unchecked (an overflow panic in builds with overflow checks), so these are
/// refused before it runs; positions it checks itself. tobj reads `l` (line) records with
/// the same face parser, and one of three or more corners becomes a polygon, so both kinds
/// are checked.
fn unresolvable_face_index(text: &str) -> Option<(usize, &str, tobj::LoadError)> {
    let count = |kind: &str| text.lines().filter(|l| l.split_whitespace().next() == Some(kind)).count() as i64;
    let (textures, normals) = (count("vt"), count("vn"));
    let (mut vt, mut vn) = (0i64, 0i64);
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("vt") => vt += 1,
            Some("vn") => vn += 1,
            Some("f" | "l") => {
                for word in words {
                    let mut parts = word.split('/').skip(1);
                    for (part, so_far, total, e) in [
                        (parts.next(), vt, textures, tobj::LoadError::FaceTexCoordOutOfBounds),
                        (parts.next(), vn, normals, tobj::LoadError::FaceNormalOutOfBounds),
                    ] {
                        // What does not parse is tobj's to report; 0 it reads as "none".
                        let Some(i) = part.and_then(|p| p.parse::<i64>().ok()) else { continue };
                        if i < -so_far || i > total {
                            return Some((line_no + 1, line.trim(), e));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    None
}

/// Best-effort location (1-based line, its text) of a tobj error, which itself carries none:
/// the first record of the kind the error names that fails the same check.
fn locate_obj_error(text: &str, err: &tobj::LoadError) -> Option<(usize, String)> {
    use tobj::LoadError as E;
    let floats = |words: std::str::SplitWhitespace<'_>, n: usize| {
        let ok: Vec<bool> = words.take(n).map(|w| w.parse::<f32>().is_ok()).collect();
        ok.len() == n && ok.iter().all(|&b| b)
    };
    let (mut v, mut vt) = (0i64, 0i64);
    for (line_no, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let bad = match words.next() {
            Some("v") => {
                v += 1;
                matches!(err, E::PositionParseError) && !floats(words, 3)
            }
            Some("vt") => {
                vt += 1;
                matches!(err, E::TexcoordParseError) && !floats(words, 1)
            }
            Some("vn") => matches!(err, E::NormalParseError) && !floats(words, 3),
            Some("f" | "l") => match err {
                E::FaceParseError | E::FaceVertexOutOfBounds | E::FaceTexCoordOutOfBounds => {
                    // Bad if unparsable, 0, or beyond the records read so far (OBJ
                    // indices are 1-based; negative ones count back from the last).
                    let check = |s: Option<&str>, count: i64| match s {
                        None | Some("") => false,
                        Some(s) => match s.parse::<i64>() {
                            Err(_) => true,
                            Ok(i) => i == 0 || i > count || -i > count,
                        },
                    };
                    let words: Vec<&str> = words.collect();
                    words.is_empty()
                        || words.iter().any(|w| {
                            let mut parts = w.split('/');
                            check(parts.next(), v)
                                || (matches!(err, E::FaceTexCoordOutOfBounds) && check(parts.next(), vt))
                        })
                }
                _ => false,
            },
            _ => false,
        };
        if bad {
            let mut content: String = line.trim().chars().take(80).collect();
            if content.len() < line.trim().len() {
                content.push_str("...");
            }
            return Some((line_no + 1, content));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh temp dir per test (tests run in parallel).
    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("biscale-mesh-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn write_obj(name: &str, text: &str) -> PathBuf {
        let path = temp_dir(name).join(format!("{name}.obj"));
        std::fs::write(&path, text).unwrap();
        path
    }

    fn load_err(name: &str, text: &str) -> String {
        let path = write_obj(name, text);
        match Mesh::load_obj(&path) {
            Ok(m) => panic!("{name}: expected an error, got {} triangles", m.mesh.triangle_count()),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains(&path.display().to_string()), "{name}: error must name the file: {msg}");
                assert!(matches!(e, CoreError::Input { .. }));
                msg
            }
        }
    }

    #[test]
    fn missing_file_is_an_input_error() {
        let path = temp_dir("missing").join("does_not_exist.obj");
        let e = Mesh::load_obj(&path).unwrap_err();
        assert!(matches!(&e, CoreError::Input { path: p, .. } if *p == path), "{e}");
        assert!(e.to_string().contains("not found"), "{e}");
    }

    #[test]
    fn parse_errors_say_what_and_where() {
        let msg = load_err("garbage", "v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n");
        assert!(msg.contains("position parse error") && msg.contains("line 3"), "{msg}");
        let msg = load_err("badface", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n");
        assert!(msg.contains("face parse error") && msg.contains("line 4"), "{msg}");
        // Binary junk is not UTF-8: tobj fails to read lines.
        let path = write_obj("binary", "");
        std::fs::write(&path, [0xffu8, 0xfe, 0x00, 0x9f, 0x80, 0x0a]).unwrap();
        assert!(Mesh::load_obj(&path).is_err());
    }

    #[test]
    fn texture_and_normal_indices_that_name_no_record_are_errors_not_overflows() {
        // Regression (fuzzing): tobj turned `-21` (counting back past the first of 3 texture
        // coordinates) into a huge offset and overflowed multiplying it.
        let head = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n";
        for (face, what) in [
            ("f 1/1 2/2 3/-21", "texcoord"),
            ("f 1/-4 2/2 3/3", "texcoord"),
            ("f 1/1 2/2 3/9223372036854775807", "texcoord"),
            ("f 1//1 2//1 3//-2", "normal"),
            ("f 1//1 2//1 3//6148914691236517205", "normal"),
            // Regression (fuzzing): an `l` record goes through tobj's face parser too.
            ("l 1//1 2//1 3//-9", "normal"),
            ("l 1/-7 2/1", "texcoord"),
        ] {
            let msg = load_err("index", &format!("{head}{face}\n"));
            assert!(msg.contains(what) && msg.contains(&format!("line 8: `{face}`")), "{face}: {msg}");
        }
        // Counting back to the first record, and 0 (tobj's "no index"), still load.
        let path = write_obj("index_ok", &format!("{head}f 1/-3/-1 2/-2/-1 3/-1/1\nf 1/0 2/0 3/0\n"));
        assert_eq!(Mesh::load_obj(&path).unwrap().mesh.triangle_count(), 2);
    }

    #[test]
    fn out_of_range_index_names_the_line() {
        let msg = load_err("range", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 7\n");
        assert!(msg.contains("out of bounds") && msg.contains("line 5"), "{msg}");
        let e = Mesh::from_parts(vec![Vec3::ZERO, Vec3::X, Vec3::Y], None, vec![[0, 1, 2], [0, 1, 3]], "parts")
            .unwrap_err()
            .to_string();
        assert!(e.contains("triangle 1") && e.contains("vertex 3") && e.starts_with("parts:"), "{e}");
    }

    #[test]
    fn no_faces_is_an_error() {
        let msg = load_err("nofaces", "# only vertices\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
        assert!(msg.contains("no faces"), "{msg}");
        let msg = load_err("empty", "");
        assert!(msg.contains("no faces"), "{msg}");
        // Only degenerate faces: nothing left after repair.
        let msg = load_err("alldegenerate", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n");
        assert!(msg.contains("no faces left") && msg.contains("1 with a repeated vertex, 1 zero-area"), "{msg}");
    }

    #[test]
    fn non_finite_vertex_is_named() {
        let msg = load_err("nan", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 nan 1\nf 1 2 3\nf 2 3 4\n");
        assert!(msg.contains("OBJ vertex 4 (line 4)") && msg.contains("non-finite"), "{msg}");
        let msg = load_err("inf", "v 0 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n");
        assert!(msg.contains("OBJ vertex 2 (line 2)"), "{msg}");
        let e = Mesh::from_parts(vec![Vec3::ZERO, Vec3::X, Vec3::new(0.0, f32::NAN, 0.0)], None, vec![[0, 1, 2]], "p")
            .unwrap_err()
            .to_string();
        assert!(e.contains("vertex 2 has a non-finite position"), "{e}");
        let e = Mesh::from_parts(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            Some(vec![Vec2::ZERO, Vec2::new(f32::INFINITY, 0.0), Vec2::ONE]),
            vec![[0, 1, 2]],
            "p",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("vertex 1 has a non-finite texture coordinate"), "{e}");
    }

    #[test]
    fn repairs_degenerate_duplicate_and_unreferenced() {
        // A unit quad (4 vertices, 2 triangles) plus:
        // v5 = exact duplicate of v3, used by the second triangle instead of v3 (welded);
        // v6 = unreferenced; v7 = on the segment v1-v2 (zero-area triangle 1 2 7);
        // v8 a hair off v1-v2 (sliver, area 5e-14 < 1e-12 * 2 = 2e-12);
        // face 1 1 2 (repeated index); face 3 4 5 becomes 3 4 3 after welding (repeated).
        let text = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 1 0 1\nv 9 9 9\nv 0.5 0 0\nv 0.5 1e-13 0\n\
                    f 1 4 3\nf 1 5 2\nf 1 2 7\nf 1 2 8\nf 1 1 2\nf 3 4 5\n";
        let path = write_obj("repair", text);
        let load = Mesh::load_obj(&path).unwrap();
        let m = &load.mesh;
        assert_eq!(m.triangle_count(), 2, "{:?}", load.repairs);
        assert_eq!(m.vertex_count(), 4, "{:?}", load.repairs);
        assert_eq!(
            load.repairs,
            vec![
                "welded 1 exactly duplicated vertices (same position and uv)".to_string(),
                "dropped 4 degenerate triangles (2 with a repeated vertex, 2 with area <= 1e-12 x bbox diagonal^2)"
                    .to_string(),
                // tobj already leaves out vertex 6 (never referenced by a face); v7 and v8 were
                // referenced only by dropped triangles.
                "dropped 2 unreferenced vertices".to_string(),
            ]
        );
        // The quad is intact: positions in original order, both triangles facing +Y.
        assert_eq!(m.positions, vec![Vec3::ZERO, Vec3::Z, Vec3::new(1.0, 0.0, 1.0), Vec3::X]);
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            assert!((b - a).cross(c - a).y > 0.0);
        }
    }

    #[test]
    fn from_parts_counts_every_repair() {
        // Same position but different uvs is a seam, not a duplicate.
        let p =
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X, Vec3::Y, Vec3::new(5.0, 5.0, 5.0), Vec3::new(-0.0, 0.0, 0.0)];
        let uv = vec![Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::X, Vec2::ONE, Vec2::ZERO, Vec2::ZERO];
        let tris = vec![[0, 1, 2], [6, 3, 4], [0, 3, 1]];
        let load = Mesh::from_parts(p, Some(uv), tris, "parts").unwrap();
        // v3 = v1 (same uv) and v6 = v0 (-0.0 == 0.0) are welded; v4 is a seam copy of v2.
        // Triangle [0,3,1] becomes [0,1,1]: dropped. v5 is unreferenced.
        assert_eq!(load.mesh.triangles, vec![[0, 1, 2], [0, 1, 3]]);
        assert_eq!(load.mesh.vertex_count(), 4);
        assert_eq!(load.mesh.uvs.as_ref().unwrap()[3], Vec2::ONE);
        assert_eq!(load.repairs.len(), 3, "{:?}", load.repairs);
        assert!(load.repairs[0].starts_with("welded 2 "), "{:?}", load.repairs);
        assert!(load.repairs[1].starts_with("dropped 1 degenerate triangles (1 with a repeated vertex, 0 "));
        assert_eq!(load.repairs[2], "dropped 1 unreferenced vertices");
        // A clean mesh passes through unchanged.
        let clean = crate::geometry::shapes::grid_plane(3, 2.0);
        let load =
            Mesh::from_parts(clean.positions.clone(), clean.uvs.clone(), clean.triangles.clone(), "grid").unwrap();
        assert!(load.repairs.is_empty());
        assert_eq!(load.mesh, clean);
    }

    #[test]
    fn partial_uvs_are_dropped_with_a_note() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\nf 2 4 3\n";
        let load = Mesh::load_obj(&write_obj("partialuv", text)).unwrap();
        assert!(load.mesh.uvs.is_none());
        // tobj made 6 vertices (1/1, 2/2, 3/3, 2, 4, 3); without uvs, "2" and "3" are exact
        // duplicates of "2/2" and "3/3" and get welded.
        assert_eq!(
            load.repairs,
            vec![
                "dropped texture coordinates: only 3 of 6 vertices have one".to_string(),
                "welded 2 exactly duplicated vertices (same position and uv)".to_string()
            ]
        );
        assert_eq!(load.mesh.vertex_count(), 4);
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";
        let load = Mesh::load_obj(&write_obj("fulluv", text)).unwrap();
        assert_eq!(load.mesh.uvs, Some(vec![Vec2::ZERO, Vec2::X, Vec2::Y]));
    }

    #[test]
    fn quads_and_multiple_objects_are_merged() {
        let text = "o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no b\nv 0 0 2\nv 1 0 2\nv 0 1 2\nf 5 6 7\n";
        let load = Mesh::load_obj(&write_obj("merge", text)).unwrap();
        assert_eq!(load.mesh.triangle_count(), 3);
        assert_eq!(load.mesh.vertex_count(), 7);
        assert!(load.repairs.is_empty());
        assert!(load.mesh.triangles.iter().flatten().all(|&i| i < 7));
    }

    #[test]
    fn a_non_convex_polygon_loads_as_triangles_inside_it() {
        // Regression (hostile input): the fan of this chevron from its first corner made a
        // triangle outside the polygon with reversed winding, silently.
        let text = "v 0 0 0\nv 4 0 0\nv 4 3 0\nv 2 1 0\nv 0 3 0\nf 1 2 3 4 5\n";
        let load = Mesh::load_obj(&write_obj("chevron", text)).unwrap();
        assert_eq!(load.mesh.triangle_count(), 3);
        assert!(load.repairs.iter().any(|r| r.contains("1 non-convex polygon")), "{:?}", load.repairs);
        let mut area = 0.0;
        for t in &load.mesh.triangles {
            let [a, b, c] = t.map(|i| load.mesh.positions[i as usize]);
            let z = (b - a).cross(c - a).z;
            assert!(z > 0.0, "triangle {t:?} wound against the face");
            area += z / 2.0;
        }
        assert!((area - 8.0).abs() < 1e-5, "covered {area} of the polygon's 8");
    }

    #[test]
    fn a_partly_inside_out_mesh_loads_unchanged_with_a_winding_warning() {
        // Regression (issue 36): with 40% of a closed sphere's faces reversed, 37% of the
        // vertices rendered black and nothing was said. Now the load says so, and changes
        // nothing (no face is flipped).
        let sphere = crate::geometry::shapes::uv_sphere(Vec3::ZERO, 1.0, 12, 16);
        let mut bad = sphere.clone();
        let n = bad.triangles.len();
        for (i, t) in bad.triangles.iter_mut().enumerate() {
            // 40%, scattered (7919 is prime: i -> 7919 i mod n is a permutation).
            if (i * 7919) % n < 2 * n / 5 {
                t.swap(1, 2);
            }
        }
        let reversed = bad.triangles.iter().zip(&sphere.triangles).filter(|(a, b)| a != b).count();
        assert_eq!(reversed, 2 * n / 5);
        let load = Mesh::from_parts(bad.positions.clone(), None, bad.triangles.clone(), "sphere").unwrap();
        assert_eq!(load.mesh, bad, "the mesh is left as it came");
        assert_eq!(load.repairs.len(), 1, "{:?}", load.repairs);
        let line = &load.repairs[0];
        assert!(line.starts_with(&format!("{reversed} of {n} faces (")) && line.contains("look reversed"), "{line}");
        assert!(line.contains("in 1 of 1 connected components") && line.contains("re-orient"), "{line}");
        // Through an OBJ file too, and nothing for the sphere as it is.
        let back = Mesh::load_obj(&write_obj("partly-inside-out", &bad.to_obj())).unwrap();
        assert_eq!(back.repairs, load.repairs);
        // (The OBJ loader numbers vertices in order of first use: compare corners.)
        let corners =
            |m: &Mesh| -> Vec<[Vec3; 3]> { m.triangles.iter().map(|t| t.map(|i| m.positions[i as usize])).collect() };
        assert_eq!(corners(&back.mesh), corners(&bad));
        let good = Mesh::from_parts(sphere.positions.clone(), None, sphere.triangles.clone(), "sphere").unwrap();
        assert!(good.repairs.is_empty(), "{:?}", good.repairs);
    }

    fn asset(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/meshes").join(name)
    }

    #[test]
    fn loads_the_bunny_unchanged() {
        let load = Mesh::load_obj(&asset("bunny.obj")).unwrap();
        // Counts and bounds from assets/SOURCES.md.
        assert_eq!((load.mesh.vertex_count(), load.mesh.triangle_count()), (1839, 3674));
        assert!(load.repairs.is_empty(), "{:?}", load.repairs);
        assert!(load.mesh.uvs.is_none());
        let (lo, hi) = load.mesh.bounds();
        assert!((lo - Vec3::new(-4.958, -0.003, -3.730)).abs().max_element() < 1e-3, "{lo}");
        assert!((hi - Vec3::new(4.949, 9.655, 3.811)).abs().max_element() < 1e-3, "{hi}");
        assert!((load.mesh.diagonal() - (hi - lo).length()).abs() < 1e-6);
    }

    #[test]
    fn loads_the_teapot() {
        let load = Mesh::load_obj(&asset("teapot.obj")).unwrap();
        assert_eq!((load.mesh.vertex_count(), load.mesh.triangle_count()), (1177, 2256), "{:?}", load.repairs);
        let (lo, hi) = load.mesh.bounds();
        assert!((lo - Vec3::new(-3.0, 0.0, -2.0)).abs().max_element() < 1e-3, "{lo}");
        assert!((hi - Vec3::new(3.430, 3.15, 2.0)).abs().max_element() < 1e-3, "{hi}");
    }

    #[test]
    fn obj_text_round_trips() {
        let plane = crate::geometry::shapes::grid_plane(3, 2.0);
        let sphere = crate::geometry::shapes::uv_sphere(Vec3::ONE, 0.5, 6, 8);
        for (name, mesh) in [("plane", plane), ("sphere", sphere)] {
            let path = write_obj(&format!("rt-{name}"), &mesh.to_obj());
            let back = Mesh::load_obj(&path).unwrap();
            assert!(back.repairs.is_empty(), "{:?}", back.repairs);
            // The loader renumbers vertices in order of first use: compare the triangles'
            // corners (positions exactly: Rust prints the shortest round-tripping float).
            let corners = |m: &Mesh| -> Vec<[(Vec3, Option<glam::Vec2>); 3]> {
                m.triangles
                    .iter()
                    .map(|t| t.map(|i| (m.positions[i as usize], m.uvs.as_ref().map(|u| u[i as usize]))))
                    .collect()
            };
            assert_eq!(corners(&back.mesh), corners(&mesh), "{name}");
            assert_eq!(back.mesh.vertex_count(), mesh.vertex_count(), "{name}");
        }
    }

    const TWO_QUADS: &str = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 2 0 0\nv 2 0 1\n";

    #[test]
    fn usemtl_names_each_triangle() {
        // Faces before the first usemtl are "default"; a name used twice is one material;
        // an mtllib that does not exist is never opened.
        let text = format!(
            "mtllib missing.mtl\n{TWO_QUADS}f 1 2 3\nusemtl stone\nf 1 3 4\nusemtl gold leaf\nf 2 5 6\nf 2 6 3\nusemtl stone\nf 4 3 5\n"
        );
        let load = Mesh::load_obj(&write_obj("usemtl", &text)).unwrap();
        let m = load.mesh.materials.expect("materials recorded");
        assert_eq!(m.names, ["default", "stone", "gold leaf"]);
        assert_eq!(m.per_triangle, [0, 1, 2, 2, 1]);
        assert_eq!(m.counts(), [1, 2, 2]);
    }

    #[test]
    fn groups_name_materials_when_there_is_no_usemtl() {
        let text = format!("{TWO_QUADS}g roof\nf 1 2 3\nf 1 3 4\ng steps\nf 2 5 6\n");
        let m = Mesh::load_obj(&write_obj("groups", &text)).unwrap().mesh.materials.unwrap();
        assert_eq!(m.names, ["roof", "steps"]);
        assert_eq!(m.per_triangle, [0, 0, 1]);
        // No usemtl and no groups: one material, no ids.
        let plain = Mesh::load_obj(&write_obj("plain", &format!("{TWO_QUADS}f 1 2 3\n"))).unwrap();
        assert!(plain.mesh.materials.is_none());
    }

    #[test]
    fn repairs_keep_each_triangles_material() {
        // The degenerate second face is dropped; the survivors keep their own materials.
        let text = format!("{TWO_QUADS}usemtl a\nf 1 2 3\nusemtl b\nf 1 1 3\nusemtl c\nf 2 5 6\n");
        let load = Mesh::load_obj(&write_obj("repair-mat", &text)).unwrap();
        let m = load.mesh.materials.clone().unwrap();
        assert_eq!(load.mesh.triangle_count(), 2);
        assert_eq!(m.per_triangle.iter().map(|&i| m.names[i as usize].as_str()).collect::<Vec<_>>(), ["a", "c"]);
    }

    #[test]
    fn materials_round_trip_through_obj_and_subdivision() {
        use crate::geometry::shapes;
        let a = shapes::with_material(shapes::grid_plane(2, 1.0), "floor");
        let b = shapes::with_material(shapes::uv_sphere(Vec3::Y, 0.5, 4, 6), "ball");
        let mesh = shapes::merged(&[a, shapes::grid_plane(1, 3.0), b]);
        let m = mesh.materials.clone().unwrap();
        assert_eq!(m.names, ["floor", MaterialIds::DEFAULT_NAME, "ball"]);
        assert_eq!(m.counts(), [8, 2, mesh.triangle_count() - 10]);
        let back = Mesh::load_obj(&write_obj("rt-mat", &mesh.to_obj())).unwrap().mesh;
        assert_eq!(back.materials, mesh.materials);
        let fine = shapes::subdivide_midpoint(&mesh);
        let fm = fine.materials.unwrap();
        assert_eq!(fm.counts(), m.counts().iter().map(|c| 4 * c).collect::<Vec<_>>());
    }

    #[test]
    fn bad_material_ids_are_rejected() {
        let tri = vec![[0, 1, 2]];
        let pos = vec![Vec3::ZERO, Vec3::X, Vec3::Z];
        let bad = |m: MaterialIds| {
            Mesh::from_parts_with_materials(pos.clone(), None, tri.clone(), Some(m), "t").unwrap_err().to_string()
        };
        assert!(bad(MaterialIds { names: vec!["a".into()], per_triangle: vec![] })
            .contains("0 material ids for 1 triangles"));
        assert!(bad(MaterialIds { names: vec!["a".into()], per_triangle: vec![1] }).contains("uses material 1"));
        assert!(bad(MaterialIds { names: vec!["a".into(), "a".into()], per_triangle: vec![0] }).contains("repeated"));
    }
}
