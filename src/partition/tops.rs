//! A piece's top level, kept in a temporary file while it waits for the next round: the tops of
//! every cell together grow with the input (a sixteenth of its faces or so), so held in memory
//! they would make the build's peak grow with it too.
//!
//! The file is plain little-endian arrays, each after its length (u64), positions first so that a
//! round can read where the tops' vertices are without reading the rest. It is read back by the
//! same process; its lengths are still checked against the file's size, so a damaged file ends
//! in an error naming it.

use crate::bounds::NodeBounds;
use crate::dag::write::Stored;
use crate::error::{Error, Result};
use crate::format::skeleton::NodeCodes;
use crate::format::Cone;
use crate::hierarchy::GroupInfo;
use crate::levels::LevelMesh;
use crate::mesh::Mesh;
use byteorder::{ReadBytesExt, WriteBytesExt, LE};
use glam::{Vec2, Vec3};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// A piece's top level, for the next round.
pub struct Top {
    pub level: LevelMesh,
    pub groups: Vec<GroupInfo>,
    pub bounds: Vec<NodeBounds>,
    /// Node key of each group.
    pub keys: Vec<u32>,
    pub max_angle: f32,
    pub max_faces: u32,
}

/// A [`Top`] in its file.
#[derive(Debug)]
pub struct Spilled {
    path: PathBuf,
    /// Faces of its level mesh.
    pub faces: usize,
}

impl Top {
    /// Write the top to a new file at `path`.
    pub fn spill(self, path: PathBuf) -> Result<Spilled> {
        let io = |e| Error::io(&path, e);
        let mut w = BufWriter::with_capacity(1 << 20, File::options().write(true).create_new(true).open(&path).map_err(io)?);
        let m = &self.level.mesh;
        let faces = m.face_count();
        put_mesh(&mut w, m).map_err(io)?;
        put(&mut w, &self.level.face_group, |w, &x| w.write_u32::<LE>(x)).map_err(io)?;
        put(&mut w, &self.level.group_error, |w, &x| w.write_f32::<LE>(x)).map_err(io)?;
        put(&mut w, &self.groups, |w, g| {
            cone(w, g.cone)?;
            vec3(w, g.center)?;
            w.write_f32::<LE>(g.radius)?;
            vec3(w, g.min)?;
            vec3(w, g.max)?;
            w.write_u32::<LE>(g.faces)?;
            w.write_f32::<LE>(g.area)?;
            vec3(w, g.area_normal)
        })
        .map_err(io)?;
        put(&mut w, &self.bounds, |w, b| {
            let c = &b.codes;
            c.min.iter().chain(&c.max).chain(&c.center).try_for_each(|&x| w.write_u32::<LE>(x))?;
            c.axis.iter().try_for_each(|&x| w.write_i16::<LE>(x))?;
            w.write_u16::<LE>(c.half_angle)?;
            w.write_u16::<LE>(c.radius)?;
            cone(w, b.cone)?;
            vec3(w, b.center)?;
            w.write_f32::<LE>(b.radius)?;
            w.write_f32::<LE>(b.error)
        })
        .map_err(io)?;
        put(&mut w, &self.keys, |w, &x| w.write_u32::<LE>(x)).map_err(io)?;
        w.write_f32::<LE>(self.max_angle).map_err(io)?;
        w.write_u32::<LE>(self.max_faces).map_err(io)?;
        w.into_inner().map_err(|e| io(e.into_error()))?;
        Ok(Spilled { path, faces })
    }
}

/// Bytes of one element of each array, as [`Top::spill`] writes them.
const GROUP_BYTES: u64 = 19 * 4;
const BOUNDS_BYTES: u64 = 9 * 4 + 2 * 2 + 2 * 2 + 9 * 4;

impl Spilled {
    /// The top's vertex positions.
    pub fn positions(&self) -> Result<Vec<Vec3>> {
        let mut r = self.open()?;
        r.array(12, |r| r.vec3())
    }

