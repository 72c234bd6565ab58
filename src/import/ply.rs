//! PLY import: a hand-written reader for ascii and binary (both byte orders) PLY 1.0.
//!
//! Hand-written rather than a crate so errors can name the byte offset, line or element that is
//! wrong, and so large binary files read at close to memory speed. The vertex element gives
//! positions and optional normals, colors and texture coordinates (v flipped to glTF's convention); `face` polygons are
//! fan-triangulated and `tristrips` expanded with alternating winding; MeshLab's `comment
//! TextureFile <name>` lines become materials whose base color is that image (read from the
//! file's folder), faces choosing theirs by `texnumber`. Every other element is
//! skipped by its declared types. Vertex attributes are copied onto each triangle corner.
//!
//! Ascii records are read one per line, as PLY writes them: a line with more or fewer values than
//! its record is an error naming the line, and so is a last value that runs into the end of the
//! file instead of ending in a line end or blank (the file was cut, perhaps inside that number).

use super::stream::{FaceSink, Faces, Vertices, BATCH};
use super::{ImportOptions, Raw};
use crate::error::{Error, Location, Result};
use crate::format::{MapKind, TextureSlot, Wrap};
use crate::mesh::{coordinate_problem, Material, Mesh};
use byteorder::{BigEndian, ByteOrder, LittleEndian};
use glam::{Vec2, Vec3};
use std::marker::PhantomData;
use std::path::Path;

/// Read a PLY file into a raw, uncleaned mesh: positions as in the file, one triangle list.
/// Fails on a file without faces (a point cloud) and on any malformed or inconsistent data.
pub fn read(path: &Path, options: &ImportOptions, warnings: &mut Vec<String>) -> Result<Raw> {
    let mut mesh = read_mesh(path, warnings)?;
    load_textures(path, options, &mut mesh, warnings);
    Ok(Raw { mesh, metres_per_unit: None, georef: None, grid: None })
}

/// MeshLab's `TextureFile` comments name images beside the file: each material's base color,
/// read into `mesh.images` (a warning for each that cannot be read).
fn load_textures(path: &Path, options: &ImportOptions, mesh: &mut Mesh, warnings: &mut Vec<String>) {
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut files = super::ImageFiles::default();
    for m in 0..mesh.materials.len() {
        let Some(name) = mesh.materials[m].texture.clone() else { continue };
        if let Some(image) = files.load(dir, Path::new(&name), options.allow_outside_files, mesh, warnings) {
            mesh.materials[m].maps[MapKind::BaseColor as usize] = Some(TextureSlot { image, wrap: [Wrap::Repeat; 2] });
        }
    }
}

/// One material per `TextureFile`, named after it, its image to be loaded ([`load_textures`]).
fn texture_materials(texture_files: &[String]) -> Vec<Material> {
    texture_files
        .iter()
        .map(|t| Material { name: t.clone(), base_color: [1.0; 4], texture: Some(t.clone()), ..Material::default() })
        .collect()
}

/// The material of a face of `texnumber` (`None`: the face has none) among `count` texture files:
/// the first when it has none or one out of range.
fn texture_material(texnumber: Option<i64>, count: usize) -> u32 {
    texnumber.filter(|&t| (0..count as i64).contains(&t)).map_or(0, |t| t as u32)
}

fn read_mesh(path: &Path, warnings: &mut Vec<String>) -> Result<Mesh> {
    let bytes = super::read_file(path)?;
    parse(path, &bytes, warnings)
}

/// Parse PLY bytes; `path` only names the file in errors.
fn parse(path: &Path, bytes: &[u8], warnings: &mut Vec<String>) -> Result<Mesh> {
    let header = parse_header(path, bytes, warnings)?;
    let body = &bytes[header.body_start..];
    check_sizes(path, &header, body.len())?;
    let plan = Plan::new(path, &header)?;
    let mut reader = Reader::new(path, &plan);
    match header.encoding {
        Encoding::Ascii => reader.run(&header, &plan, &mut Ascii::new(body, header.body_line))?,
        Encoding::Little => reader.run(&header, &plan, &mut Binary::<LittleEndian>::new(body, header.body_start))?,
        Encoding::Big => reader.run(&header, &plan, &mut Binary::<BigEndian>::new(body, header.body_start))?,
    }
    Ok(reader.finish(&header.texture_files, warnings))
}

/// What a PLY header declares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Declared {
    pub vertices: u64,
    /// Face-like records (polygons or strips), not triangles.
    pub faces: u64,
    pub binary: bool,
    /// Whether it names texture images or has texture coordinates.
    pub textured: bool,
    /// About how many triangles the faces make: in a binary file, from the bytes the face lists
    /// take (polygons and strips make more triangles than records); else the face records, or
    /// twice the vertices (a closed mesh's ratio) for strips.
    pub triangles: u64,
}

/// The triangles `header`'s face elements make in a binary body of `body` bytes, when every
/// other element's records have a fixed size and each face element one list besides scalars.
fn binary_triangles(header: &Header, body: u64) -> Option<u64> {
    let scalars = |e: &Element| -> Option<u64> {
        e.props.iter().map(|p| if let Kind::Scalar(t) = p.kind { Some(t.size() as u64) } else { None }).sum()
    };
    let face_like = |e: &Element| e.name == "face" || e.name == "tristrips";
    let fixed: u64 = header.elements.iter().filter(|e| !face_like(e)).map(|e| scalars(e).map(|r| r * e.count)).sum::<Option<u64>>()?;
    let faces: Vec<&Element> = header.elements.iter().filter(|e| face_like(e)).collect();
    let [e] = faces[..] else { return None };
    let lists: Vec<(Scalar, Scalar)> =
        e.props.iter().filter_map(|p| if let Kind::List(c, t) = p.kind { Some((c, t)) } else { None }).collect();
    let [(count, item)] = lists[..] else { return None };
    let other: u64 = e.props.iter().map(|p| if let Kind::Scalar(t) = p.kind { t.size() as u64 } else { 0 }).sum();
    let items = body.checked_sub(fixed)?.checked_sub(e.count * (count.size() as u64 + other))? / item.size() as u64;
    // A polygon of n corners makes n − 2 triangles, and so does a strip of n indices.
    Some(items.saturating_sub(2 * e.count))
}

/// Longest header [`stream`] and [`declared`] read.
const MAX_HEADER: usize = 16 << 20;

/// Read the header of `path` alone.
pub fn declared(path: &Path) -> Result<Declared> {
    let (header, len) = read_header(path, &mut Vec::new())?;
    Ok(declared_by(path, &header, len))
}

/// What `header` (of a file of `len` bytes) declares.
fn declared_by(path: &Path, header: &Header, len: u64) -> Declared {
    let count = |names: &[&str]| header.elements.iter().filter(|e| names.contains(&e.name.as_str())).map(|e| e.count).sum();
    let textured = !header.texture_files.is_empty() || Plan::new(path, header).is_ok_and(|p| p.has_texcoords());
    let (vertices, faces): (u64, u64) = (count(&["vertex"]), count(&["face", "tristrips"]));
    let binary = header.encoding != Encoding::Ascii;
    let strips = header.elements.iter().any(|e| e.name == "tristrips");
    let triangles = match binary.then(|| binary_triangles(header, len.saturating_sub(header.body_start as u64))).flatten() {
        Some(t) => t,
        None if strips => faces.max(vertices.saturating_mul(2)),
        None => faces,
    };
    Declared { vertices, faces, binary, textured, triangles }
}

/// [`declared`] as the partitioned build asks it ([`super::stream::Streaming`]): with why [`stream`]
/// would refuse the file, if it would.
pub fn streaming_declared(path: &Path) -> Result<super::stream::Declared> {
    let (header, len) = read_header(path, &mut Vec::new())?;
    let refused = Plan::new(path, &header).ok().and_then(|plan| unstreamable(&plan));
    Ok(super::stream::Declared { triangles: declared_by(path, &header, len).triangles, refused })
}

/// Why [`stream`] cannot read a file of this header, if it cannot: faces before the vertices they
/// index.
fn unstreamable(plan: &Plan) -> Option<String> {
    let faces_first = plan.faces.iter().position(Option::is_some).is_some_and(|f| f < plan.vertex);
    faces_first.then(|| "faces come before vertices: a stream cannot index vertices it has not read".into())
}

fn read_header(path: &Path, warnings: &mut Vec<String>) -> Result<(Header, u64)> {
    use std::io::Read as _;
    let (file, len) = super::open_regular(path)?;
    let mut bytes = Vec::new();
    file.take(MAX_HEADER as u64).read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    let end = bytes.windows(10).position(|w| w == b"end_header").map(|i| i + 10);
    if let Some(end) = end {
        let line_end = bytes[end..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |n| end + n + 1);
        bytes.truncate(line_end);
    }
    Ok((parse_header(path, &bytes, warnings)?, len))
}

/// Read a PLY file (ascii or binary) as a stream: its vertex arrays are held (positions, normals,
/// colors, texture coordinates), and its triangles go to `faces` in batches as they are read with
/// their corners' UVs and their materials, indices checked, with the errors [`read`] gives; the
/// `TextureFile` materials and their images come back at the end. For the partitioned build, so
/// it refuses vertices after faces.
pub fn stream(path: &Path, options: &ImportOptions, faces: &mut FaceSink, warnings: &mut Vec<String>) -> Result<super::stream::Looks> {
    let (header, len) = read_header(path, warnings)?;
    check_sizes(path, &header, (len - header.body_start as u64) as usize)?;
    let plan = Plan::new(path, &header)?;
    if let Some(why) = unstreamable(&plan) {
        return Err(Error::invalid(path, None, why));
    }
    let mut reader = Reader::new(path, &plan);
    reader.texture_files = header.texture_files.len();
    reader.sink = Some(faces);
    let (file, _) = super::open_regular(path)?;
    let mut file = std::io::BufReader::with_capacity(1 << 20, file);
    std::io::Seek::seek(&mut file, std::io::SeekFrom::Start(header.body_start as u64)).map_err(|e| Error::io(path, e))?;
    let body = (header.body_start as u64, len);
    let failed = match header.encoding {
        Encoding::Little => {
            let mut src = Stream::<_, LittleEndian>::new(file, body.0, body.1);
            let r = reader.run(&header, &plan, &mut src);
            (src.failed.take(), r)
        }
        Encoding::Big => {
            let mut src = Stream::<_, BigEndian>::new(file, body.0, body.1);
            let r = reader.run(&header, &plan, &mut src);
            (src.failed.take(), r)
        }
        Encoding::Ascii => {
            let mut src = AsciiStream::new(file, header.body_line, body.1 - body.0);
            let r = reader.run(&header, &plan, &mut src);
            (src.failed.take(), r)
        }
    };
    // A read that failed is the error, not the end of data it looked like.
    match failed {
        (Some(e), _) => return Err(Error::io(path, e)),
        (None, r) => r?,
    }
    reader.warn(warnings);
    if header.texture_files.is_empty() {
        return Ok(super::stream::Looks::default());
    }
    let mut holder = Mesh { materials: texture_materials(&header.texture_files), ..Mesh::default() };
    load_textures(path, options, &mut holder, warnings);
    Ok(super::stream::Looks { materials: holder.materials, images: holder.images })
}

/// A binary body read from a file in pieces.
struct Stream<R, B> {
    src: R,
    buf: Vec<u8>,
    pos: usize,
    /// File offset of `buf[0]`.
    base: u64,
    len: u64,
    mark: u64,
    failed: Option<std::io::Error>,
    order: PhantomData<B>,
}

