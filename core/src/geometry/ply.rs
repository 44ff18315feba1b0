//! Stanford PLY meshes: a strict reader of the polygon file format, ASCII and binary (little
//! and big endian), behind [`super::Mesh::load_ply`].
//!
//! It keeps what a mesh needs: the `vertex` element's `x y z` and texture coordinates (`u v`,
//! `s t`, `texture_u texture_v` or `texture_s texture_t`), and the `face` element's index
//! list (`vertex_indices` or `vertex_index`). Other properties (normals: biscale computes its
//! own from the faces, as for OBJ; colours; per-face texture coordinates) and other elements
//! are read past.
//!
//! Strict, because a PLY header is a promise about the bytes after it: every declared count
//! is checked against the bytes that follow before anything is allocated (a lying header is
//! an error, never a huge allocation), every value against its declared type, and a short
//! file, a value that does not parse, an index out of range or data left after the last
//! element is an error that names the element, its number and the line (ASCII: one element
//! per line) or byte offset (binary).

use glam::{Vec2, Vec3};

/// Longest header read, in bytes (real headers are a few hundred).
const MAX_HEADER_BYTES: usize = 1 << 16;

/// The texture coordinate property pairs understood, in order of preference.
const UV_NAMES: [(&str, &str); 4] = [("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t")];

/// What a PLY file holds for a mesh: vertices (file order) and polygons.
#[derive(Debug)]
pub(super) struct PlyMesh {
    pub positions: Vec<Vec3>,
    pub uvs: Option<Vec<Vec2>>,
    /// Every face's vertex indices, one face after another.
    pub indices: Vec<u32>,
    /// Corners of each face (at least 3), in file order.
    pub arities: Vec<u32>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn name(self) -> &'static str {
        ["char", "uchar", "short", "ushort", "int", "uint", "float", "double"][self as usize]
    }

    /// The range of an integer type; `None` for the float types.
    fn int_range(self) -> Option<(i64, i64)> {
        Some(match self {
            Self::I8 => (i8::MIN as i64, i8::MAX as i64),
            Self::U8 => (0, u8::MAX as i64),
            Self::I16 => (i16::MIN as i64, i16::MAX as i64),
            Self::U16 => (0, u16::MAX as i64),
            Self::I32 => (i32::MIN as i64, i32::MAX as i64),
            Self::U32 => (0, u32::MAX as i64),
            Self::F32 | Self::F64 => return None,
        })
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    /// Header line of the `element` keyword.
    line: usize,
}

impl Element {
    fn property(&self, name: &str) -> Option<usize> {
        self.properties.iter().position(|p| p.name == name)
    }