    /// Read the top back and remove its file (left for the temporary folder's removal on error).
    pub fn load(self) -> Result<Top> {
        let mut r = self.open()?;
        let m = r.mesh()?;
        let face_group = r.array(4, |r| r.u32())?;
        let group_error = r.array(4, |r| r.f32())?;
        let groups = r.array(GROUP_BYTES, |r| {
            Ok(GroupInfo {
                cone: r.cone()?,
                center: r.vec3()?,
                radius: r.f32()?,
                min: r.vec3()?,
                max: r.vec3()?,
                faces: r.u32()?,
                area: r.f32()?,
                area_normal: r.vec3()?,
            })
        })?;
        let bounds = r.array(BOUNDS_BYTES, |r| {
            let mut u = [0u32; 9];
            for x in &mut u {
                *x = r.u32()?;
            }
            let codes = NodeCodes {
                min: [u[0], u[1], u[2]],
                max: [u[3], u[4], u[5]],
                center: [u[6], u[7], u[8]],
                axis: [r.read.read_i16::<LE>()?, r.read.read_i16::<LE>()?],
                half_angle: r.read.read_u16::<LE>()?,
                radius: r.read.read_u16::<LE>()?,
            };
            Ok(NodeBounds { codes, cone: r.cone()?, center: r.vec3()?, radius: r.f32()?, error: r.f32()? })
        })?;
        let keys = r.array(4, |r| r.u32())?;
        let (max_angle, max_faces) = (r.f32().map_err(|e| r.fail(e))?, r.u32().map_err(|e| r.fail(e))?);
        if r.left != 8 {
            return Err(Error::invalid(&self.path, None, format!("{} bytes after a top", r.left.saturating_sub(8))));
        }
        let _ = std::fs::remove_file(&self.path);
        let n = m.triangles.len();
        let fits = face_group.len() == n
            && m.triangles.iter().flatten().all(|&v| (v as usize) < m.positions.len())
            && face_group.iter().all(|&g| (g as usize) < groups.len())
            && [m.normals.len(), m.uvs.len(), m.colors.len()].iter().all(|&c| c == 0 || c == 3 * n)
            && (m.face_materials.is_empty() || m.face_materials.len() == n)
            && group_error.len() == groups.len()
            && keys.len() == groups.len()
            && bounds.len() == groups.len();
        if !fits || n != self.faces {
            return Err(Error::invalid(&self.path, None, "a top's arrays do not fit together"));
        }
        Ok(Top { level: LevelMesh { mesh: m, face_group, group_error }, groups, bounds, keys, max_angle, max_faces })
    }

    fn open(&self) -> Result<Reading<'_>> {
        let file = File::open(&self.path).map_err(|e| Error::io(&self.path, e))?;
        let left = file.metadata().map_err(|e| Error::io(&self.path, e))?.len();
        Ok(Reading { read: BufReader::with_capacity(1 << 20, file), left, path: &self.path })
    }
}

/// A DAG piece's top level, for the next round ([`super::dag`]): its mesh, faces ordered by node,
/// with each vertex's grid point as the next level inherits it; per node its face count (at least
/// one), key and what it was stored with, and the index of its source among `sources` (a source's
/// nodes are a run); per source group, what it was stored with.
pub struct DagTop {
    pub mesh: Mesh,
    pub points: Vec<[u32; 3]>,
    pub faces: Vec<u32>,
    pub keys: Vec<u32>,
    pub stored: Vec<Stored>,
    pub source: Vec<u32>,
    pub sources: Vec<Stored>,
}