impl<R: std::io::Read, B: ByteOrder> Stream<R, B> {
    fn new(src: R, base: u64, len: u64) -> Self {
        Stream { src, buf: Vec::with_capacity(1 << 16), pos: 0, base, len, mark: base, failed: None, order: PhantomData }
    }

    /// Make `n` bytes available at `pos`, if the file has them.
    fn fill(&mut self, n: usize) -> bool {
        if self.buf.len() - self.pos >= n {
            return true;
        }
        self.buf.drain(..self.pos);
        self.base += self.pos as u64;
        self.pos = 0;
        let want = n.max(1 << 16);
        while self.buf.len() < want {
            let at = self.buf.len();
            self.buf.resize(want, 0);
            match self.src.read(&mut self.buf[at..]) {
                Ok(0) => {
                    self.buf.truncate(at);
                    break;
                }
                Ok(k) => self.buf.truncate(at + k),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => self.buf.truncate(at),
                Err(e) => {
                    self.buf.truncate(at);
                    self.failed = Some(e);
                    break;
                }
            }
        }
        self.buf.len() >= n
    }

    fn take(&mut self, n: usize) -> Read<&[u8]> {
        self.mark = self.base + self.pos as u64;
        if !self.fill(n) {
            return Err(Fault { at: self.at(), kind: FaultKind::Eof });
        }
        self.pos += n;
        Ok(&self.buf[self.pos - n..self.pos])
    }
}

impl<R: std::io::Read, B: ByteOrder> Source for Stream<R, B> {
    fn value(&mut self, t: Scalar) -> Read<f64> {
        let b = self.take(t.size())?;
        Ok(decode_value::<B>(t, b))
    }

    fn int(&mut self, t: Scalar) -> Read<i64> {
        let b = self.take(t.size())?;
        Ok(decode_int::<B>(t, b))
    }

    fn skip(&mut self, t: Scalar, n: usize) -> Read<()> {
        let mut left = t.size().saturating_mul(n);
        while left > 0 {
            let k = left.min(1 << 16);
            self.take(k)?;
            left -= k;
        }
        Ok(())
    }

    fn room(&self, n: u64, t: Scalar) -> bool {
        n as u128 * t.size() as u128 <= self.len.saturating_sub(self.base + self.pos as u64) as u128
    }

    fn at(&self) -> Location {
        Location::Byte(self.mark)
    }

    fn triangle(&mut self, count: Scalar, item: Scalar) -> Option<[i64; 3]> {
        let (cs, s) = (count.size(), item.size());
        if !self.fill(cs + 3 * s) {
            return None;
        }
        let rest = &self.buf[self.pos..self.pos + cs + 3 * s];
        if decode_int::<B>(count, rest) != 3 {
            return None;
        }
        self.pos += cs + 3 * s;
        Some([0, 1, 2].map(|k| decode_int::<B>(item, &rest[cs + k * s..])))
    }
}

/// An ascii body read from a file in pieces: the current line is always whole in `buf`.
struct AsciiStream<R> {
    src: R,
    buf: Vec<u8>,
    pos: usize,
    /// Where the line `pos` is on starts in `buf`.
    line_start: usize,
    eof: bool,
    /// Body bytes not yet read into `buf`.
    unread: u64,
    line: usize,
    record_line: usize,
    failed: Option<std::io::Error>,
}

impl<R: std::io::Read> AsciiStream<R> {
    fn new(src: R, first_line: usize, body: u64) -> Self {
        AsciiStream {
            src,
            buf: Vec::with_capacity(1 << 16),
            pos: 0,
            line_start: 0,
            eof: false,
            unread: body,
            line: first_line,
            record_line: first_line,
            failed: None,
        }
    }

    /// Read until a line end follows `pos` or the file ends.
    fn fill_line(&mut self) {
        while !self.eof && !self.buf[self.pos..].contains(&b'\n') {
            let keep = self.line_start;
            self.buf.drain(..keep);
            self.pos -= keep;
            self.line_start = 0;
            let at = self.buf.len();
            self.buf.resize(at + (1 << 16), 0);
            match self.src.read(&mut self.buf[at..]) {
                Ok(0) => {
                    self.buf.truncate(at);
                    self.eof = true;
                }
                Ok(k) => {
                    self.buf.truncate(at + k);
                    self.unread = self.unread.saturating_sub(k as u64);
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => self.buf.truncate(at),
                Err(e) => {
                    self.buf.truncate(at);
                    self.failed = Some(e);
                    self.eof = true;
                }
            }
        }
    }

    fn skip_blanks(&mut self) {
        while self.pos < self.buf.len() && is_blank(self.buf[self.pos]) {
            self.pos += 1;
        }
    }

    /// The next value on the current line, as its range in `buf`.
    fn token(&mut self) -> Read<std::ops::Range<usize>> {
        self.fill_line();
        self.skip_blanks();
        match self.buf.get(self.pos) {
            None => return Err(self.end_of_data()),
            Some(b'\n') => return Err(Fault { at: self.at(), kind: FaultKind::LineEnd }),
            Some(_) => {}
        }
        let start = self.pos;
        while self.pos < self.buf.len() && !self.buf[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        Ok(start..self.pos)
    }

    fn bad(&self, token: std::ops::Range<usize>, t: Scalar) -> Fault {
        Fault { at: self.at(), kind: FaultKind::Token(String::from_utf8_lossy(&self.buf[token]).into_owned(), t) }
    }

    /// At the end of the file: a cut value if the file ends inside one, else a missing one.
    fn end_of_data(&self) -> Fault {
        let tail = self.buf.iter().rev().take_while(|b| !b.is_ascii_whitespace()).count();
        let kind = match &self.buf[self.buf.len() - tail..] {
            [] => FaultKind::Eof,
            cut => FaultKind::Cut(String::from_utf8_lossy(cut).into_owned()),
        };
        Fault { at: self.at(), kind }
    }

    fn values_on_line(&self) -> usize {
        let end = self.buf[self.pos..].iter().position(|&b| b == b'\n').map_or(self.buf.len(), |n| self.pos + n);
        self.buf[self.line_start..end].split(|b| b.is_ascii_whitespace()).filter(|t| !t.is_empty()).count()
    }
}

impl<R: std::io::Read> Source for AsciiStream<R> {
    fn value(&mut self, t: Scalar) -> Read<f64> {
        let token = self.token()?;
        parse_value(&self.buf[token.clone()], t).ok_or_else(|| self.bad(token, t))
    }

    fn int(&mut self, t: Scalar) -> Read<i64> {
        let token = self.token()?;
        parse_int(&self.buf[token.clone()]).ok_or_else(|| self.bad(token, t))
    }

    fn skip(&mut self, t: Scalar, n: usize) -> Read<()> {
        for _ in 0..n {
            self.value(t)?;
        }
        Ok(())
    }

    fn room(&self, n: u64, _t: Scalar) -> bool {
        n as u128 * 2 <= ((self.buf.len() - self.pos) as u64 + self.unread) as u128 + 1
    }

    fn at(&self) -> Location {
        Location::Line(self.record_line)
    }

    fn begin_record(&mut self) {
        loop {
            self.fill_line();
            while self.pos < self.buf.len() && self.buf[self.pos].is_ascii_whitespace() {
                if self.buf[self.pos] == b'\n' {
                    self.line += 1;
                    self.line_start = self.pos + 1;
                }
                self.pos += 1;
            }
            if self.pos < self.buf.len() || self.eof {
                break;
            }
        }
        if self.pos < self.buf.len() {
            self.record_line = self.line;
        }
    }

    fn end_record(&mut self) -> Read<()> {
        self.fill_line();
        self.skip_blanks();
        match self.buf.get(self.pos) {
            Some(b'\n') => Ok(()),
            None => match self.end_of_data() {
                Fault { kind: FaultKind::Eof, .. } => Ok(()),
                cut => Err(cut),
            },
            Some(_) => Err(Fault { at: self.at(), kind: FaultKind::Extra(self.values_on_line()) }),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// A PLY scalar type.
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
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    fn name(self) -> &'static str {
        match self {
            Scalar::I8 => "char",
            Scalar::U8 => "uchar",
            Scalar::I16 => "short",
            Scalar::U16 => "ushort",
            Scalar::I32 => "int",
            Scalar::U32 => "uint",
            Scalar::F32 => "float",
            Scalar::F64 => "double",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Scalar(Scalar),
    /// Count type, item type.
    List(Scalar, Scalar),
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
    /// Header line that declared the element.
    line: usize,
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    /// `comment TextureFile <name>` lines (MeshLab's convention), in order: face `texnumber` k
    /// samples the k-th.
    texture_files: Vec<String>,
    body_start: usize,
    /// Line number of the first body line (for ascii errors).
    body_line: usize,
}

fn parse_header(path: &Path, bytes: &[u8], warnings: &mut Vec<String>) -> Result<Header> {
    if bytes.is_empty() {
        return Err(Error::at_byte(path, 0, super::EMPTY));
    }
    let mut encoding = None;
    let mut texture_files = Vec::new();
    let mut elements: Vec<Element> = Vec::new();
    let mut pos = 0;
    let mut line = 0;
    loop {
        if pos >= bytes.len() {
            return Err(Error::at_line(path, line, "the header has no end_header line"));
        }
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |n| pos + n);
        let raw = &bytes[pos..end];
        pos = (end + 1).min(bytes.len());
        line += 1;
        let text = std::str::from_utf8(raw).ok();
        if line == 1 {
            if text.map(str::trim) != Some("ply") {
                let why = super::utf16_hint(bytes).unwrap_or_else(|| "the first line must be 'ply'".into());
                return Err(Error::at_line(path, 1, format!("not a PLY file: {why}")));
            }
            continue;
        }
        let text = text.ok_or_else(|| Error::at_line(path, line, "header line is not text"))?;
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        match words.first().copied() {
            Some("comment") if words.get(1).is_some_and(|w| w.eq_ignore_ascii_case("TextureFile")) => {
                let rest = text.trim_start()["comment".len()..].trim_start()["TextureFile".len()..].trim();
                if !rest.is_empty() {
                    texture_files.push(rest.to_string());
                }
            }
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                if encoding.is_some() {
                    return Err(Error::at_line(path, line, "second format line"));
                }
                encoding = Some(parse_format(&words).map_err(|m| Error::at_line(path, line, m))?);
            }
            Some("element") => {
                let (name, count) = match words[1..] {
                    [name, count] => (name, count),
                    _ => return Err(Error::at_line(path, line, "expected 'element <name> <count>'")),
                };
                let count = count
                    .parse::<u64>()
                    .map_err(|_| Error::at_line(path, line, format!("element count '{count}' is not a non-negative integer")))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new(), line });
            }
            Some("property") => {
                let element = elements.last_mut().ok_or_else(|| Error::at_line(path, line, "property before any element"))?;
                let prop = parse_property(&words).map_err(|m| Error::at_line(path, line, m))?;
                element.props.push(prop);
            }
            Some("end_header") => break,
            Some(_) => warnings.push(format!("line {line}: ignored unrecognised header line '{}'", text.trim())),
        }
    }
    let encoding = encoding.ok_or_else(|| Error::at_line(path, line, "the header has no format line"))?;
    Ok(Header { encoding, elements, texture_files, body_start: pos, body_line: line + 1 })
}

fn parse_format(words: &[&str]) -> std::result::Result<Encoding, String> {
    let (encoding, version) = match words[1..] {
        [e, v] => (e, v),
        _ => return Err("expected 'format <ascii|binary_little_endian|binary_big_endian> 1.0'".into()),
    };
    let encoding = match encoding {
        "ascii" => Encoding::Ascii,
        "binary_little_endian" => Encoding::Little,
        "binary_big_endian" => Encoding::Big,
        other => return Err(format!("unknown PLY format '{other}'")),
    };
    if version.parse::<f64>().ok() != Some(1.0) {
        return Err(format!("unsupported PLY version '{version}' (only 1.0 is supported)"));
    }
    Ok(encoding)
}

fn parse_property(words: &[&str]) -> std::result::Result<Property, String> {
    let scalar = |s: &str| Scalar::parse(s).ok_or_else(|| format!("unknown property type '{s}'"));
    let (kind, name) = match words[1..] {
        ["list", count, item, name, ..] => {
            let count = scalar(count)?;
            if count.is_float() {
                return Err(format!("list count type '{}' is not an integer type", count.name()));
            }
            (Kind::List(count, scalar(item)?), name)
        }
        ["list", ..] => return Err("expected 'property list <count type> <item type> <name>'".into()),
        [t, name, ..] => (Kind::Scalar(scalar(t)?), name),
        _ => return Err("expected 'property <type> <name>'".into()),
    };
    Ok(Property { name: name.to_string(), kind })
}

/// Reject headers whose element counts need more bytes than the file holds, before anything is
/// allocated from those counts. A binary file that fails this check is truncated (or its counts
/// lie): the error names the byte offset where the data ends and the record it ends in, exact
/// when the elements before have no lists (which may be longer than their minimum).
fn check_sizes(path: &Path, header: &Header, body_len: usize) -> Result<()> {
    // A binary value takes its type's size (a list at least its count); an ascii value at least
    // one character and one separator (the file's last value may lack the separator).
    let ascii = header.encoding == Encoding::Ascii;
    let available = body_len as u128 + ascii as u128;
    let mut need: u128 = 0;
    for e in &header.elements {
        let record: u128 = e
            .props
            .iter()
            .map(|p| match p.kind {
                _ if ascii => 2,
                Kind::Scalar(t) | Kind::List(t, _) => t.size() as u128,
            })
            .sum();
        let before = need;
        need += e.count as u128 * record;
        if need <= available {
            continue;
        }
        let declared = format!(
            "element {} (header line {}) declares {} records, needing at least {need} bytes of data, but only {body_len} bytes follow the header",
            e.name, e.line, e.count
        );
        return Err(if ascii {
            Error::at_line(path, e.line, declared)
        } else {
            let end = (header.body_start + body_len) as u64;
            let record_index = (available - before) / record.max(1);
            Error::at_byte(path, end, format!("file ends in {} {record_index}: {declared}", e.name))
        });
    }
    Ok(())
}

// Vertex attribute slots.
const X: usize = 0;
const NX: usize = 3;
const RED: usize = 6;
const ALPHA: usize = 9;
const U: usize = 10;
const SLOTS: usize = 12;

/// Texture coordinate property names, in order of preference.
const UV_NAMES: [(&str, &str); 4] = [("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t")];

/// What to do with each element, decided from the header alone.
struct Plan {
    /// The vertex element.
    vertex: usize,
    vertex_count: u64,
    /// Per vertex property: the attribute slot it fills, if any.
    slots: Vec<Option<usize>>,
    /// Per slot: the scalar type that fills it, if any.
    slot_types: [Option<Scalar>; SLOTS],
    /// Per element: for face-like elements, the index list and an optional texcoord list.
    faces: Vec<Option<FaceProps>>,
    /// Elements after this one are not needed.
    last_needed: usize,
}

#[derive(Clone, Copy)]
struct FaceProps {
    /// The index list property, its count type and its index type.
    indices: usize,
    count_type: Scalar,
    index_type: Scalar,
    texcoord: Option<usize>,
    /// A scalar `texnumber`: which `TextureFile` the face samples.
    texnumber: Option<usize>,
    strips: bool,
}

impl Plan {
    fn new(path: &Path, header: &Header) -> Result<Plan> {
        let mut vertex = None;
        let mut faces = vec![None; header.elements.len()];
        let mut face_records = 0u64;
        for (i, e) in header.elements.iter().enumerate() {
            match e.name.as_str() {
                "vertex" if vertex.is_some() => {
                    return Err(Error::at_line(path, e.line, "second vertex element"));
                }
                "vertex" => vertex = Some(i),
                "face" | "tristrips" => {
                    faces[i] = Some(face_props(path, e)?);
                    face_records = face_records.saturating_add(e.count);
                }
                _ => {}
            }
        }
        let vertex_count = vertex.map_or(0, |v| header.elements[v].count);
        if face_records == 0 {
            return Err(Error::invalid(
                path,
                None,
                format!("this PLY is a point cloud: {vertex_count} vertices and no faces (nothing to triangulate)"),
            ));
        }
        let v = vertex.ok_or_else(|| Error::invalid(path, None, "the file has faces but no vertex element"))?;
        let ve = &header.elements[v];
        if vertex_count > u32::MAX as u64 {
            return Err(Error::at_line(path, ve.line, format!("{vertex_count} vertices is more than strata supports")));
        }
        let mut slots = vec![None; ve.props.len()];
        let mut slot_types = [None; SLOTS];
        let mut assign = |slot: usize, names: &[&str]| {
            let found = ve.props.iter().position(|p| names.contains(&p.name.as_str()) && matches!(p.kind, Kind::Scalar(_)));
            if let (Some(p), None) = (found, slot_types[slot]) {
                if let Kind::Scalar(t) = ve.props[p].kind {
                    slots[p] = Some(slot);
                    slot_types[slot] = Some(t);
                }
            }
        };
        for (k, name) in ["x", "y", "z", "nx", "ny", "nz"].iter().enumerate() {
            assign(k, &[name]);
        }
        for (k, name) in ["red", "green", "blue", "alpha"].iter().enumerate() {
            assign(RED + k, &[name, &format!("diffuse_{name}")]);
        }
        let has = |n: &str| ve.props.iter().any(|p| p.name == n && matches!(p.kind, Kind::Scalar(_)));
        if let Some((u, v)) = UV_NAMES.iter().find(|(u, v)| has(u) && has(v)) {
            assign(U, &[u]);
            assign(U + 1, &[v]);
        }
        if slot_types[X..X + 3].iter().any(Option::is_none) {
            return Err(Error::at_line(path, ve.line, "the vertex element lacks a scalar x, y or z property"));
        }
        let last_needed = faces.iter().rposition(Option::is_some).map_or(v, |f| f.max(v));
        Ok(Plan { vertex: v, vertex_count, slots, slot_types, faces, last_needed })
    }