    /// The fewest bytes one instance can take: binary, its scalars and list counts (empty
    /// lists); ASCII, one character and one separator per value.
    fn min_bytes(&self, format: Format) -> u64 {
        match format {
            Format::Ascii => 2 * self.properties.len() as u64,
            _ => self
                .properties
                .iter()
                .map(|p| match p.kind {
                    Kind::Scalar(t) | Kind::List { count: t, .. } => t.size() as u64,
                })
                .sum(),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    Little,
    Big,
}

/// Parse a PLY file's bytes; the error is a message saying what and where (the caller adds
/// the file name).
pub(super) fn parse(bytes: &[u8]) -> Result<PlyMesh, String> {
    let (format, elements, data_start, header_lines) = header(bytes)?;
    let data_len = (bytes.len() - data_start) as u64;

    // Every count against the bytes present, before any allocation.
    let mut need = 0u128;
    for el in &elements {
        if el.properties.is_empty() {
            return Err(format!("header line {}: element `{}` has no properties", el.line, el.name));
        }
        need += el.count as u128 * el.min_bytes(format) as u128;
        // An ASCII file may end without a newline after its last value.
        if need > data_len as u128 + 1 {
            return Err(format!(
                "header line {}: declares {} `{}` elements, which need at least {need} bytes with those before \
                 them, but only {data_len} bytes follow the header (a truncated file or a lying count)",
                el.line, el.count, el.name
            ));
        }
    }

    let vertex_el = elements.iter().position(|e| e.name == "vertex").ok_or("no `vertex` element")?;
    let face_el = elements.iter().position(|e| e.name == "face").ok_or("no `face` element: no faces")?;
    let vertices = &elements[vertex_el];
    if vertices.count > u32::MAX as u64 + 1 {
        return Err(format!("header line {}: more than 2^32 vertices ({})", vertices.line, vertices.count));
    }
    let scalar_at = |name: &str| -> Result<Option<usize>, String> {
        match vertices.property(name) {
            None => Ok(None),
            Some(i) => match vertices.properties[i].kind {
                Kind::Scalar(_) => Ok(Some(i)),
                Kind::List { .. } => {
                    Err(format!("header line {}: vertex property `{name}` is a list, expected a number", vertices.line))
                }
            },
        }
    };
    let mut xyz = [0usize; 3];
    for (slot, name) in xyz.iter_mut().zip(["x", "y", "z"]) {
        *slot = scalar_at(name)?
            .ok_or_else(|| format!("header line {}: the `vertex` element has no `{name}` property", vertices.line))?;
    }
    let mut uv_at = None;
    for (u, v) in UV_NAMES {
        match (scalar_at(u)?, scalar_at(v)?) {
            (Some(a), Some(b)) => {
                uv_at = Some([a, b]);
                break;
            }
            (None, None) => {}
            _ => {
                return Err(format!(
                    "header line {}: the `vertex` element has only one of the texture coordinates `{u}` and `{v}`",
                    vertices.line
                ))
            }
        }
    }
    let faces = &elements[face_el];
    let list = match (faces.property("vertex_indices"), faces.property("vertex_index")) {
        (Some(i), None) | (None, Some(i)) => i,
        (Some(_), Some(_)) => {
            return Err(format!(
                "header line {}: the `face` element has both `vertex_indices` and `vertex_index`",
                faces.line
            ))
        }
        (None, None) => {
            return Err(format!(
                "header line {}: the `face` element has no `vertex_indices` (or `vertex_index`) list",
                faces.line
            ))
        }
    };
    match faces.properties[list].kind {
        Kind::List { item, .. } if item.int_range().is_some() => {}
        Kind::List { item, .. } => {
            return Err(format!(
                "header line {}: face indices `{}` are {}, expected an integer type",
                faces.line,
                faces.properties[list].name,
                item.name()
            ))
        }
        Kind::Scalar(_) => {
            return Err(format!(
                "header line {}: face property `{}` is not a list",
                faces.line, faces.properties[list].name
            ))
        }
    }

    let vertex_count = vertices.count as usize;
    let mut positions = Vec::with_capacity(vertex_count);
    let mut uvs = uv_at.map(|_| Vec::with_capacity(vertex_count));
    let mut indices = Vec::new();
    let mut arities = Vec::with_capacity(faces.count as usize);
    let mut cursor = Cursor::new(bytes, data_start, header_lines, format);
    let mut values = Vec::new();
    for (e, el) in elements.iter().enumerate() {
        for i in 0..el.count {
            let at = |what: String, cursor: &Cursor<'_>| format!("{} {i} ({}): {what}", el.name, cursor.place());
            cursor.begin().map_err(|m| at(m, &cursor))?;
            values.clear();
            for (k, p) in el.properties.iter().enumerate() {
                match p.kind {
                    Kind::Scalar(t) => {
                        let v = cursor.value(t).map_err(|m| at(format!("property `{}`: {m}", p.name), &cursor))?;
                        values.push(v);
                    }
                    Kind::List { count, item } => {
                        let n = cursor.value(count).map_err(|m| at(format!("list `{}`: {m}", p.name), &cursor))?;
                        if n < 0.0 {
                            return Err(at(format!("list `{}` has a negative length {n}", p.name), &cursor));
                        }
                        let n = n as u64;
                        // A binary list's items must all be in the file before any is read.
                        if let Some(left) = cursor.bytes_left() {
                            if n * item.size() as u64 > left as u64 {
                                return Err(at(
                                    format!(
                                        "list `{}` of {n} {}s needs {} bytes, only {left} are left",
                                        p.name,
                                        item.name(),
                                        n * item.size() as u64
                                    ),
                                    &cursor,
                                ));
                            }
                        }
                        let is_face = e == face_el && k == list;
                        if is_face && n < 3 {
                            return Err(at(format!("a face with {n} vertices (at least 3)"), &cursor));
                        }
                        for _ in 0..n {
                            let v = cursor.value(item).map_err(|m| at(format!("list `{}`: {m}", p.name), &cursor))?;
                            if is_face {
                                if v < 0.0 || v >= vertex_count as f64 {
                                    return Err(at(
                                        format!("vertex index {v} out of range (the file has {vertex_count} vertices)"),
                                        &cursor,
                                    ));
                                }
                                indices.push(v as u32);
                            }
                        }
                        if is_face {
                            arities.push(n as u32);
                        }
                        values.push(f64::NAN);
                    }
                }
            }
            cursor.end().map_err(|m| at(m, &cursor))?;
            if e == vertex_el {
                let p = Vec3::from_array(xyz.map(|k| values[k] as f32));
                if !p.is_finite() {
                    return Err(at(format!("non-finite position {p}"), &cursor));
                }
                positions.push(p);
                if let (Some(out), Some([a, b])) = (&mut uvs, uv_at) {
                    let t = Vec2::new(values[a] as f32, values[b] as f32);
                    if !t.is_finite() {
                        return Err(at(format!("non-finite texture coordinate {t}"), &cursor));
                    }
                    out.push(t);
                }
            }
        }
    }
    cursor.finish()?;
    Ok(PlyMesh { positions, uvs, indices, arities })
}

/// The header: format, elements, the byte offset where the data starts and the number of
/// header lines.
fn header(bytes: &[u8]) -> Result<(Format, Vec<Element>, usize, usize), String> {
    if !(bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n")) {
        return Err("not a PLY file: the first line must be `ply`".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut at = 0usize;
    let mut line_no = 0usize;
    loop {
        if at >= bytes.len() || at > MAX_HEADER_BYTES {
            return Err(format!("no `end_header` line in the first {} bytes", at.min(bytes.len())));
        }
        let end = bytes[at..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |i| at + i);
        line_no += 1;
        let line = std::str::from_utf8(&bytes[at..end])
            .map_err(|_| format!("header line {line_no}: not ASCII text"))?
            .trim_end_matches('\r');
        at = (end + 1).min(bytes.len());
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        let bad = |what: &str| format!("header line {line_no}: {what}: `{line}`");
        match words.as_slice() {
            ["ply"] if line_no == 1 => {}
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, version] => {
                if format.is_some() {
                    return Err(bad("a second `format` line"));
                }
                format = Some(match *kind {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    _ => return Err(bad("unknown format (ascii, binary_little_endian or binary_big_endian)")),
                });
                if *version != "1.0" {
                    return Err(bad("unsupported version (1.0)"));
                }
            }
            ["element", name, count] => {
                let count = count.parse::<u64>().map_err(|_| bad("the element count is not a whole number"))?;
                if elements.iter().any(|e| e.name == *name) {
                    return Err(bad("a second element of this name"));
                }
                elements.push(Element { name: name.to_string(), count, properties: vec![], line: line_no });
            }
            ["property", rest @ ..] => {
                let kind = match rest {
                    [t, _] => Kind::Scalar(Scalar::parse(t).ok_or_else(|| bad("unknown property type"))?),
                    ["list", c, t, _] => {
                        let count = Scalar::parse(c).ok_or_else(|| bad("unknown list count type"))?;
                        let item = Scalar::parse(t).ok_or_else(|| bad("unknown list item type"))?;
                        if count.int_range().is_none() {
                            return Err(bad("a list's count type must be an integer type"));
                        }
                        Kind::List { count, item }
                    }
                    _ => return Err(bad("expected `property TYPE NAME` or `property list COUNT_TYPE ITEM_TYPE NAME`")),
                };
                let name = rest[rest.len() - 1];
                let Some(el) = elements.last_mut() else { return Err(bad("a property before any element")) };
                if el.property(name).is_some() {
                    return Err(bad("a second property of this name"));
                }
                el.properties.push(Property { name: name.to_string(), kind });
            }
            ["end_header"] => break,
            _ => return Err(bad("not a header line")),
        }
    }
    let format = format.ok_or("the header has no `format` line")?;
    let at = if bytes[..at].ends_with(b"\n") { at } else { bytes.len() };
    Ok((format, elements, at, line_no))
}

/// Reads the values of the data section in order, ASCII or binary, and says where it is.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
    format: Format,
    /// ASCII: the line being read (1-based in the file) and its values not yet read.
    line: usize,
    words: std::vec::IntoIter<&'a str>,
}

impl<'a> Cursor<'a> {
    fn new(bytes: &'a [u8], at: usize, header_lines: usize, format: Format) -> Self {
        Self { bytes, at, format, line: header_lines, words: Vec::new().into_iter() }
    }

    /// Where the cursor is, for messages.
    fn place(&self) -> String {
        match self.format {
            Format::Ascii => format!("line {}", self.line),
            _ => format!("byte offset {}", self.at),
        }
    }

    /// Binary: the bytes not read yet.
    fn bytes_left(&self) -> Option<usize> {
        (self.format != Format::Ascii).then(|| self.bytes.len() - self.at)
    }

    /// The next ASCII line holding values (blank lines are skipped): one element each.
    fn next_line(&mut self) -> Option<Result<Vec<&'a str>, String>> {
        while self.at < self.bytes.len() {
            let end = self.bytes[self.at..].iter().position(|&b| b == b'\n').map_or(self.bytes.len(), |i| self.at + i);
            let text = &self.bytes[self.at..end];
            self.at = (end + 1).min(self.bytes.len());
            self.line += 1;
            let Ok(text) = std::str::from_utf8(text) else {
                return Some(Err(format!("line {}: not ASCII text", self.line)));
            };
            let words: Vec<&str> = text.split_ascii_whitespace().collect();
            if !words.is_empty() {
                return Some(Ok(words));
            }
        }
        None
    }

    /// Start an element.
    fn begin(&mut self) -> Result<(), String> {
        if self.format == Format::Ascii {
            match self.next_line() {
                None => return Err("the file ends before this element".into()),
                Some(words) => self.words = words?.into_iter(),
            }
        }
        Ok(())
    }

    /// End an element: an ASCII line must hold nothing more.
    fn end(&mut self) -> Result<(), String> {
        match self.words.next() {
            Some(w) => Err(format!("`{w}` after the element's last property")),
            None => Ok(()),
        }
    }

    /// Nothing may follow the last element.
    fn finish(&mut self) -> Result<(), String> {
        match self.format {
            Format::Ascii => match self.next_line() {
                None => Ok(()),
                Some(_) => Err(format!("line {}: data after the last element the header declares", self.line)),
            },
            _ if self.at < self.bytes.len() => Err(format!(
                "byte offset {}: {} bytes after the last element the header declares",
                self.at,
                self.bytes.len() - self.at
            )),
            _ => Ok(()),
        }
    }

    /// The next value, of type `t` (exact in f64 for every integer type).
    fn value(&mut self, t: Scalar) -> Result<f64, String> {
        if self.format == Format::Ascii {
            let w = self.words.next().ok_or("the line ends early")?;
            let bad = || format!("`{w}` is not a {}", t.name());
            return match t.int_range() {
                Some((lo, hi)) => {
                    let v = w.parse::<i64>().map_err(|_| bad())?;
                    if v < lo || v > hi {
                        return Err(bad());
                    }
                    Ok(v as f64)
                }
                None if t == Scalar::F32 => Ok(w.parse::<f32>().map_err(|_| bad())? as f64),
                None => w.parse::<f64>().map_err(|_| bad()),
            };
        }
        let n = t.size();
        let Some(b) = self.bytes.get(self.at..self.at + n) else {
            return Err(format!("the file ends at byte {}, inside a {} ({n} bytes)", self.bytes.len(), t.name()));
        };
        self.at += n;
        let big = self.format == Format::Big;
        macro_rules! num {
            ($ty:ty) => {{
                let a = b.try_into().expect("sized above");
                (if big { <$ty>::from_be_bytes(a) } else { <$ty>::from_le_bytes(a) }) as f64
            }};
        }
        Ok(match t {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => num!(i16),
            Scalar::U16 => num!(u16),
            Scalar::I32 => num!(i32),
            Scalar::U32 => num!(u32),
            Scalar::F32 => num!(f32),
            Scalar::F64 => num!(f64),
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::geometry::{Mesh, MeshLoad};
    use rand::{Rng, SeedableRng};
    use std::path::{Path, PathBuf};

    /// Two convex faces and a non-convex one (a chevron: ear-clipped), with texture
    /// coordinates; every vertex is first used in file order, as tobj numbers OBJ vertices.
    const POSITIONS: [[f32; 3]; 10] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [2.0, 0.5, 0.25],
        [0.0, 0.0, 2.0],
        [4.0, 0.0, 2.0],
        [4.0, 3.0, 2.0],
        [2.0, 1.0, 2.0],
        [0.0, 3.0, 2.0],
    ];
    const FACES: [&[u32]; 3] = [&[0, 1, 2, 3], &[1, 4, 2], &[5, 6, 7, 8, 9]];

    fn uv(i: usize) -> [f32; 2] {
        [i as f32 * 0.125, 1.0 - i as f32 * 0.0625]
    }

    fn obj_text() -> String {
        let mut s = String::new();
        for p in POSITIONS {
            s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        for i in 0..POSITIONS.len() {
            s += &format!("vt {} {}\n", uv(i)[0], uv(i)[1]);
        }
        for f in FACES {
            s += "f";
            for i in f.iter() {
                s += &format!(" {0}/{0}", i + 1);
            }
            s += "\n";
        }
        s
    }

    /// The header of the sample, with extra properties and an extra element to read past.
    fn header(format: &str, uv: (&str, &str), index_type: &str) -> String {
        format!(
            "ply\nformat {format} 1.0\ncomment made by a test\nelement vertex {}\nproperty float x\n\
             property float y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\n\
             property float {}\nproperty double {}\nproperty uchar red\nelement edge 1\n\
             property list uchar int pair\nelement face {}\nproperty list uchar {index_type} {}\n\
             property uchar flags\nend_header\n",
            POSITIONS.len(),
            uv.0,
            uv.1,
            FACES.len(),
            if index_type == "int" { "vertex_indices" } else { "vertex_index" }
        )
    }

    fn ascii_ply() -> Vec<u8> {
        let mut s = header("ascii", ("u", "v"), "int");
        for (i, p) in POSITIONS.iter().enumerate() {
            s += &format!("{} {} {} 0 0 1 {} {} 200\n", p[0], p[1], p[2], uv(i)[0], uv(i)[1]);
        }
        s += "2 0 1\n";
        for f in FACES {
            s += &format!("{} {} 7\n", f.len(), f.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(" "));
        }
        s.into_bytes()
    }

    fn binary_ply(big: bool, uv_names: (&str, &str), index_type: &str) -> Vec<u8> {
        let format = if big { "binary_big_endian" } else { "binary_little_endian" };
        let mut b = header(format, uv_names, index_type).into_bytes();
        let f32b = |x: f32| if big { x.to_be_bytes() } else { x.to_le_bytes() };
        let f64b = |x: f64| if big { x.to_be_bytes() } else { x.to_le_bytes() };
        for (i, p) in POSITIONS.iter().enumerate() {
            b.extend(f32b(p[0]));
            b.extend(f32b(p[1]));
            b.extend(f64b(p[2] as f64));
            for n in [0.0, 0.0, 1.0] {
                b.extend(f32b(n));
            }
            b.extend(f32b(uv(i)[0]));
            b.extend(f64b(uv(i)[1] as f64));
            b.push(200);
        }
        b.push(2);
        for x in [0i32, 1] {
            b.extend(if big { x.to_be_bytes() } else { x.to_le_bytes() });
        }
        for f in FACES {
            b.push(f.len() as u8);
            for &i in f.iter() {
                match index_type {
                    "int" => b.extend(if big { (i as i32).to_be_bytes() } else { (i as i32).to_le_bytes() }),
                    _ => b.extend(if big { (i as u16).to_be_bytes() } else { (i as u16).to_le_bytes() }),
                }
            }
            b.push(7);
        }
        b
    }

    fn path(name: &str) -> PathBuf {
        PathBuf::from(format!("/data/{name}.ply"))
    }

    fn parse(name: &str, bytes: &[u8]) -> crate::Result<MeshLoad> {
        Mesh::parse_ply(bytes, &path(name))
    }

    /// The error of a file that must be refused, checked to name the file.
    fn refused(name: &str, bytes: &[u8]) -> String {
        match parse(name, bytes) {
            Ok(m) => panic!("{name}: expected an error, got {} triangles", m.mesh.triangle_count()),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with(&format!("{}: PLY: ", path(name).display())), "{name}: {msg}");
                msg
            }
        }
    }

    fn with_vertex_line(k: usize, line: &str) -> Vec<u8> {
        let text = String::from_utf8(ascii_ply()).unwrap();
        let (head, body) = text.split_once("end_header\n").unwrap();
        let mut lines: Vec<String> = body.lines().map(String::from).collect();
        lines[k] = line.to_string();
        format!("{head}end_header\n{}\n", lines.join("\n")).into_bytes()
    }

    #[test]
    fn ascii_and_binary_ply_load_the_same_mesh_as_the_obj() {
        let dir = tempfile::tempdir().unwrap();
        let obj_path = dir.path().join("sample.obj");
        std::fs::write(&obj_path, obj_text()).unwrap();
        let obj = Mesh::load_obj(&obj_path).unwrap();
        assert_eq!(obj.mesh.triangle_count(), 2 + 1 + 3);
        assert!(obj.mesh.uvs.is_some());
        assert_eq!(obj.repairs.len(), 1, "the chevron is ear-clipped: {:?}", obj.repairs);
        for (name, bytes) in [
            ("ascii", ascii_ply()),
            ("little", binary_ply(false, ("u", "v"), "int")),
            ("big", binary_ply(true, ("u", "v"), "int")),
            ("little-st-ushort", binary_ply(false, ("s", "t"), "ushort")),
            ("big-texture-uv", binary_ply(true, ("texture_u", "texture_v"), "int")),
        ] {
            let file = dir.path().join(format!("{name}.ply"));
            std::fs::write(&file, &bytes).unwrap();
            // Through the extension dispatch, as every command loads a mesh.
            let ply = Mesh::load(&file).unwrap();
            assert_eq!(ply.mesh, obj.mesh, "{name}");
            assert_eq!(ply.repairs, obj.repairs, "{name}");
        }
        // Without texture coordinates (and with CRLF lines), the positions alone.
        let text = String::from_utf8(ascii_ply()).unwrap();
        let plain = text
            .replace("property float u\nproperty double v\n", "")
            .lines()
            .map(|l| {
                let w: Vec<&str> = l.split(' ').collect();
                if w.len() == 9 && !l.starts_with("property") {
                    [&w[..6], &w[8..]].concat().join(" ")
                } else {
                    l.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\r\n");
        let ply = parse("plain", plain.as_bytes()).unwrap();
        assert!(ply.mesh.uvs.is_none());
        assert_eq!(ply.mesh.positions, obj.mesh.positions);
        assert_eq!(ply.mesh.triangles, obj.mesh.triangles);
    }

    #[test]
    fn mesh_files_are_chosen_by_extension() {
        let dir = tempfile::tempdir().unwrap();
        let upper = dir.path().join("SAMPLE.PLY");
        std::fs::write(&upper, ascii_ply()).unwrap();
        assert_eq!(Mesh::load(&upper).unwrap().mesh.triangle_count(), 6);
        let stl = dir.path().join("sample.stl");
        std::fs::write(&stl, b"solid x").unwrap();
        let e = Mesh::load(&stl).unwrap_err().to_string();
        assert!(e.contains("sample.stl") && e.contains("unsupported mesh format '.stl'"), "{e}");
        let e = Mesh::load(&dir.path().join("missing.ply")).unwrap_err().to_string();
        assert!(e.contains("missing.ply: file not found"), "{e}");
    }

    #[test]
    fn unreferenced_ply_vertices_are_dropped_with_a_note() {
        let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 1\nproperty list uchar uint vertex_indices\nend_header\n\
                    0 0 0\n9 9 9\n1 0 0\n0 1 0\n3 0 2 3\n";
        let load = parse("unreferenced", text.as_bytes()).unwrap();
        assert_eq!(load.mesh.positions, vec![glam::Vec3::ZERO, glam::Vec3::X, glam::Vec3::Y]);
        assert_eq!(load.repairs, ["dropped 1 unreferenced vertices"]);
    }

    #[test]
    fn truncated_ply_files_are_refused_where_they_end() {
        for (name, bytes) in [("ascii", ascii_ply()), ("binary", binary_ply(false, ("u", "v"), "int"))] {
            for len in 0..bytes.len() {
                match parse(name, &bytes[..len]) {
                    // Only the ASCII file without its last newline is whole.
                    Ok(_) if name == "ascii" && len == bytes.len() - 1 => {}
                    Ok(_) => panic!("a cut {name} file loaded ({len} of {} bytes)", bytes.len()),
                    Err(e) => assert!(e.to_string().contains("PLY: "), "{e}"),
                }
            }
        }
        // Cut inside the last face's list: the element, its number and the byte offset.
        let bytes = binary_ply(false, ("u", "v"), "int");
        let e = refused("cut", &bytes[..bytes.len() - 6]);
        assert!(
            e.contains("face 2 (byte offset") && e.contains("list `vertex_indices` of 5 ints needs 20 bytes"),
            "{e}"
        );
        // Cut inside the vertices: the counts no longer fit the bytes.
        let e = refused("short", &bytes[..bytes.len() - 100]);
        assert!(e.contains("declares") && e.contains("a truncated file or a lying count"), "{e}");
        let e = refused("ascii-short", &with_vertex_line(4, "2 0.5"));
        assert!(e.contains("vertex 4 (line 24): property `z`: the line ends early"), "{e}");
    }

    #[test]
    fn lying_counts_are_refused_before_allocating() {
        // 10^12 vertices in a few hundred bytes: refused from the header, no allocation.
        let text = String::from_utf8(ascii_ply()).unwrap().replace("element vertex 10", "element vertex 1000000000000");
        let e = refused("lying", text.as_bytes());
        assert!(e.contains("header line 4: declares 1000000000000 `vertex` elements"), "{e}");
        let bytes = binary_ply(true, ("u", "v"), "int");
        let body = bytes.windows(11).position(|w| w == b"end_header\n").unwrap();
        let head =
            String::from_utf8(bytes[..body].to_vec()).unwrap().replace("element face 3", "element face 99999999");
        let e = refused("lying-faces", &[head.as_bytes(), &bytes[body..]].concat());
        assert!(e.contains("`face` elements"), "{e}");
        // A list that claims more items than the file holds.
        let mut bytes = binary_ply(false, ("u", "v"), "int");
        let last_face = bytes.len() - (1 + 5 * 4 + 1);
        bytes[last_face] = 255;
        let e = refused("lying-list", &bytes);
        assert!(e.contains("face 2 (byte offset") && e.contains("of 255 ints needs 1020 bytes"), "{e}");
        // Fewer elements than the data holds: what is left over is an error, not ignored.
        let e = refused("extra", &[ascii_ply(), b"3 0 1 2 7\n".to_vec()].concat());
        assert!(e.contains("line 34: data after the last element"), "{e}");
        let e = refused("extra-binary", &[binary_ply(false, ("u", "v"), "int"), vec![0; 3]].concat());
        assert!(e.contains("3 bytes after the last element"), "{e}");
    }

    #[test]
    fn bad_headers_and_values_are_refused_with_their_place() {
        let text = String::from_utf8(ascii_ply()).unwrap();
        let swap = |from: &str, to: &str| {
            assert!(text.contains(from), "{from}");
            text.replacen(from, to, 1).into_bytes()
        };
        for (name, bytes, needle) in [
            ("magic", b"solid cube\n".to_vec(), "not a PLY file"),
            ("format", swap("format ascii 1.0\n", ""), "no `format` line"),
            ("format-kind", swap("ascii 1.0", "utf8 1.0"), "header line 2: unknown format"),
            ("version", swap("ascii 1.0", "ascii 2.0"), "unsupported version"),
            ("type", swap("property float x", "property float3 x"), "header line 5: unknown property type"),
            (
                "list-count",
                swap("list uchar int vertex_indices", "list float int vertex_indices"),
                "count type must be an integer",
            ),
            (
                "float-index",
                swap("list uchar int vertex_indices", "list uchar float vertex_indices"),
                "are float, expected an integer type",
            ),
            ("no-z", swap("property double z\n", ""), "the `vertex` element has no `z` property"),
            ("list-x", swap("property float x", "property list uchar float x"), "vertex property `x` is a list"),
            (
                "half-uv",
                swap("property double v\n", "property double w\n"),
                "only one of the texture coordinates `u` and `v`",
            ),
            ("no-list", swap("vertex_indices", "corners"), "no `vertex_indices` (or `vertex_index`) list"),
            ("no-face", swap("element face 3", "element polygon 3"), "no `face` element"),
            ("keyword", swap("comment made", "remark made"), "header line 3: not a header line"),
            ("orphan", swap("ply\n", "ply\nproperty float w\n"), "a property before any element"),
            (
                "twice",
                swap("property float y\n", "property float y\nproperty float y\n"),
                "a second property of this name",
            ),
            ("count", swap("element vertex 10", "element vertex ten"), "not a whole number"),
            ("end", text.split("end_header").next().unwrap().as_bytes().to_vec(), "no `end_header` line"),
            (
                "token",
                with_vertex_line(2, "1 1 abc 0 0 1 0 0 200"),
                "vertex 2 (line 22): property `z`: `abc` is not a double",
            ),
            ("range", with_vertex_line(2, "1 1 0 0 0 1 0 0 256"), "property `red`: `256` is not a uchar"),
            (
                "more",
                with_vertex_line(2, "1 1 0 0 0 1 0 0 200 5"),
                "vertex 2 (line 22): `5` after the element's last property",
            ),
            ("nan", with_vertex_line(3, "0 nan 0 0 0 1 0 0 200"), "vertex 3 (line 23): non-finite position"),
            (
                "uv-inf",
                with_vertex_line(3, "0 1 0 0 0 1 inf 0 200"),
                "vertex 3 (line 23): non-finite texture coordinate",
            ),
            (
                "index",
                with_vertex_line(12, "3 1 4 10 7"),
                "face 1 (line 32): vertex index 10 out of range (the file has 10 vertices)",
            ),
            ("negative", with_vertex_line(12, "3 1 -4 2 7"), "face 1 (line 32): vertex index -4 out of range"),
            ("two", with_vertex_line(12, "2 1 4 7"), "face 1 (line 32): a face with 2 vertices"),
        ] {
            let e = refused(name, &bytes);
            assert!(e.contains(needle), "{name}: {e}");
        }
        // No faces at all (a point cloud): nothing to trace.
        let cloud = String::from_utf8(swap("element face 3", "element face 0")).unwrap();
        let cloud: Vec<&str> = cloud.lines().collect();
        let e = refused("cloud", (cloud[..cloud.len() - 3].join("\n") + "\n").as_bytes());
        assert!(e.ends_with("PLY: no faces"), "{e}");
    }

    #[test]
    fn corrupted_ply_files_are_errors_never_panics() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
        let samples = [ascii_ply(), binary_ply(false, ("u", "v"), "int"), binary_ply(true, ("s", "t"), "ushort")];
        for sample in &samples {
            for _ in 0..2000 {
                let mut b = sample.clone();
                for _ in 0..rng.gen_range(1..4) {
                    let i = rng.gen_range(0..b.len());
                    b[i] = match rng.gen_range(0..3) {
                        0 => rng.gen(),
                        1 => b"0123456789 -\n.e"[rng.gen_range(0..15)],
                        _ => 0xff,
                    };
                }
                if let Err(e) = Mesh::parse_ply(&b, Path::new("fuzz.ply")) {
                    assert!(e.to_string().starts_with("fuzz.ply: "), "{e}");
                }
            }
        }
    }
}