impl DagTop {
    /// Write the top to a new file at `path`.
    pub fn spill(self, path: PathBuf) -> Result<Spilled> {
        let io = |e| Error::io(&path, e);
        let mut w = BufWriter::with_capacity(1 << 20, File::options().write(true).create_new(true).open(&path).map_err(io)?);
        let m = &self.mesh;
        let faces = m.face_count();
        put_mesh(&mut w, m).map_err(io)?;
        put(&mut w, &self.points, |w, p| p.iter().try_for_each(|&x| w.write_u32::<LE>(x))).map_err(io)?;
        put(&mut w, &self.faces, |w, &x| w.write_u32::<LE>(x)).map_err(io)?;
        put(&mut w, &self.keys, |w, &x| w.write_u32::<LE>(x)).map_err(io)?;
        put(&mut w, &self.stored, stored).map_err(io)?;
        put(&mut w, &self.source, |w, &x| w.write_u32::<LE>(x)).map_err(io)?;
        put(&mut w, &self.sources, stored).map_err(io)?;
        w.into_inner().map_err(|e| io(e.into_error()))?;
        Ok(Spilled { path, faces })
    }
}

fn stored(w: &mut BufWriter<File>, s: &Stored) -> std::io::Result<()> {
    w.write_f32::<LE>(s.error)?;
    vec3(w, s.center)?;
    w.write_f32::<LE>(s.radius)
}

impl Spilled {
    /// Read a [`DagTop`] back and remove its file (left for the temporary folder's removal on
    /// error).
    pub fn load_dag(self) -> Result<DagTop> {
        let mut r = self.open()?;
        let mesh = r.mesh()?;
        let points = r.array(12, |r| Ok([r.u32()?, r.u32()?, r.u32()?]))?;
        let faces = r.array(4, |r| r.u32())?;
        let keys = r.array(4, |r| r.u32())?;
        let read_stored = |r: &mut Reading| Ok(Stored { error: r.f32()?, center: r.vec3()?, radius: r.f32()? });
        let stored = r.array(20, read_stored)?;
        let source = r.array(4, |r| r.u32())?;
        let sources = r.array(20, read_stored)?;
        if r.left != 0 {
            return Err(Error::invalid(&self.path, None, format!("{} bytes after a top", r.left)));
        }
        let _ = std::fs::remove_file(&self.path);
        let n = mesh.triangles.len();
        let fits = mesh.triangles.iter().flatten().all(|&v| (v as usize) < mesh.positions.len())
            && [mesh.normals.len(), mesh.uvs.len(), mesh.colors.len()].iter().all(|&c| c == 0 || c == 3 * n)
            && (mesh.face_materials.is_empty() || mesh.face_materials.len() == n)
            && points.len() == mesh.positions.len()
            && faces.iter().map(|&f| f as u64).sum::<u64>() == n as u64
            && faces.iter().all(|&f| f > 0)
            && source.windows(2).all(|w| w[0] <= w[1])
            && [keys.len(), stored.len(), source.len()].iter().all(|&c| c == faces.len())
            && source.iter().all(|&s| (s as usize) < sources.len());
        if !fits || n != self.faces {
            return Err(Error::invalid(&self.path, None, "a top's arrays do not fit together"));
        }
        Ok(DagTop { mesh, points, faces, keys, stored, source, sources })
    }
}

/// Write a mesh's vertex and face arrays (not its materials or face geometry).
fn put_mesh<W: Write>(w: &mut W, m: &Mesh) -> std::io::Result<()> {
    put(w, &m.positions, |w, p| vec3(w, *p))?;
    put(w, &m.triangles, |w, t| t.iter().try_for_each(|&i| w.write_u32::<LE>(i)))?;
    put(w, &m.normals, |w, n| vec3(w, *n))?;
    put(w, &m.uvs, |w, uv| uv.to_array().iter().try_for_each(|&x| w.write_f32::<LE>(x)))?;
    put(w, &m.colors, |w, c| w.write_all(c))?;
    put(w, &m.face_materials, |w, &x| w.write_u32::<LE>(x))
}

/// Write `items` after their count.
fn put<W: Write, T>(w: &mut W, items: &[T], mut each: impl FnMut(&mut W, &T) -> std::io::Result<()>) -> std::io::Result<()> {
    w.write_u64::<LE>(items.len() as u64)?;
    items.iter().try_for_each(|x| each(w, x))
}