    fn has(&self, slot: usize, n: usize) -> bool {
        self.slot_types[slot..slot + n].iter().all(Option::is_some)
    }

    /// Whether vertices or faces carry texture coordinates.
    fn has_texcoords(&self) -> bool {
        self.has(U, 2) || self.faces.iter().flatten().any(|f| f.texcoord.is_some())
    }
}

fn face_props(path: &Path, e: &Element) -> Result<FaceProps> {
    let indices = e
        .props
        .iter()
        .position(|p| p.name == "vertex_indices" || p.name == "vertex_index")
        .ok_or_else(|| Error::at_line(path, e.line, format!("element {} has no vertex_indices list", e.name)))?;
    let (count_type, index_type) = match e.props[indices].kind {
        Kind::List(c, t) if !t.is_float() => (c, t),
        _ => {
            return Err(Error::at_line(
                path,
                e.line,
                format!("{} of element {} must be a list of an integer type", e.props[indices].name, e.name),
            ))
        }
    };
    let texcoord = e.props.iter().position(|p| p.name == "texcoord" && matches!(p.kind, Kind::List(..)));
    let texnumber = e.props.iter().position(|p| p.name == "texnumber" && matches!(p.kind, Kind::Scalar(_)));
    Ok(FaceProps { indices, count_type, index_type, texcoord, texnumber, strips: e.name == "tristrips" })
}

/// Why reading a value failed, and where.
struct Fault {
    at: Location,
    kind: FaultKind,
}

enum FaultKind {
    Eof,
    Token(String, Scalar),
    Count(i64),
    /// Ascii: the record's line ended before its last value.
    LineEnd,
    /// Ascii: this value runs into the end of the file, so the file was cut inside it.
    Cut(String),
    /// Ascii: the record's line holds this many values, more than the record takes.
    Extra(usize),
}

/// The error for a fault in record `record` of element `e`, inside property `p` if known.
fn fault_error(path: &Path, f: Fault, e: &Element, record: u64, p: Option<&Property>) -> Error {
    let what = match p {
        Some(p) => format!("{} {record} (property {})", e.name, p.name),
        None => format!("{} {record}", e.name),
    };
    let message = match f.kind {
        FaultKind::Eof => format!("file ends inside {what}"),
        FaultKind::LineEnd => format!("the line ends inside {what}: ascii PLY holds one record per line"),
        FaultKind::Cut(token) => format!(
            "'{token}' in {what} runs into the end of the file: the file looks cut (its last value must be \
             followed by a line end)"
        ),
        FaultKind::Extra(values) => {
            let n = e.props.len();
            format!(
                "element {} has {n} {} but the line has {values} values, more than {what} takes \
                 (ascii PLY holds one record per line)",
                e.name,
                if n == 1 { "property" } else { "properties" }
            )
        }
        FaultKind::Token(token, t) => format!("'{token}' is not a valid {} in {what}", t.name()),
        FaultKind::Count(n) if n < 0 => format!("list length {n} in {what} is negative"),
        FaultKind::Count(n) => format!("list length {n} in {what} runs past the end of the file"),
    };
    Error::invalid(path, Some(f.at), message)
}

type Read<T> = std::result::Result<T, Fault>;

/// The body of a PLY file as a stream of typed values.
trait Source {
    /// The next value, converted to f64.
    fn value(&mut self, t: Scalar) -> Read<f64>;
    /// The next value of an integer type.
    fn int(&mut self, t: Scalar) -> Read<i64>;
    /// Skip `n` values of type `t`.
    fn skip(&mut self, t: Scalar, n: usize) -> Read<()>;
    /// Whether `n` values of type `t` could still fit in the rest of the data.
    fn room(&self, n: u64, t: Scalar) -> bool;
    /// Where the last value read starts.
    fn at(&self) -> Location;
    /// Move to the start of the next record (ascii: past the line end and any blank lines).
    fn begin_record(&mut self) {}
    /// Check that the record just read ends there (ascii: nothing but blanks after it on its line).
    fn end_record(&mut self) -> Read<()> {
        Ok(())
    }

    /// A list length, checked against the remaining data.
    fn list_len(&mut self, count: Scalar, item: Scalar) -> Read<usize> {
        let n = self.int(count)?;
        if n < 0 || !self.room(n as u64, item) {
            return Err(Fault { at: self.at(), kind: FaultKind::Count(n) });
        }
        Ok(n as usize)
    }

    /// If the next record is a list of exactly three indices that is wholly present, consume and
    /// return it. A fast path only; `None` means "read it the general way".
    fn triangle(&mut self, _count: Scalar, _item: Scalar) -> Option<[i64; 3]> {
        None
    }
}

struct Binary<'a, B> {
    data: &'a [u8],
    pos: usize,
    /// File offset of `data[0]`.
    base: usize,
    mark: usize,
    order: PhantomData<B>,
}