fn vec3(w: &mut impl Write, v: Vec3) -> std::io::Result<()> {
    v.to_array().iter().try_for_each(|&x| w.write_f32::<LE>(x))
}

fn cone(w: &mut impl Write, c: Cone) -> std::io::Result<()> {
    vec3(w, c.axis)?;
    w.write_f32::<LE>(c.half_angle)
}

/// A top's file being read, with the bytes not yet read.
struct Reading<'a> {
    read: BufReader<File>,
    left: u64,
    path: &'a Path,
}

impl Reading<'_> {
    /// An array of `bytes`-byte elements after its count, which must fit in what is left.
    fn array<T>(&mut self, bytes: u64, mut each: impl FnMut(&mut Self) -> std::io::Result<T>) -> Result<Vec<T>> {
        let n = self.read.read_u64::<LE>().map_err(|e| self.fail(e))?;
        self.left = self.left.saturating_sub(8);
        if n.checked_mul(bytes).is_none_or(|b| b > self.left) {
            return Err(Error::invalid(self.path, None, format!("an array of {n} elements of {bytes} bytes, {} bytes left", self.left)));
        }
        self.left -= n * bytes;
        let mut out = Vec::with_capacity(n as usize);
        for _ in 0..n {
            out.push(each(self).map_err(|e| self.fail(e))?);
        }
        Ok(out)
    }

    /// A mesh as [`put_mesh`] writes it.
    fn mesh(&mut self) -> Result<Mesh> {
        let positions = self.array(12, |r| r.vec3())?;
        let triangles = self.array(12, |r| Ok([r.u32()?, r.u32()?, r.u32()?]))?;
        let normals = self.array(12, |r| r.vec3())?;
        let uvs = self.array(8, |r| Ok(Vec2::new(r.f32()?, r.f32()?)))?;
        let colors = self.array(4, |r| {
            let mut c = [0u8; 4];
            r.read.read_exact(&mut c)?;
            Ok(c)
        })?;
        let face_materials = self.array(4, |r| r.u32())?;
        Ok(Mesh { positions, triangles, normals, uvs, colors, face_materials, ..Mesh::default() })
    }

    fn fail(&self, e: std::io::Error) -> Error {
        Error::io(self.path, e)
    }

    fn u32(&mut self) -> std::io::Result<u32> {
        self.read.read_u32::<LE>()
    }

    fn f32(&mut self) -> std::io::Result<f32> {
        self.read.read_f32::<LE>()
    }

    fn vec3(&mut self) -> std::io::Result<Vec3> {
        Ok(Vec3::new(self.f32()?, self.f32()?, self.f32()?))
    }

    fn cone(&mut self) -> std::io::Result<Cone> {
        Ok(Cone { axis: self.vec3()?, half_angle: self.f32()? })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn top() -> Top {
        let mesh = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, -0.0)],
            triangles: vec![[0, 1, 2], [2, 1, 3]],
            normals: vec![Vec3::Z; 6],
            uvs: (0..6).map(|i| Vec2::new(i as f32 * 0.25, 1.0 - i as f32 * 0.125)).collect(),
            colors: (0..6).map(|i| [i, 2 * i, 255 - i, 128]).collect(),
            face_materials: vec![0, 1],
            ..Mesh::default()
        };
        let cone = Cone { axis: Vec3::Z, half_angle: 0.25 };
        let group = GroupInfo {
            cone,
            center: Vec3::splat(0.5),
            radius: 0.75,
            min: Vec3::ZERO,
            max: Vec3::new(1.0, 1.0, 0.0),
            faces: 40,
            area: 1.0,
            area_normal: Vec3::Z,
        };
        let codes = NodeCodes { min: [1, 2, 3], max: [4, 5, 6], center: [7, 8, 9], axis: [-3, 4], half_angle: 11, radius: 12 };
        let bounds = NodeBounds { codes, cone, center: Vec3::splat(0.5), radius: 0.8, error: 0.01 };
        Top {
            level: LevelMesh { mesh, face_group: vec![0, 1], group_error: vec![0.01, 0.02] },
            groups: vec![group, GroupInfo { faces: 7, ..group }],
            bounds: vec![bounds, NodeBounds { error: 0.02, ..bounds }],
            keys: vec![5, 1 << 20 | 9],
            max_angle: 0.5,
            max_faces: 64,
        }
    }

    #[test]
    fn a_top_reads_back_as_it_was_written_and_its_file_goes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("top");
        let spilled = top().spill(path.clone()).unwrap();
        assert_eq!(spilled.faces, 2);
        assert_eq!(spilled.positions().unwrap(), top().level.mesh.positions);
        let back = spilled.load().unwrap();
        let want = top();
        assert_eq!(back.level, want.level);
        assert_eq!((back.groups, back.bounds, back.keys), (want.groups, want.bounds, want.keys));
        assert_eq!((back.max_angle, back.max_faces), (0.5, 64));
        assert!(!path.exists());
    }

    #[test]
    fn a_damaged_top_file_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("top");
        top().spill(path.clone()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        for cut in [0, 7, 8, 60, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let e = Spilled { path: path.clone(), faces: 2 }.load().err().expect("a cut file fails");
            assert!(e.to_string().contains("top"), "{e}");
        }
        std::fs::write(&path, [&bytes[..], &[0; 3]].concat()).unwrap();
        let e = Spilled { path: path.clone(), faces: 2 }.load().err().expect("bytes past the end fail");
        assert!(e.to_string().contains("3 bytes after a top"), "{e}");
        let mut wrong = bytes.clone();
        wrong[12 * 4 + 8 + 8..][..4].copy_from_slice(&9u32.to_le_bytes());
        std::fs::write(&path, &wrong).unwrap();
        let e = Spilled { path: path.clone(), faces: 2 }.load().err().expect("an index past the vertices fails");
        assert!(e.to_string().contains("do not fit"), "{e}");
    }

    fn dag_top() -> DagTop {
        let s = |error: f32| Stored { error, center: Vec3::splat(0.5), radius: 0.75 };
        DagTop {
            mesh: top().level.mesh,
            points: vec![[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]],
            faces: vec![1, 1],
            keys: vec![3, 1 << 20 | 4],
            stored: vec![s(0.25), s(0.5)],
            source: vec![0, 0],
            sources: vec![s(0.5)],
        }
    }

    #[test]
    fn a_dag_top_reads_back_as_it_was_written_and_damage_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("top");
        let spilled = dag_top().spill(path.clone()).unwrap();
        assert_eq!(spilled.positions().unwrap(), dag_top().mesh.positions);
        let (back, want) = (spilled.load_dag().unwrap(), dag_top());
        assert_eq!((back.mesh, back.points, back.faces, back.keys), (want.mesh, want.points, want.faces, want.keys));
        assert_eq!((back.stored, back.source, back.sources), (want.stored, want.source, want.sources));
        assert!(!path.exists());

        dag_top().spill(path.clone()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        for cut in [0, 7, 100, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let e = Spilled { path: path.clone(), faces: 2 }.load_dag().err().expect("a cut file fails");
            assert!(e.to_string().contains("top"), "{e}");
        }
        // The last source index points past the one source group.
        let mut wrong = bytes.clone();
        let at = bytes.len() - 8 - 20 - 4;
        wrong[at..at + 4].copy_from_slice(&1u32.to_le_bytes());
        std::fs::write(&path, &wrong).unwrap();
        let e = Spilled { path: path.clone(), faces: 2 }.load_dag().err().expect("a source past the groups fails");
        assert!(e.to_string().contains("do not fit"), "{e}");
    }
}