impl<'a, B: ByteOrder> Binary<'a, B> {
    fn new(data: &'a [u8], base: usize) -> Self {
        Binary { data, pos: 0, base, mark: 0, order: PhantomData }
    }

    fn take(&mut self, n: usize) -> Read<&'a [u8]> {
        self.mark = self.pos;
        match self.data.get(self.pos..self.pos.saturating_add(n)) {
            Some(bytes) => {
                self.pos += n;
                Ok(bytes)
            }
            None => Err(Fault { at: self.at(), kind: FaultKind::Eof }),
        }
    }
}

/// Decode a value as f64; `b` holds at least `t.size()` bytes.
fn decode_value<B: ByteOrder>(t: Scalar, b: &[u8]) -> f64 {
    match t {
        Scalar::F32 => B::read_f32(b) as f64,
        Scalar::F64 => B::read_f64(b),
        _ => decode_int::<B>(t, b) as f64,
    }
}

/// Decode an integer-typed value; `b` holds at least `t.size()` bytes.
fn decode_int<B: ByteOrder>(t: Scalar, b: &[u8]) -> i64 {
    match t {
        Scalar::I8 => b[0] as i8 as i64,
        Scalar::U8 => b[0] as i64,
        Scalar::I16 => B::read_i16(b) as i64,
        Scalar::U16 => B::read_u16(b) as i64,
        Scalar::I32 => B::read_i32(b) as i64,
        Scalar::U32 => B::read_u32(b) as i64,
        Scalar::F32 => B::read_f32(b) as i64,
        Scalar::F64 => B::read_f64(b) as i64,
    }
}

impl<B: ByteOrder> Source for Binary<'_, B> {
    fn value(&mut self, t: Scalar) -> Read<f64> {
        let b = self.take(t.size())?;
        Ok(decode_value::<B>(t, b))
    }

    fn int(&mut self, t: Scalar) -> Read<i64> {
        let b = self.take(t.size())?;
        Ok(decode_int::<B>(t, b))
    }

    fn skip(&mut self, t: Scalar, n: usize) -> Read<()> {
        self.take(t.size().saturating_mul(n)).map(|_| ())
    }

    fn room(&self, n: u64, t: Scalar) -> bool {
        n as u128 * t.size() as u128 <= (self.data.len() - self.pos) as u128
    }

    fn at(&self) -> Location {
        Location::Byte((self.base + self.mark) as u64)
    }

    fn triangle(&mut self, count: Scalar, item: Scalar) -> Option<[i64; 3]> {
        let (cs, s) = (count.size(), item.size());
        let rest = self.data.get(self.pos..self.pos + cs + 3 * s)?;
        if decode_int::<B>(count, rest) != 3 {
            return None;
        }
        self.pos += cs + 3 * s;
        Some([0, 1, 2].map(|k| decode_int::<B>(item, &rest[cs + k * s..])))
    }
}

/// Ascii PLY: one record per line, values separated by blanks. Values are read to their last
/// byte: one that runs into the end of the file (no line end or blank after it) means the file
/// was cut inside it.
struct Ascii<'a> {
    data: &'a [u8],
    pos: usize,
    /// The line `pos` is on.
    line: usize,
    /// The line of the record being read (at the end of the data, of the last one read).
    record_line: usize,
}

/// Whitespace inside a line.
fn is_blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\x0c')
}

impl<'a> Ascii<'a> {
    fn new(data: &'a [u8], first_line: usize) -> Self {
        Ascii { data, pos: 0, line: first_line, record_line: first_line }
    }

    fn skip_blanks(&mut self) {
        let data = self.data;
        let mut pos = self.pos;
        while pos < data.len() && is_blank(data[pos]) {
            pos += 1;
        }
        self.pos = pos;
    }

    /// The next value on the current line.
    fn token(&mut self) -> Read<&'a [u8]> {
        self.skip_blanks();
        let (data, start) = (self.data, self.pos);
        match data.get(start) {
            None => return Err(self.end_of_data()),
            Some(b'\n') => return Err(Fault { at: self.at(), kind: FaultKind::LineEnd }),
            Some(_) => {}
        }
        let mut end = start + 1;
        while end < data.len() && !data[end].is_ascii_whitespace() {
            end += 1;
        }
        self.pos = end;
        Ok(&data[start..end])
    }

    /// The fault of reaching the end of the data: a cut value if the data ends inside one (or
    /// right after it, without a line end), else a missing one.
    fn end_of_data(&self) -> Fault {
        let data = self.data;
        let value = data.len() - data.iter().rev().take_while(|b| !b.is_ascii_whitespace()).count();
        let kind = match &data[value..] {
            [] => FaultKind::Eof,
            cut => FaultKind::Cut(String::from_utf8_lossy(cut).into_owned()),
        };
        Fault { at: self.at(), kind }
    }

    fn bad(&self, token: &[u8], t: Scalar) -> Fault {
        Fault { at: self.at(), kind: FaultKind::Token(String::from_utf8_lossy(token).into_owned(), t) }
    }

    /// The number of values on the current line.
    fn values_on_line(&self) -> usize {
        let start = self.data[..self.pos].iter().rposition(|&b| b == b'\n').map_or(0, |n| n + 1);
        let end = self.data[self.pos..].iter().position(|&b| b == b'\n').map_or(self.data.len(), |n| self.pos + n);
        self.data[start..end].split(|b| b.is_ascii_whitespace()).filter(|t| !t.is_empty()).count()
    }
}

/// An ascii value of type `t` converted to f64, or `None`.
fn parse_value(token: &[u8], t: Scalar) -> Option<f64> {
    match t {
        Scalar::F32 => std::str::from_utf8(token).ok().and_then(|s| s.parse::<f32>().ok()).map(f64::from),
        Scalar::F64 => std::str::from_utf8(token).ok().and_then(|s| s.parse::<f64>().ok()),
        _ => parse_int(token).map(|n| n as f64),
    }
}

/// A decimal integer with an optional sign, or `None`.
fn parse_int(token: &[u8]) -> Option<i64> {
    let (negative, digits) = match token.split_first()? {
        (b'-', rest) => (true, rest),
        (b'+', rest) => (false, rest),
        _ => (false, token),
    };
    if digits.is_empty() {
        return None;
    }
    let mut n: i64 = 0;
    for &d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        n = n.checked_mul(10)?.checked_add((d - b'0') as i64)?;
    }
    Some(if negative { -n } else { n })
}

impl Source for Ascii<'_> {
    fn value(&mut self, t: Scalar) -> Read<f64> {
        let token = self.token()?;
        parse_value(token, t).ok_or_else(|| self.bad(token, t))
    }

    fn int(&mut self, t: Scalar) -> Read<i64> {
        let token = self.token()?;
        parse_int(token).ok_or_else(|| self.bad(token, t))
    }

    fn skip(&mut self, t: Scalar, n: usize) -> Read<()> {
        for _ in 0..n {
            self.value(t)?;
        }
        Ok(())
    }

    fn room(&self, n: u64, _t: Scalar) -> bool {
        n as u128 * 2 <= (self.data.len() - self.pos) as u128 + 1
    }

    fn at(&self) -> Location {
        Location::Line(self.record_line)
    }

    fn begin_record(&mut self) {
        let data = self.data;
        let (mut pos, mut line) = (self.pos, self.line);
        while pos < data.len() && data[pos].is_ascii_whitespace() {
            line += (data[pos] == b'\n') as usize;
            pos += 1;
        }
        // At the end of the data, errors blame the line of the last record read.
        if pos < data.len() {
            self.record_line = line;
        }
        (self.pos, self.line) = (pos, line);
    }

    fn end_record(&mut self) -> Read<()> {
        self.skip_blanks();
        match self.data.get(self.pos) {
            Some(b'\n') => Ok(()),
            None => match self.end_of_data() {
                Fault { kind: FaultKind::Eof, .. } => Ok(()),
                cut => Err(cut),
            },
            Some(_) => Err(Fault { at: self.at(), kind: FaultKind::Extra(self.values_on_line()) }),
        }
    }
}

/// The UV of a corner whose face has no texcoord pair for it: (0, 0) as the file counts, v flipped.
const NO_UV: Vec2 = Vec2::new(0.0, 1.0);

/// Accumulates what the body holds.
struct Reader<'p> {
    path: &'p Path,
    vertex_count: u64,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    colors: Vec<[u8; 4]>,
    uvs: Vec<Vec2>,
    /// Whether vertices have UVs; else whether faces have `texcoord` lists.
    vertex_uvs: bool,
    face_uvs: bool,
    triangles: Vec<[u32; 3]>,
    /// With `face_uvs`, per triangle its corners' UVs from its face's `texcoord` list ([`NO_UV`]
    /// when the list does not hold a pair per corner: `lacking_uvs` counts those faces).
    corner_uvs: Vec<[Vec2; 3]>,
    lacking_uvs: usize,
    /// Per triangle, its face's `texnumber`, when faces have one.
    texnumbers: Vec<i64>,
    short_faces: usize,
    /// Streaming ([`stream`]): triangles go here in batches instead of accumulating, with their
    /// corners' UVs and, when the file names `texture_files`, their materials.
    sink: Option<&'p mut FaceSink<'p>>,
    texture_files: usize,
    batch_uvs: Vec<[Vec2; 3]>,
    batch_materials: Vec<u32>,
}

impl<'p> Reader<'p> {
    fn new(path: &'p Path, plan: &Plan) -> Self {
        Reader {
            path,
            vertex_count: plan.vertex_count,
            positions: Vec::new(),
            normals: Vec::new(),
            colors: Vec::new(),
            uvs: Vec::new(),
            vertex_uvs: plan.has(U, 2),
            face_uvs: !plan.has(U, 2) && plan.has_texcoords(),
            triangles: Vec::new(),
            corner_uvs: Vec::new(),
            lacking_uvs: 0,
            texnumbers: Vec::new(),
            short_faces: 0,
            sink: None,
            texture_files: 0,
            batch_uvs: Vec::new(),
            batch_materials: Vec::new(),
        }
    }

    /// Hand the triangles read so far to the sink, if streaming.
    fn flush(&mut self) -> Result<()> {
        let Some(sink) = self.sink.as_mut() else { return Ok(()) };
        if self.triangles.is_empty() {
            return Ok(());
        }
        self.batch_uvs.clear();
        if self.vertex_uvs {
            self.batch_uvs.extend(self.triangles.iter().map(|t| t.map(|v| self.uvs[v as usize])));
        }
        self.batch_materials.clear();
        if self.texture_files > 0 {
            let (n, texnumbers) = (self.texture_files, &self.texnumbers);
            self.batch_materials.extend((0..self.triangles.len()).map(|f| texture_material(texnumbers.get(f).copied(), n)));
        }
        let v = Vertices { positions: &self.positions, normals: &self.normals, colors: &self.colors };
        let uvs = if self.face_uvs { &self.corner_uvs } else { &self.batch_uvs };
        sink(&v, &Faces { triangles: &self.triangles, normals: &[], uvs, materials: &self.batch_materials })?;
        self.triangles.clear();
        self.corner_uvs.clear();
        self.texnumbers.clear();
        Ok(())
    }

    /// The warnings of what was skipped or filled in.
    fn warn(&self, warnings: &mut Vec<String>) {
        if self.short_faces > 0 {
            warnings.push(format!("skipped {} faces with fewer than 3 vertices", self.short_faces));
        }
        if self.lacking_uvs > 0 {
            warnings.push(format!(
                "{} faces have no texcoord list of one (u, v) pair per corner: their corners get UV (0, 0)",
                self.lacking_uvs
            ));
        }
    }

    fn run<S: Source>(&mut self, header: &Header, plan: &Plan, src: &mut S) -> Result<()> {
        for (i, e) in header.elements.iter().enumerate().take(plan.last_needed + 1) {
            if i == plan.vertex {
                self.vertices(src, e, plan)?;
            } else if let Some(face) = plan.faces[i] {
                self.faces(src, e, face)?;
            } else if !e.props.is_empty() {
                for r in 0..e.count {
                    src.begin_record();
                    for p in &e.props {
                        skip_property(src, p).map_err(|f| fault_error(self.path, f, e, r, Some(p)))?;
                    }
                    src.end_record().map_err(|f| fault_error(self.path, f, e, r, None))?;
                }
            }
        }
        Ok(())
    }

    fn vertices<S: Source>(&mut self, src: &mut S, e: &Element, plan: &Plan) -> Result<()> {
        // The size check bounds the count by the file length.
        let n = e.count as usize;
        let (normals, colors, uvs) = (plan.has(NX, 3), plan.has(RED, 3), plan.has(U, 2));
        self.positions.reserve_exact(n);
        self.normals.reserve_exact(if normals { n } else { 0 });
        self.colors.reserve_exact(if colors { n } else { 0 });
        self.uvs.reserve_exact(if uvs { n } else { 0 });
        let mut v = [0.0f64; SLOTS];
        v[ALPHA] = 255.0;
        let color_float = plan.slot_types.map(|t| t.is_some_and(Scalar::is_float));
        for r in 0..e.count {
            src.begin_record();
            for (p, slot) in e.props.iter().zip(&plan.slots) {
                let got = match (p.kind, slot) {
                    (Kind::Scalar(t), Some(s)) => src.value(t).map(|x| v[*s] = x),
                    _ => skip_property(src, p),
                };
                got.map_err(|f| fault_error(self.path, f, e, r, Some(p)))?;
            }
            src.end_record().map_err(|f| fault_error(self.path, f, e, r, None))?;
            if let Some(problem) = coordinate_problem([v[X], v[X + 1], v[X + 2]]) {
                return Err(Error::at_element(self.path, format!("vertex {r}"), problem));
            }
            self.positions.push(Vec3::new(v[X] as f32, v[X + 1] as f32, v[X + 2] as f32));
            if normals {
                self.normals.push(Vec3::new(v[NX] as f32, v[NX + 1] as f32, v[NX + 2] as f32));
            }
            if colors {
                self.colors.push(std::array::from_fn(|k| {
                    let c = v[RED + k];
                    if color_float[RED + k] {
                        (c.clamp(0.0, 1.0) * 255.0).round() as u8
                    } else {
                        c.clamp(0.0, 255.0) as u8
                    }
                }));
            }
            if uvs {
                self.uvs.push(Vec2::new(v[U] as f32, 1.0 - v[U + 1] as f32));
            }
        }
        Ok(())
    }

    fn faces<S: Source>(&mut self, src: &mut S, e: &Element, face: FaceProps) -> Result<()> {
        let fast = e.props.len() == 1 && !face.strips;
        self.triangles.reserve(if self.sink.is_some() { BATCH } else { e.count as usize });
        let mut indices: Vec<i64> = Vec::new();
        let mut texcoords: Vec<f64> = Vec::new();
        let mut texnumber = 0i64;
        for r in 0..e.count {
            src.begin_record();
            if fast {
                if let Some(t) = src.triangle(face.count_type, face.index_type) {
                    src.end_record().map_err(|f| fault_error(self.path, f, e, r, None))?;
                    self.polygon(&t, None, e, r)?;
                    if self.sink.is_some() && self.triangles.len() >= BATCH {
                        self.flush()?;
                    }
                    continue;
                }
            }
            indices.clear();
            texcoords.clear();
            for (k, p) in e.props.iter().enumerate() {
                let got = match p.kind {
                    Kind::List(c, t) if k == face.indices => read_list(src, c, t, &mut indices, |s, t| s.int(t)),
                    Kind::List(c, t) if Some(k) == face.texcoord => read_list(src, c, t, &mut texcoords, |s, t| s.value(t)),
                    Kind::Scalar(t) if Some(k) == face.texnumber => src.value(t).map(|v| texnumber = v as i64),
                    _ => skip_property(src, p),
                };
                got.map_err(|f| fault_error(self.path, f, e, r, Some(p)))?;
            }
            src.end_record().map_err(|f| fault_error(self.path, f, e, r, None))?;
            let before = self.triangles.len();
            if face.strips {
                self.strip(&indices, e, r)?;
            } else {
                self.polygon(&indices, face.texcoord.map(|_| texcoords.as_slice()), e, r)?;
            }
            if face.texnumber.is_some() {
                self.texnumbers.resize(before, 0);
                self.texnumbers.resize(self.triangles.len(), texnumber);
            }
            if self.sink.is_some() && self.triangles.len() >= BATCH {
                self.flush()?;
            }
        }
        self.flush()
    }

    fn check_index(&self, v: i64, e: &Element, record: u64) -> Result<()> {
        if v >= 0 && (v as u64) < self.vertex_count {
            Ok(())
        } else {
            Err(Error::at_element(
                self.path,
                format!("{} {record}", e.name),
                format!("vertex index {v} is out of range: the file has {} vertices", self.vertex_count),
            ))
        }
    }

    /// Fan-triangulate one polygon; `texcoords`, its face's `texcoord` list if its element has
    /// one, should hold a (u, v) pair per corner.
    fn polygon(&mut self, indices: &[i64], texcoords: Option<&[f64]>, e: &Element, record: u64) -> Result<()> {
        if indices.len() < 3 {
            self.short_faces += 1;
            return Ok(());
        }
        for &v in indices {
            self.check_index(v, e, record)?;
        }
        let pairs = texcoords.filter(|t| t.len() == 2 * indices.len());
        if self.face_uvs && pairs.is_none() {
            self.lacking_uvs += 1;
        }
        for k in 1..indices.len() - 1 {
            self.triangles.push([indices[0], indices[k], indices[k + 1]].map(|v| v as u32));
            if self.face_uvs {
                let uv = |c: usize| pairs.map_or(NO_UV, |t| Vec2::new(t[2 * c] as f32, 1.0 - t[2 * c + 1] as f32));
                self.corner_uvs.push([uv(0), uv(k), uv(k + 1)]);
            }
        }
        Ok(())
    }

    /// Expand triangle strips separated by -1, flipping every other triangle to keep the winding.
    fn strip(&mut self, indices: &[i64], e: &Element, record: u64) -> Result<()> {
        for &v in indices.iter().filter(|&&v| v != -1) {
            self.check_index(v, e, record)?;
        }
        let before = self.triangles.len();
        for strip in indices.split(|&v| v == -1) {
            for k in 2..strip.len() {
                let [a, b, c] = [strip[k - 2], strip[k - 1], strip[k]].map(|v| v as u32);
                self.triangles.push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
            }
        }
        if self.face_uvs && self.triangles.len() > before {
            self.lacking_uvs += 1;
            self.corner_uvs.resize(self.corner_uvs.len() + self.triangles.len() - before, [NO_UV; 3]);
        }
        Ok(())
    }

    fn finish(self, texture_files: &[String], warnings: &mut Vec<String>) -> Mesh {
        self.warn(warnings);
        let uvs = if self.vertex_uvs { per_corner(&self.triangles, &self.uvs) } else { self.corner_uvs.into_iter().flatten().collect() };
        // One material per texture file; faces pick theirs by `texnumber`.
        let (materials, face_materials) = if texture_files.is_empty() {
            (vec![Material::default()], vec![0; self.triangles.len()])
        } else {
            let n = texture_files.len();
            let faces = (0..self.triangles.len()).map(|f| texture_material(self.texnumbers.get(f).copied(), n)).collect();
            (texture_materials(texture_files), faces)
        };
        Mesh {
            normals: per_corner(&self.triangles, &self.normals),
            colors: per_corner(&self.triangles, &self.colors),
            uvs,
            face_materials,
            materials,
            positions: self.positions,
            triangles: self.triangles,
            ..Default::default()
        }
    }
}

/// Copy a per-vertex attribute (empty = absent) onto each triangle corner.
fn per_corner<T: Copy>(triangles: &[[u32; 3]], a: &[T]) -> Vec<T> {
    if a.is_empty() {
        return Vec::new();
    }
    triangles.iter().flat_map(|t| t.map(|v| a[v as usize])).collect()
}

fn skip_property<S: Source>(src: &mut S, p: &Property) -> Read<()> {
    match p.kind {
        Kind::Scalar(t) => src.skip(t, 1),
        Kind::List(c, t) => {
            let n = src.list_len(c, t)?;
            src.skip(t, n)
        }
    }
}

fn read_list<S: Source, T>(
    src: &mut S,
    count: Scalar,
    item: Scalar,
    out: &mut Vec<T>,
    value: impl Fn(&mut S, Scalar) -> Read<T>,
) -> Read<()> {
    let n = src.list_len(count, item)?;
    out.reserve(n);
    for _ in 0..n {
        out.push(value(src, item)?);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use byteorder::WriteBytesExt;

    fn path() -> &'static Path {
        Path::new("test.ply")
    }

    fn ok_warn(bytes: &[u8]) -> (Mesh, Vec<String>) {
        let mut warnings = Vec::new();
        let mesh = parse(path(), bytes, &mut warnings).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(mesh.validate(), Ok(()));
        (mesh, warnings)
    }

    fn ok(bytes: &[u8]) -> Mesh {
        ok_warn(bytes).0
    }

    fn err(bytes: &[u8]) -> Error {
        match parse(path(), bytes, &mut Vec::new()) {
            Ok(m) => panic!("expected an error, got {} faces", m.face_count()),
            Err(e) => e,
        }
    }

    fn at_line(e: &Error) -> usize {
        match e.location() {
            Some(Location::Line(n)) => *n,
            other => panic!("expected a line, got {other:?}: {e}"),
        }
    }

    fn at_byte(e: &Error) -> u64 {
        match e.location() {
            Some(Location::Byte(n)) => *n,
            other => panic!("expected a byte offset, got {other:?}: {e}"),
        }
    }

    fn at_element(e: &Error) -> String {
        match e.location() {
            Some(Location::Element(s)) => s.clone(),
            other => panic!("expected an element, got {other:?}: {e}"),
        }
    }

    /// A typed value for building files.
    #[derive(Clone, Copy, Debug)]
    enum V {
        C(i8),
        Uc(u8),
        S(i16),
        Us(u16),
        I(i32),
        Ui(u32),
        F(f32),
        D(f64),
    }

    fn ascii_token(v: V) -> String {
        match v {
            V::C(x) => x.to_string(),
            V::Uc(x) => x.to_string(),
            V::S(x) => x.to_string(),
            V::Us(x) => x.to_string(),
            V::I(x) => x.to_string(),
            V::Ui(x) => x.to_string(),
            V::F(x) => x.to_string(),
            V::D(x) => x.to_string(),
        }
    }

    fn put<B: ByteOrder>(out: &mut Vec<u8>, v: V) {
        match v {
            V::C(x) => out.write_i8(x),
            V::Uc(x) => out.write_u8(x),
            V::S(x) => out.write_i16::<B>(x),
            V::Us(x) => out.write_u16::<B>(x),
            V::I(x) => out.write_i32::<B>(x),
            V::Ui(x) => out.write_u32::<B>(x),
            V::F(x) => out.write_f32::<B>(x),
            V::D(x) => out.write_f64::<B>(x),
        }
        .unwrap();
    }

    /// A PLY file from header lines (without `ply`, `format` and `end_header`) and records, one
    /// record per inner slice.
    fn file(encoding: Encoding, header: &[&str], records: &[Vec<V>]) -> Vec<u8> {
        let format = match encoding {
            Encoding::Ascii => "ascii",
            Encoding::Little => "binary_little_endian",
            Encoding::Big => "binary_big_endian",
        };
        let mut out = format!("ply\nformat {format} 1.0\n{}\nend_header\n", header.join("\n")).into_bytes();
        for r in records {
            match encoding {
                Encoding::Ascii => {
                    let tokens: Vec<String> = r.iter().map(|&v| ascii_token(v)).collect();
                    out.extend_from_slice(tokens.join(" ").as_bytes());
                    out.push(b'\n');
                }
                Encoding::Little => r.iter().for_each(|&v| put::<LittleEndian>(&mut out, v)),
                Encoding::Big => r.iter().for_each(|&v| put::<BigEndian>(&mut out, v)),
            }
        }
        out
    }

    const ALL: [Encoding; 3] = [Encoding::Ascii, Encoding::Little, Encoding::Big];

    /// A quad (0.5 in double coordinates), uchar colors, normals, (s,t) UVs, an extra vertex
    /// property, and an unrelated element with a list before the vertices.
    fn quad(encoding: Encoding) -> Vec<u8> {
        let header = [
            "comment made by hand",
            "obj_info nothing",
            "element material 2",
            "property list uchar float rgb",
            "property int id",
            "element vertex 4",
            "property double x",
            "property double y",
            "property double z",
            "property float confidence",
            "property float nx",
            "property float ny",
            "property float nz",
            "property uchar red",
            "property uchar green",
            "property uchar blue",
            "property float s",
            "property float t",
            "element face 1",
            "property list uchar int vertex_indices",
        ];
        let vertex = |x: f64, y: f64, c: u8| {
            vec![
                V::D(x),
                V::D(y),
                V::D(0.5),
                V::F(0.25),
                V::F(0.0),
                V::F(0.0),
                V::F(1.0),
                V::Uc(c),
                V::Uc(2 * c),
                V::Uc(255),
                V::F(x as f32),
                V::F(y as f32),
            ]
        };
        let records = [
            vec![V::Uc(3), V::F(0.1), V::F(0.2), V::F(0.3), V::I(7)],
            vec![V::Uc(0), V::I(8)],
            vertex(0.0, 0.0, 10),
            vertex(1.0, 0.0, 20),
            vertex(1.0, 1.0, 30),
            vertex(0.0, 1.0, 40),
            vec![V::Uc(4), V::I(0), V::I(1), V::I(2), V::I(3)],
        ];
        file(encoding, &header, &records)
    }

    #[test]
    fn reads_quad_with_attributes_in_every_encoding() {
        for encoding in ALL {
            let m = ok(&quad(encoding));
            assert_eq!(m.positions, vec![Vec3::new(0., 0., 0.5), Vec3::new(1., 0., 0.5), Vec3::new(1., 1., 0.5), Vec3::new(0., 1., 0.5)]);
            assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]], "{encoding:?}");
            assert_eq!(m.normals, vec![Vec3::Z; 6]);
            let color = |c: u8| [c, 2 * c, 255, 255];
            assert_eq!(m.colors, [10, 20, 30, 10, 30, 40].map(color).to_vec());
            let uv = |x: f32, y: f32| Vec2::new(x, 1.0 - y);
            assert_eq!(m.uvs, vec![uv(0., 0.), uv(1., 0.), uv(1., 1.), uv(0., 0.), uv(1., 1.), uv(0., 1.)]);
            assert_eq!(m.face_materials, vec![0, 0]);
        }
    }

    #[test]
    fn float_colors_are_scaled_rounded_and_clamped() {
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "property float diffuse_red",
            "property float diffuse_green",
            "property float diffuse_blue",
            "property double alpha",
            "element face 1",
            "property list uchar uint vertex_indices",
        ];
        let v = |x: f32, r: f32, g: f32, b: f32, a: f64| vec![V::F(x), V::F(x * x), V::F(0.0), V::F(r), V::F(g), V::F(b), V::D(a)];
        let records = [
            v(0., 0.5, 1.5, -0.2, 1.0),
            v(1., 0.0, 1.0, 0.1, 0.0),
            v(2., 0.999, 0.002, 0.5, 0.5),
            vec![V::Uc(3), V::Ui(0), V::Ui(1), V::Ui(2)],
        ];
        for encoding in ALL {
            let m = ok(&file(encoding, &header, &records));
            assert_eq!(m.colors, vec![[128, 255, 0, 255], [0, 255, 26, 0], [255, 1, 128, 128]], "{encoding:?}");
        }
    }

    #[test]
    fn every_uv_naming_is_recognised() {
        for (u, v) in UV_NAMES {
            let header = [
                "element vertex 3",
                "property float x",
                "property float y",
                "property float z",
                &format!("property float {u}"),
                &format!("property float {v}"),
                "element face 1",
                "property list uchar int vertex_indices",
            ];
            let vert = |x: f32| vec![V::F(x), V::F(1.0 - x), V::F(x * x), V::F(x), V::F(2.0 * x)];
            let records = [vert(0.0), vert(0.5), vert(1.0), vec![V::Uc(3), V::I(2), V::I(1), V::I(0)]];
            let m = ok(&file(Encoding::Little, &header, &records));
            assert_eq!(m.uvs, vec![Vec2::new(1., -1.), Vec2::new(0.5, 0.), Vec2::new(0., 1.)], "{u},{v} (v flipped)");
        }
    }

    /// A triangle and a pentagon over five vertices, with the given count and index types.
    fn polygons(count: &str, index: &str, c: fn(usize) -> V, i: fn(u32) -> V) -> Vec<u8> {
        let header = [
            "element vertex 5".to_string(),
            "property float32 x".into(),
            "property float32 y".into(),
            "property float32 z".into(),
            "element face 2".into(),
            format!("property list {count} {index} vertex_index"),
        ];
        let header: Vec<&str> = header.iter().map(String::as_str).collect();
        let mut records: Vec<Vec<V>> = (0..5).map(|k| vec![V::F(k as f32), V::F((k * k) as f32), V::F(1.0)]).collect();
        records.push(vec![c(3), i(4), i(3), i(2)]);
        records.push(vec![c(5), i(0), i(1), i(2), i(3), i(4)]);
        file(Encoding::Little, &header, &records)
    }

    #[test]
    fn reads_any_integer_count_and_index_types() {
        let expected = vec![[4, 3, 2], [0, 1, 2], [0, 2, 3], [0, 3, 4]];
        type Case = (&'static str, &'static str, fn(usize) -> V, fn(u32) -> V);
        let cases: [Case; 6] = [
            ("uint8", "int32", |n| V::Uc(n as u8), |v| V::I(v as i32)),
            ("ushort", "ushort", |n| V::Us(n as u16), |v| V::Us(v as u16)),
            ("char", "uint", |n| V::C(n as i8), |v| V::Ui(v)),
            ("int", "uchar", |n| V::I(n as i32), |v| V::Uc(v as u8)),
            ("uint32", "int16", |n| V::Ui(n as u32), |v| V::S(v as i16)),
            ("short", "int8", |n| V::S(n as i16), |v| V::C(v as i8)),
        ];
        for (count, index, c, i) in cases {
            let m = ok(&polygons(count, index, c, i));
            assert_eq!(m.triangles, expected, "{count} {index}");
            assert_eq!(m.positions[3], Vec3::new(3., 9., 1.));
            assert!(m.normals.is_empty() && m.colors.is_empty() && m.uvs.is_empty());
        }
    }

    #[test]
    fn reads_tristrips_with_restarts_and_degenerates() {
        let header = [
            "element vertex 7",
            "property float x",
            "property float y",
            "property float z",
            "element tristrips 1",
            "property list int int vertex_indices",
        ];
        let mut records: Vec<Vec<V>> = (0..7).map(|k| vec![V::F(k as f32), V::F((k % 2) as f32), V::F(0.0)]).collect();
        let strip = [0, 1, 2, 3, -1, 4, 5, 6, -1, 0, 1, 1, 2, -1];
        records.push(std::iter::once(V::I(strip.len() as i32)).chain(strip.iter().map(|&v| V::I(v))).collect());
        for encoding in ALL {
            let m = ok(&file(encoding, &header, &records));
            assert_eq!(m.triangles, vec![[0, 1, 2], [2, 1, 3], [4, 5, 6], [0, 1, 1], [1, 1, 2]], "{encoding:?}");
        }
    }

    #[test]
    fn face_texcoords_become_corner_uvs() {
        let header = [
            "element face 2",
            "property uchar flags",
            "property list uchar int vertex_indices",
            "property list uchar float texcoord",
            "element vertex 4",
            "property float x",
            "property float y",
            "property float z",
        ];
        let records = [
            vec![V::Uc(1), V::Uc(3), V::I(0), V::I(1), V::I(2), V::Uc(6), V::F(0.), V::F(0.), V::F(1.), V::F(0.), V::F(1.), V::F(1.)],
            vec![V::Uc(1), V::Uc(3), V::I(0), V::I(2), V::I(3), V::Uc(6), V::F(0.), V::F(0.), V::F(1.), V::F(1.), V::F(0.), V::F(1.)],
            vec![V::F(0.), V::F(0.), V::F(0.)],
            vec![V::F(1.), V::F(0.), V::F(0.)],
            vec![V::F(1.), V::F(1.), V::F(0.)],
            vec![V::F(0.), V::F(1.), V::F(0.)],
        ];
        for encoding in ALL {
            let m = ok(&file(encoding, &header, &records));
            assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
            let uv = |x: f32, y: f32| Vec2::new(x, 1.0 - y);
            assert_eq!(m.uvs, vec![uv(0., 0.), uv(1., 0.), uv(1., 1.), uv(0., 0.), uv(1., 1.), uv(0., 1.)], "{encoding:?}");
        }
    }

    #[test]
    fn short_faces_are_skipped_with_a_warning() {
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element face 3",
            "property list uchar int vertex_indices",
        ];
        let v = |x: f32| vec![V::F(x), V::F(x * x), V::F(0.)];
        let records = [v(0.), v(1.), v(2.), vec![V::Uc(2), V::I(0), V::I(1)], vec![V::Uc(3), V::I(0), V::I(1), V::I(2)], vec![V::Uc(0)]];
        for encoding in ALL {
            let (m, warnings) = ok_warn(&file(encoding, &header, &records));
            assert_eq!(m.triangles, vec![[0, 1, 2]]);
            assert_eq!(warnings, vec!["skipped 2 faces with fewer than 3 vertices".to_string()]);
        }
    }

    #[test]
    fn crlf_header_and_unknown_lines_are_tolerated() {
        let text = "ply\r\nformat ascii 1.0\r\ncomment x\r\nmade by something\r\nelement vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n0 0 0\r\n1 0 0\r\n0 1 0\r\n3 0 1 2\r\n";
        let (m, warnings) = ok_warn(text.as_bytes());
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].starts_with("line 4:"), "{warnings:?}");
        // Binary data starts right after the CRLF.
        let mut bin = b"ply\r\nformat binary_big_endian 1.0\r\nelement vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n".to_vec();
        for x in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
            bin.write_f32::<BigEndian>(x).unwrap();
        }
        bin.push(3);
        for i in [0, 1, 2] {
            bin.write_i32::<BigEndian>(i).unwrap();
        }
        assert_eq!(ok(&bin).positions[2], Vec3::Y);
    }

    fn triangle_file(encoding: Encoding) -> Vec<u8> {
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element face 2",
            "property list uchar int vertex_indices",
        ];
        let v = |x: f32| vec![V::F(x), V::F(x * x), V::F(0.)];
        file(
            encoding,
            &header,
            &[v(0.), v(1.), v(2.), vec![V::Uc(3), V::I(0), V::I(1), V::I(2)], vec![V::Uc(3), V::I(2), V::I(1), V::I(0)]],
        )
    }

    #[test]
    fn header_errors_name_the_line() {
        assert_eq!(at_byte(&err(b"")), 0);
        assert_eq!(at_line(&err(b"plx\nformat ascii 1.0\nend_header\n")), 1);
        assert_eq!(at_line(&err(&[0xff, 0xfe, b'\n'])), 1);
        let good = String::from_utf8(triangle_file(Encoding::Ascii)).unwrap();
        for (from, to, line) in [
            ("format ascii 1.0", "format binary 1.0", 2),
            ("format ascii 1.0", "format ascii 2.0", 2),
            ("format ascii 1.0", "format ascii", 2),
            ("format ascii 1.0", "comment no format", 9),
            ("property float y", "property float128 y", 5),
            ("property list uchar int", "property list float int", 8),
            ("property list uchar int", "property list uchar float", 7),
            ("property list uchar int", "property list uchar", 8),
            ("element vertex 3", "element vertex -3", 3),
            ("element vertex 3", "property float w\nelement vertex 3", 3),
            ("property float z", "property float w", 3),
            ("vertex_indices", "corners", 7),
        ] {
            let e = err(good.replacen(from, to, 1).as_bytes());
            assert_eq!(at_line(&e), line, "{to}: {e}");
        }
        let e = err(good.replacen("end_header", "end_headers", 1).as_bytes());
        assert!(e.to_string().contains("no end_header"), "{e}");
        assert!(at_line(&e) > 9);
    }

    #[test]
    fn lying_counts_fail_before_allocating() {
        for encoding in ALL {
            let good = triangle_file(encoding);
            let header_len = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            for (from, to, line, element) in [
                ("element vertex 3", "element vertex 1000000000000000", 3, "vertex 5"),
                ("element face 2", "element face 1000000000000000", 7, "face 26"),
                ("vertex_indices", "vertex_indices\nelement junk 18446744073709551615\nproperty list uchar int x", 9, "junk 24"),
            ] {
                let header = String::from_utf8(good[..header_len].to_vec()).unwrap();
                let mut bytes = header.replacen(from, to, 1).into_bytes();
                bytes.extend_from_slice(&good[header_len..]);
                let e = err(&bytes);
                assert!(e.to_string().contains(&format!("(header line {line}) declares")), "{e}");
                if encoding == Encoding::Ascii {
                    assert_eq!(at_line(&e), line, "{to}: {e}");
                } else {
                    assert_eq!(at_byte(&e), bytes.len() as u64, "{to}: {e}");
                    assert!(e.to_string().contains(&format!("file ends in {element}:")), "{e}");
                }
            }
        }
    }

    #[test]
    fn truncated_binary_names_offset_and_element() {
        let good = triangle_file(Encoding::Little);
        let start = good.len() - 3 * 12 - 2 * 13;
        // Cut inside vertex 2 (caught from the header counts), then inside face 1's indices (caught
        // at its list length).
        let e = err(&good[..start + 2 * 12 + 9]);
        assert_eq!(at_byte(&e), (start + 2 * 12 + 9) as u64);
        assert!(e.to_string().contains("file ends in vertex 2:"), "{e}");
        let e = err(&good[..good.len() - 6]);
        assert_eq!(at_byte(&e), (good.len() - 13) as u64, "{e}");
        assert!(e.to_string().contains("list length 3 in face 1 (property vertex_indices) runs past the end"), "{e}");
        // Cut inside a value after a list.
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element face 2",
            "property list uchar int vertex_indices",
            "property int flags",
        ];
        let v = |x: f32| vec![V::F(x), V::F(x * x), V::F(0.)];
        let face = vec![V::Uc(3), V::I(0), V::I(1), V::I(2), V::I(-1)];
        let bytes = file(Encoding::Little, &header, &[v(0.), v(1.), v(2.), face.clone(), face]);
        let e = err(&bytes[..bytes.len() - 2]);
        assert_eq!(at_byte(&e), (bytes.len() - 4) as u64, "{e}");
        assert!(e.to_string().contains("file ends inside face 1 (property flags)"), "{e}");
    }

    #[test]
    fn bad_ascii_tokens_name_the_line() {
        let good = String::from_utf8(triangle_file(Encoding::Ascii)).unwrap();
        for (from, to, line) in [("\n1 1 0\n", "\n1 one 0\n", 11), ("\n3 2 1 0\n", "\n3 2 1.5 0\n", 14), ("\n3 2 1 0\n", "\n3 2 1\n", 14)] {
            let e = err(good.replacen(from, to, 1).as_bytes());
            assert_eq!(at_line(&e), line, "{to}: {e}");
        }
        let e = err(good.replacen("\n3 2 1 0\n", "\n-3 2 1 0\n", 1).as_bytes());
        assert_eq!(at_line(&e), 14);
        assert!(e.to_string().contains("list length -3"), "{e}");
    }

    #[test]
    fn ascii_records_are_one_per_line_and_read_to_the_last_byte() {
        let good = String::from_utf8(triangle_file(Encoding::Ascii)).unwrap();
        // Blank lines, trailing blanks and CRLF line ends are fine.
        for text in [good.replacen("\n1 1 0\n", "\n\n 1 1 0 \t\n\n", 1), good.replace("\n3", "\r\n3"), format!("{good} ")] {
            assert_eq!(ok(text.as_bytes()).face_count(), 2, "{text}");
        }
        // Cut right after the last value, after a blank, and inside a value.
        for (cut, what) in [(1, "'0' in face 1"), (2, "file ends inside face 1"), (3, "in face 1")] {
            let e = err(&good.as_bytes()[..good.len() - cut]);
            assert_eq!(at_line(&e), 14, "{e}");
            assert!(e.to_string().contains(what), "{e}");
        }
        let cases = [
            ("\n1 1 0\n", "\n1 1 0 5\n", 11, "element vertex has 3 properties but the line has 4 values, more than vertex 1"),
            ("\n3 2 1 0\n", "\n3 2 1 0 2\n", 14, "element face has 1 property but the line has 5 values, more than face 1"),
            ("\n1 1 0\n", "\n1 1\n0\n", 11, "the line ends inside vertex 1 (property z)"),
            ("\n3 0 1 2\n", "\n3 0 1\n2\n", 13, "the line ends inside face 0 (property vertex_indices)"),
        ];
        for (from, to, line, what) in cases {
            let e = err(good.replacen(from, to, 1).as_bytes());
            assert_eq!(at_line(&e), line, "{e}");
            assert!(e.to_string().contains(what), "{e}");
        }
    }

    /// `bytes` read by [`stream`] from a file: its triangles, or its error.
    fn streamed(bytes: &[u8]) -> Result<Vec<[u32; 3]>> {
        let path = std::env::temp_dir().join(format!("strata-ply-stream-{}-{:x}.ply", std::process::id(), crc32fast::hash(bytes)));
        std::fs::write(&path, bytes).unwrap();
        let mut tris = Vec::new();
        let r = stream(
            &path,
            &Default::default(),
            &mut |_, t| {
                tris.extend_from_slice(t.triangles);
                Ok(())
            },
            &mut Vec::new(),
        );
        let _ = std::fs::remove_file(&path);
        r.map(|_| tris)
    }

    #[test]
    fn streaming_reads_what_a_whole_read_reads_and_fails_where_it_fails() {
        let good = String::from_utf8(triangle_file(Encoding::Ascii)).unwrap();
        let mut inputs: Vec<Vec<u8>> = vec![triangle_file(Encoding::Little), triangle_file(Encoding::Big), good.clone().into_bytes()];
        for text in [good.replacen("\n1 1 0\n", "\n\n 1 1 0 \t\n\n", 1), good.replace("\n3", "\r\n3"), format!("{good} ")] {
            inputs.push(text.into_bytes());
        }
        for cut in 1..4 {
            inputs.push(good.as_bytes()[..good.len() - cut].to_vec());
        }
        for (from, to) in
            [("\n1 1 0\n", "\n1 1 0 5\n"), ("\n3 2 1 0\n", "\n3 2 1 0 2\n"), ("\n1 1 0\n", "\n1 1\n0\n"), ("\n3 0 1 2\n", "\n3 0 1 9\n")]
        {
            inputs.push(good.replacen(from, to, 1).into_bytes());
        }
        let binary = triangle_file(Encoding::Little);
        inputs.push(binary[..binary.len() - 3].to_vec());
        for bytes in inputs {
            let whole = parse(path(), &bytes, &mut Vec::new());
            match (whole, streamed(&bytes)) {
                (Ok(m), Ok(t)) => assert_eq!(m.triangles, t),
                (Err(a), Err(b)) => {
                    assert_eq!(a.location(), b.location(), "{a} / {b}");
                    let tail = |e: &Error| e.to_string().split_once(": ").map(|x| x.1.to_string()).unwrap_or_default();
                    assert_eq!(tail(&a), tail(&b));
                }
                (a, b) => panic!("whole read {:?}, stream {:?}", a.map(|m| m.face_count()), b.map(|t| t.len())),
            }
        }
    }

    /// What [`stream`] gives for the file `path`, as the whole-file reader's mesh: triangles,
    /// corner UVs, face materials, materials and images; and its warnings.
    fn streamed_mesh(path: &Path) -> (Mesh, Vec<String>) {
        let (mut m, mut warnings) = (Mesh::default(), Vec::new());
        let looks = stream(
            path,
            &Default::default(),
            &mut |_, f| {
                assert!(f.normals.is_empty());
                m.triangles.extend_from_slice(f.triangles);
                m.uvs.extend(f.uvs.iter().flatten());
                m.face_materials.extend_from_slice(f.materials);
                Ok(())
            },
            &mut warnings,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        (m.materials, m.images) = (looks.materials, looks.images);
        (m, warnings)
    }

    /// A new folder `name` in the temporary folder holding a 2 × 2 PNG, `a.png`.
    fn folder_with_image(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let png = crate::texture::encode(crate::texture::ImageCodec::Png, &crate::texture::Rgba8::new(2, 2), 90).unwrap();
        std::fs::write(dir.join("a.png"), &png).unwrap();
        dir
    }

    #[test]
    fn textured_files_stream_as_they_read_whole() {
        let dir = folder_with_image("strata-ply-tex-stream");
        let vertices = |uvs: bool| -> Vec<Vec<V>> {
            [(0., 0.), (1., 0.), (1., 1.), (0., 1.), (2., 0.)]
                .iter()
                .map(|&(x, y)| {
                    let mut r = vec![V::F(x), V::F(y), V::F(0.)];
                    if uvs {
                        r.extend([V::F(x / 2.), V::F(y)]);
                    }
                    r
                })
                .collect()
        };
        let xyz = ["property float x", "property float y", "property float z"];
        // Per-vertex UVs.
        let mut per_vertex: Vec<&str> = vec!["element vertex 5"];
        per_vertex.extend(xyz);
        per_vertex.extend(["property float s", "property float t", "element face 2", "property list uchar int vertex_indices"]);
        let mut records = vertices(true);
        records.extend([vec![V::Uc(4), V::I(0), V::I(1), V::I(2), V::I(3)], vec![V::Uc(3), V::I(1), V::I(4), V::I(2)]]);
        let mut files =
            vec![("vertex", file(Encoding::Little, &per_vertex, &records)), ("vertex-ascii", file(Encoding::Ascii, &per_vertex, &records))];
        // MeshLab's convention: texture files, texcoord lists and texnumbers; the second face's
        // list is short, the third names a file that is missing, the fourth one out of range.
        let mut per_face: Vec<&str> = vec!["comment TextureFile a.png", "comment TextureFile missing.png", "element vertex 5"];
        per_face.extend(xyz);
        per_face.extend([
            "element face 4",
            "property list uchar int vertex_indices",
            "property list uchar float texcoord",
            "property int texnumber",
        ]);
        let face = |ix: &[i32], t: &[f32], n: i32| -> Vec<V> {
            let mut r = vec![V::Uc(ix.len() as u8)];
            r.extend(ix.iter().map(|&i| V::I(i)));
            r.push(V::Uc(t.len() as u8));
            r.extend(t.iter().map(|&x| V::F(x)));
            r.push(V::I(n));
            r
        };
        let mut records = vertices(false);
        records.extend([
            face(&[0, 1, 2, 3], &[0., 0., 0.5, 0., 0.5, 1., 0., 1.], 0),
            face(&[1, 4, 2], &[0.5, 0.], 0),
            face(&[0, 2, 3], &[0.1, 0.2, 0.3, 0.4, 0.5, 0.6], 1),
            face(&[1, 4, 2], &[0.5, 0., 1., 0., 0.5, 1.], 7),
        ]);
        for encoding in ALL {
            files.push(("face", file(encoding, &per_face, &records)));
        }
        for (name, bytes) in files {
            let path = dir.join("m.ply");
            std::fs::write(&path, &bytes).unwrap();
            let mut warnings = Vec::new();
            let whole = read(&path, &ImportOptions::default(), &mut warnings).unwrap().mesh;
            let (m, stream_warnings) = streamed_mesh(&path);
            assert_eq!(m.triangles, whole.triangles, "{name}");
            assert_eq!(m.uvs, whole.uvs, "{name}");
            assert_eq!(m.uvs.len(), 3 * m.triangles.len(), "{name}");
            assert_eq!(stream_warnings, warnings, "{name}");
            if name == "vertex" || name == "vertex-ascii" {
                assert!(m.materials.is_empty() && m.face_materials.is_empty(), "{name}: one default material");
                assert_eq!(whole.materials, vec![Material::default()]);
                continue;
            }
            assert_eq!(m.face_materials, whole.face_materials, "{name}");
            assert_eq!(m.face_materials, vec![0, 0, 0, 1, 0]);
            assert_eq!(m.materials, whole.materials, "{name}");
            assert_eq!(m.images.len(), 1);
            assert!(m.images == whole.images, "{name}");
            assert_eq!(m.uvs[6..9], [NO_UV; 3], "a short list gives (0, 0) corners");
            assert!(warnings.iter().any(|w| w.starts_with("1 faces have no texcoord list")), "{warnings:?}");
            assert!(warnings.iter().any(|w| w.contains("missing.png")), "{warnings:?}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn declared_triangles_count_polygon_corners_in_binary_files() {
        let header = [
            "element vertex 4",
            "property float x",
            "property float y",
            "property float z",
            "element face 2",
            "property list uchar int vertex_indices",
        ];
        let v = |x: f32, y: f32| vec![V::F(x), V::F(y), V::F(0.)];
        let records = [
            v(0., 0.),
            v(1., 0.),
            v(1., 1.),
            v(0., 1.),
            vec![V::Uc(4), V::I(0), V::I(1), V::I(2), V::I(3)],
            vec![V::Uc(3), V::I(0), V::I(1), V::I(2)],
        ];
        for (encoding, expect) in [(Encoding::Little, 3), (Encoding::Ascii, 2)] {
            let path = std::env::temp_dir().join(format!("strata-ply-declared-{}-{encoding:?}.ply", std::process::id()));
            std::fs::write(&path, file(encoding, &header, &records)).unwrap();
            let d = declared(&path).unwrap();
            let _ = std::fs::remove_file(&path);
            assert_eq!((d.faces, d.vertices, d.triangles), (2, 4, expect), "{encoding:?}");
        }
    }

    #[test]
    fn bad_list_lengths_name_the_byte() {
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element face 1",
            "property list int int vertex_indices",
        ];
        let v = |x: f32| vec![V::F(x), V::F(x * x), V::F(0.)];
        for n in [-5, 1_000_000, i32::MAX] {
            let bytes = file(Encoding::Little, &header, &[v(0.), v(1.), v(2.), vec![V::I(n), V::I(0), V::I(1), V::I(2)]]);
            let e = err(&bytes);
            assert_eq!(at_byte(&e), (bytes.len() - 16) as u64, "{e}");
            assert!(e.to_string().contains(&format!("list length {n} in face 0 (property vertex_indices)")), "{e}");
        }
    }

    #[test]
    fn bad_indices_and_coordinates_name_the_element() {
        let header = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property double z",
            "element face 2",
            "property list uchar int vertex_indices",
        ];
        let v = |z: f64| vec![V::F(0.), V::F(1.), V::D(z)];
        let tri = |a: i32| vec![V::Uc(3), V::I(0), V::I(1), V::I(a)];
        for encoding in ALL {
            for bad in [3, -1, i32::MAX] {
                let e = err(&file(encoding, &header, &[v(0.), v(1.), v(2.), tri(2), tri(bad)]));
                assert_eq!(at_element(&e), "face 1", "{e}");
            }
            for z in [f64::INFINITY, 1e300] {
                let e = err(&file(encoding, &header, &[v(0.), v(z), v(2.), tri(2), tri(2)]));
                assert_eq!(at_element(&e), "vertex 1", "{e}");
            }
        }
        for encoding in [Encoding::Little, Encoding::Big] {
            let e = err(&file(encoding, &header, &[v(0.), v(1.), v(f64::NAN), tri(2), tri(2)]));
            assert_eq!(at_element(&e), "vertex 2", "{e}");
        }
        let e = err(&quad(Encoding::Ascii).iter().map(|&b| if b == b'0' { b'x' } else { b }).collect::<Vec<u8>>());
        assert!(matches!(e.location(), Some(Location::Line(_))), "{e}");
        let strips = [
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element tristrips 1",
            "property list int int vertex_indices",
        ];
        let w = |x: f32| vec![V::F(x), V::F(1.), V::F(0.)];
        let e = err(&file(Encoding::Ascii, &strips, &[w(0.), w(1.), w(2.), vec![V::I(4), V::I(0), V::I(1), V::I(-2), V::I(2)]]));
        assert_eq!(at_element(&e), "tristrips 0", "{e}");
    }

    #[test]
    fn point_clouds_are_rejected_clearly() {
        let cloud = file(
            Encoding::Ascii,
            &["element vertex 2", "property float x", "property float y", "property float z"],
            &[vec![V::F(0.); 3], vec![V::F(1.); 3]],
        );
        let e = err(&cloud);
        assert!(e.to_string().contains("point cloud: 2 vertices and no faces"), "{e}");
        let empty_faces = String::from_utf8(triangle_file(Encoding::Ascii)).unwrap().replacen("element face 2", "element face 0", 1);
        let e = err(empty_faces.as_bytes());
        assert!(e.to_string().contains("point cloud: 3 vertices"), "{e}");
    }

    #[test]
    fn elements_after_the_mesh_are_not_needed_and_order_is_free() {
        let header = [
            "element face 1",
            "property list uchar int vertex_indices",
            "element vertex 3",
            "property float x",
            "property float y",
            "property float z",
            "element edge 1",
            "property int a",
        ];
        let v = |x: f32| vec![V::F(x), V::F(x * x), V::F(0.)];
        for encoding in ALL {
            let m = ok(&file(encoding, &header, &[vec![V::Uc(3), V::I(2), V::I(0), V::I(1)], v(0.), v(1.), v(2.), vec![V::I(9)]]));
            assert_eq!(m.triangles, vec![[2, 0, 1]]);
            assert_eq!(m.positions[2], Vec3::new(2., 4., 0.));
        }
    }

    /// Every prefix and every single-byte corruption of valid files parses or fails; none panics.
    #[test]
    fn truncations_and_flips_never_panic() {
        for bytes in [quad(Encoding::Little), quad(Encoding::Big), quad(Encoding::Ascii), triangle_file(Encoding::Little)] {
            for len in 0..=bytes.len() {
                let _ = parse(path(), &bytes[..len], &mut Vec::new());
            }
            for i in 0..bytes.len() {
                for mask in [0x01, 0x10, 0x80, 0xff] {
                    let mut b = bytes.clone();
                    b[i] ^= mask;
                    if let Ok(m) = parse(path(), &b, &mut Vec::new()) {
                        assert_eq!(m.validate(), Ok(()));
                    }
                }
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn random_edits_never_panic(edits in proptest::collection::vec((0usize..1000, proptest::num::u8::ANY), 1..8), cut in 0usize..1000) {
            for encoding in ALL {
                let mut b = quad(encoding);
                for &(i, x) in &edits {
                    let n = b.len();
                    b[i % n] = x;
                }
                b.truncate(b.len() - cut % 20);
                if let Ok(m) = parse(path(), &b, &mut Vec::new()) {
                    proptest::prop_assert_eq!(m.validate(), Ok(()));
                }
            }
        }
    }

    #[test]
    fn texture_file_comments_become_materials_with_their_images() {
        let dir = folder_with_image("strata-ply-tex");
        let text = "ply\nformat ascii 1.0\ncomment TextureFile a.png\ncomment TextureFile missing b.png\nelement vertex 4\n\
                    property float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\n\
                    property list uchar float texcoord\nproperty int texnumber\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n\
                    3 0 1 2 6 0 0 1 0 1 1 1\n3 0 2 3 6 0 0 1 1 0 1 0\n";
        let path = dir.join("m.ply");
        std::fs::write(&path, text).unwrap();
        let mut warnings = Vec::new();
        let raw = read(&path, &ImportOptions::default(), &mut warnings).unwrap();
        let m = raw.mesh;
        assert_eq!(m.materials.iter().map(|x| x.name.as_str()).collect::<Vec<_>>(), ["a.png", "missing b.png"]);
        assert_eq!(m.face_materials, vec![1, 0]);
        assert_eq!(m.images.len(), 1);
        assert_eq!(m.materials[0].map(MapKind::BaseColor).map(|s| s.image), Some(0));
        assert_eq!(m.materials[1].map(MapKind::BaseColor), None);
        assert!(warnings.iter().any(|w| w.contains("missing b.png")), "{warnings:?}");
        assert_eq!(m.uvs[0], Vec2::new(0.0, 1.0), "v flipped");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
