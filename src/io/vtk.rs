//! ParaView output: particles and the gas grid as VTK files, and `.pvd`
//! collections that make a time series of them.
//!
//! # Formats
//!
//! [`write_particles`] and [`write_gas`] choose the format from the file
//! name's extension:
//!
//! * `.vtk`: legacy VTK, `BINARY` encoding (big-endian, as the legacy format
//!   requires), file version 3.0 layout so that old and new ParaView read it.
//!   Particles are a `POLYDATA`, the gas a `STRUCTURED_POINTS`. The active
//!   scalars and vectors are `SCALARS`/`VECTORS` sections, every other array
//!   is in one `FIELD` block (VTK's legacy readers skip a second `SCALARS`
//!   unless asked, but always read `FIELD` arrays). Good for a single
//!   snapshot (`edpm replay --at`).
//! * `.vtp` (particles) / `.vti` (gas): VTK XML `PolyData` / `ImageData`,
//!   file version 1.0, all arrays in one raw little-endian `AppendedData`
//!   block, each preceded by its byte count as a `UInt64`. Use these for time
//!   series.
//!
//! Binary rather than ASCII: 8 bytes per double instead of about 20
//! characters, no float formatting on the write path, and values read back
//! bit for bit.
//!
//! A `.pvd` collection ([`PvdSeries`]) can only list VTK XML files:
//! ParaView's PVD reader (`vtkXMLCollectionReader`) picks the reader of each
//! entry from a fixed table of XML extensions (`vtp`, `vti`, `vtu`, `vtr`,
//! `vts`, `vtm`, ...; no `vtk`) and fails on anything else. So time series
//! use `.vtp`/`.vti`, and [`PvdSeries::write`] rejects other entries.
//!
//! # Arrays
//!
//! Particles (point data; one vertex cell per particle): `radius` (scalar;
//! the active scalars, for the Glyph filter's "scale by radius"), `velocity`
//! (vector, m/s; the active vectors), `speed` (scalar, m/s), `omega`
//! (vector, rad/s), `id` (uint64) and `material` (uint16).
//!
//! Gas (cell data on a uniform grid with origin `grid.lo`, spacing `grid.h`
//! and `n + 1` points per axis; cells in [`GridGeometry::cell_index`] order,
//! which is VTK's): `gas_fraction`, `solids_fraction` (1 − gas fraction),
//! `pressure`, `density`, `gas_velocity` (interstitial, the mean of the two
//! faces of each cell) and `superficial_velocity` (gas fraction × gas
//! velocity).
//!
//! Every file is written through [`write_atomic`].

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail, ensure};
use glam::DVec3;

use crate::domain::grid::GridGeometry;
use crate::io::output::write_atomic;

/// One particle as written to VTK.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VtkParticle {
    pub id: u64,
    /// Centre (m).
    pub pos: DVec3,
    /// Velocity (m/s).
    pub vel: DVec3,
    /// Angular velocity (rad/s).
    pub omega: DVec3,
    /// Radius (m).
    pub radius: f64,
    pub material: u16,
}

/// Gas fields on a [`GridGeometry`].
#[derive(Clone, Copy, Debug)]
pub struct GasFields<'a> {
    /// Gas volume fraction per cell.
    pub gas_fraction: &'a [f64],
    /// Pressure per cell (Pa).
    pub pressure: &'a [f64],
    /// Gas density per cell (kg/m³).
    pub density: &'a [f64],
    /// Interstitial velocity normal to each axis on its faces (m/s), laid
    /// out per [`GridGeometry::face_index`]. In planar mode `face_velocity[2]`
    /// is not read (pass an empty slice) and the z component is 0.
    pub face_velocity: [&'a [f64]; 3],
}

/// Writes particles to `path`: legacy binary VTK for `.vtk`, VTK XML
/// PolyData for `.vtp`. Zero particles give a valid, empty data set.
pub fn write_particles(path: &Path, particles: &[VtkParticle]) -> anyhow::Result<()> {
    let bytes = match extension(path).as_deref() {
        Some("vtk") => legacy_particles(particles)?,
        Some("vtp") => xml_particles(particles),
        _ => bail!(
            "{}: particle VTK files must end in .vtk (legacy) or .vtp (XML)",
            path.display()
        ),
    };
    write_atomic(path, &bytes)
}

/// Writes the gas fields to `path`: legacy binary VTK (`STRUCTURED_POINTS`)
/// for `.vtk`, VTK XML ImageData for `.vti`.
pub fn write_gas(path: &Path, grid: &GridGeometry, fields: &GasFields) -> anyhow::Result<()> {
    let format = match extension(path).as_deref() {
        Some("vtk") => Format::Legacy,
        Some("vti") => Format::Xml,
        _ => bail!(
            "{}: gas VTK files must end in .vtk (legacy) or .vti (XML)",
            path.display()
        ),
    };
    let arrays = gas_arrays(grid, fields).with_context(|| format!("writing {}", path.display()))?;
    ensure!(
        grid.lo.is_finite() && grid.h.is_finite() && grid.h.cmpgt(DVec3::ZERO).all(),
        "{}: grid origin {} and spacing {} must be finite, spacing positive",
        path.display(),
        grid.lo,
        grid.h
    );
    let bytes = match format {
        Format::Legacy => legacy_gas(grid, &arrays),
        Format::Xml => xml_gas(grid, &arrays),
    };
    write_atomic(path, &bytes)
}

/// A ParaView `.pvd` collection: a time series of VTK XML files.
///
/// [`write`](Self::write) rewrites the whole (small) file atomically, so a
/// crash leaves the last complete series.
#[derive(Clone, Debug, PartialEq)]
pub struct PvdSeries {
    path: PathBuf,
    entries: Vec<(f64, String)>,
}

/// Extensions ParaView's PVD reader accepts (`vtkXMLCollectionReader`).
const PVD_EXTENSIONS: &[&str] = &[
    "vtp", "vtu", "vti", "vtr", "vts", "vtm", "vtmb", "vthb", "vtt", "pvtp", "pvtu", "pvti",
    "pvtr", "pvts", "pvtt",
];

impl PvdSeries {
    /// An empty series to be written to `path` (nothing is written yet).
    pub fn new(path: impl Into<PathBuf>) -> Self {
        PvdSeries {
            path: path.into(),
            entries: Vec::new(),
        }
    }

    /// Adds the data set `file` at `time` (s); `file` is relative to the
    /// `.pvd` file's directory and must be a VTK XML file (`.vtp`, `.vti`, ...).
    pub fn push(&mut self, time: f64, file: impl Into<String>) {
        self.entries.push((time, file.into()));
    }

    /// The `.pvd` file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The `(time, file)` entries pushed so far.
    pub fn entries(&self) -> &[(f64, String)] {
        &self.entries
    }

    /// Writes the collection, replacing the file atomically.
    pub fn write(&self) -> anyhow::Result<()> {
        let mut s = String::from(
            "<?xml version=\"1.0\"?>\n\
             <VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  \
             <Collection>\n",
        );
        for (time, file) in &self.entries {
            ensure!(
                time.is_finite(),
                "{}: time {time} of {file} is not finite",
                self.path.display()
            );
            let ext = extension(Path::new(file));
            ensure!(
                ext.as_deref().is_some_and(|e| PVD_EXTENSIONS.contains(&e)),
                "{}: {file} cannot be listed in a .pvd file: ParaView reads only VTK XML files \
                 (.vtp, .vti, ...) from one, not legacy .vtk",
                self.path.display()
            );
            writeln!(
                s,
                "    <DataSet timestep=\"{time:?}\" group=\"\" part=\"0\" file=\"{}\"/>",
                xml_escape(file)
            )?;
        }
        s.push_str("  </Collection>\n</VTKFile>\n");
        write_atomic(&self.path, s.as_bytes())
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Legacy,
    Xml,
}

/// Lower-case extension of `path`.
fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

fn xml_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            _ => out.push(c),
        }
    }
    out
}

/// Values of one data array, flattened (components fastest).
#[derive(Clone, Debug)]
enum Values {
    F64(Vec<f64>),
    U64(Vec<u64>),
    U16(Vec<u16>),
    I64(Vec<i64>),
}

#[derive(Clone, Debug)]
struct Array {
    name: &'static str,
    /// 1 (scalars) or 3 (vectors).
    components: usize,
    values: Values,
}

impl Array {
    fn scalars(name: &'static str, values: Values) -> Self {
        Array {
            name,
            components: 1,
            values,
        }
    }

    fn vectors(name: &'static str, v: impl Iterator<Item = DVec3>) -> Self {
        Array {
            name,
            components: 3,
            values: Values::F64(v.flat_map(|v| v.to_array()).collect()),
        }
    }

    fn legacy_type(&self) -> &'static str {
        match self.values {
            Values::F64(_) => "double",
            Values::U64(_) => "vtktypeuint64",
            Values::U16(_) => "unsigned_short",
            Values::I64(_) => "vtktypeint64",
        }
    }

    fn xml_type(&self) -> &'static str {
        match self.values {
            Values::F64(_) => "Float64",
            Values::U64(_) => "UInt64",
            Values::U16(_) => "UInt16",
            Values::I64(_) => "Int64",
        }
    }

    /// Bytes per value.
    fn value_size(&self) -> usize {
        match self.values {
            Values::F64(_) | Values::U64(_) | Values::I64(_) => 8,
            Values::U16(_) => 2,
        }
    }

    /// Number of values (tuples × components).
    fn len(&self) -> usize {
        match &self.values {
            Values::F64(v) => v.len(),
            Values::U64(v) => v.len(),
            Values::U16(v) => v.len(),
            Values::I64(v) => v.len(),
        }
    }

    fn byte_len(&self) -> usize {
        self.len() * self.value_size()
    }

    /// Appends the raw values, big- or little-endian.
    fn push_bytes(&self, out: &mut Vec<u8>, big_endian: bool) {
        out.reserve(self.byte_len());
        macro_rules! put {
            ($v:expr) => {
                for x in $v {
                    out.extend_from_slice(&if big_endian {
                        x.to_be_bytes()
                    } else {
                        x.to_le_bytes()
                    });
                }
            };
        }
        match &self.values {
            Values::F64(v) => put!(v),
            Values::U64(v) => put!(v),
            Values::U16(v) => put!(v),
            Values::I64(v) => put!(v),
        }
    }
}

fn particle_arrays(particles: &[VtkParticle]) -> Vec<Array> {
    let f64s = |f: fn(&VtkParticle) -> f64| Values::F64(particles.iter().map(f).collect());
    vec![
        Array::scalars("radius", f64s(|p| p.radius)),
        Array::vectors("velocity", particles.iter().map(|p| p.vel)),
        Array::scalars("speed", f64s(|p| p.vel.length())),
        Array::vectors("omega", particles.iter().map(|p| p.omega)),
        Array::scalars("id", Values::U64(particles.iter().map(|p| p.id).collect())),
        Array::scalars(
            "material",
            Values::U16(particles.iter().map(|p| p.material).collect()),
        ),
    ]
}

/// Cell-centred interstitial gas velocity: per axis, the mean of the cell's
/// lower and upper face (on a periodic axis the upper face of the last cell
/// is face 0).
fn cell_velocities(grid: &GridGeometry, faces: [&[f64]; 3]) -> Vec<DVec3> {
    let mut v = vec![DVec3::ZERO; grid.cells()];
    for &axis in grid.velocity_axes() {
        let u = faces[axis];
        for (c, vc) in v.iter_mut().enumerate() {
            let lo = grid.cell_coords(c);
            let mut hi = lo;
            hi[axis] += 1;
            if grid.periodic[axis] && hi[axis] == grid.n[axis] {
                hi[axis] = 0;
            }
            vc[axis] = 0.5 * (u[grid.face_index(axis, lo)] + u[grid.face_index(axis, hi)]);
        }
    }
    v
}

fn gas_arrays(grid: &GridGeometry, fields: &GasFields) -> anyhow::Result<Vec<Array>> {
    let cells = grid.cells();
    for (name, len) in [
        ("gas_fraction", fields.gas_fraction.len()),
        ("pressure", fields.pressure.len()),
        ("density", fields.density.len()),
    ] {
        ensure!(len == cells, "{name} has {len} values for {cells} cells");
    }
    for &axis in grid.velocity_axes() {
        let (len, faces) = (fields.face_velocity[axis].len(), grid.faces(axis));
        ensure!(
            len == faces,
            "face velocity along axis {axis} has {len} values for {faces} faces"
        );
    }
    let eps = fields.gas_fraction;
    let vel = cell_velocities(grid, fields.face_velocity);
    Ok(vec![
        Array::scalars("gas_fraction", Values::F64(eps.to_vec())),
        Array::scalars(
            "solids_fraction",
            Values::F64(eps.iter().map(|e| 1.0 - e).collect()),
        ),
        Array::scalars("pressure", Values::F64(fields.pressure.to_vec())),
        Array::scalars("density", Values::F64(fields.density.to_vec())),
        Array::vectors("gas_velocity", vel.iter().copied()),
        Array::vectors(
            "superficial_velocity",
            vel.iter().zip(eps).map(|(v, e)| *e * *v),
        ),
    ])
}

// ---------------------------------------------------------------- legacy

fn legacy_header(title: &str, dataset: &str) -> Vec<u8> {
    format!("# vtk DataFile Version 3.0\n{title}\nBINARY\nDATASET {dataset}\n").into_bytes()
}

/// Attribute data: the first scalar array as `SCALARS` and the first
/// vector array as `VECTORS` (the active attributes), every other array in
/// one `FIELD` block. VTK's legacy readers read only the first `SCALARS` and
/// `VECTORS` unless told otherwise, but always the whole `FIELD` block.
fn legacy_attributes(out: &mut Vec<u8>, arrays: &[Array]) {
    let active_scalars = arrays.iter().position(|a| a.components == 1);
    let active_vectors = arrays.iter().position(|a| a.components == 3);
    for i in [active_scalars, active_vectors].into_iter().flatten() {
        let a = &arrays[i];
        let header = if a.components == 3 {
            format!("VECTORS {} {}\n", a.name, a.legacy_type())
        } else {
            format!(
                "SCALARS {} {} 1\nLOOKUP_TABLE default\n",
                a.name,
                a.legacy_type()
            )
        };
        out.extend_from_slice(header.as_bytes());
        a.push_bytes(out, true);
        out.push(b'\n');
    }
    let rest: Vec<&Array> = (0..arrays.len())
        .filter(|&i| Some(i) != active_scalars && Some(i) != active_vectors)
        .map(|i| &arrays[i])
        .collect();
    if !rest.is_empty() {
        out.extend_from_slice(format!("FIELD FieldData {}\n", rest.len()).as_bytes());
        for a in rest {
            let tuples = a.len() / a.components;
            out.extend_from_slice(
                format!("{} {} {tuples} {}\n", a.name, a.components, a.legacy_type()).as_bytes(),
            );
            a.push_bytes(out, true);
            out.push(b'\n');
        }
    }
}

fn legacy_particles(particles: &[VtkParticle]) -> anyhow::Result<Vec<u8>> {
    let n = particles.len();
    // Cell connectivity is int32 in the legacy format.
    ensure!(
        i32::try_from(n).is_ok(),
        "{n} particles are too many for a legacy VTK file; use .vtp"
    );
    let mut out = legacy_header("edpm particles", "POLYDATA");
    out.extend_from_slice(format!("POINTS {n} double\n").as_bytes());
    Array::vectors("points", particles.iter().map(|p| p.pos)).push_bytes(&mut out, true);
    out.push(b'\n');
    // Like VTK's own writer, an empty data set ends after its (empty) points.
    if n > 0 {
        out.extend_from_slice(format!("VERTICES {n} {}\n", 2 * n).as_bytes());
        for i in 0..n as i32 {
            out.extend_from_slice(&1i32.to_be_bytes());
            out.extend_from_slice(&i.to_be_bytes());
        }
        out.extend_from_slice(format!("\nPOINT_DATA {n}\n").as_bytes());
        legacy_attributes(&mut out, &particle_arrays(particles));
    }
    Ok(out)
}

fn legacy_gas(grid: &GridGeometry, arrays: &[Array]) -> Vec<u8> {
    let [nx, ny, nz] = grid.n;
    let (lo, h) = (grid.lo, grid.h);
    let mut out = legacy_header("edpm gas", "STRUCTURED_POINTS");
    out.extend_from_slice(
        format!(
            "DIMENSIONS {} {} {}\nORIGIN {:?} {:?} {:?}\nSPACING {:?} {:?} {:?}\nCELL_DATA {}\n",
            nx + 1,
            ny + 1,
            nz + 1,
            lo.x,
            lo.y,
            lo.z,
            h.x,
            h.y,
            h.z,
            grid.cells()
        )
        .as_bytes(),
    );
    legacy_attributes(&mut out, arrays);
    out
}

// ------------------------------------------------------------------- XML

/// A VTK XML file with raw appended data: the XML part and the data block.
struct XmlFile {
    xml: String,
    data: Vec<u8>,
}

impl XmlFile {
    fn new(kind: &str) -> Self {
        XmlFile {
            xml: format!(
                "<?xml version=\"1.0\"?>\n<VTKFile type=\"{kind}\" version=\"1.0\" \
                 byte_order=\"LittleEndian\" header_type=\"UInt64\">\n"
            ),
            data: Vec::new(),
        }
    }

    fn line(&mut self, s: &str) {
        self.xml.push_str(s);
        self.xml.push('\n');
    }

    /// Declares `a` (named `name`) and appends its values.
    fn array_named(&mut self, indent: &str, name: &str, a: &Array) {
        let offset = self.data.len();
        let _ = writeln!(
            self.xml,
            "{indent}<DataArray type=\"{}\" Name=\"{name}\" NumberOfComponents=\"{}\" \
             format=\"appended\" offset=\"{offset}\"/>",
            a.xml_type(),
            a.components
        );
        self.data
            .extend_from_slice(&(a.byte_len() as u64).to_le_bytes());
        a.push_bytes(&mut self.data, false);
    }

    fn array(&mut self, indent: &str, a: &Array) {
        self.array_named(indent, a.name, a);
    }

    fn finish(self) -> Vec<u8> {
        let mut out = self.xml.into_bytes();
        out.extend_from_slice(b"  <AppendedData encoding=\"raw\">\n   _");
        out.extend_from_slice(&self.data);
        out.extend_from_slice(b"\n  </AppendedData>\n</VTKFile>\n");
        out
    }
}

fn xml_particles(particles: &[VtkParticle]) -> Vec<u8> {
    let n = particles.len();
    let mut f = XmlFile::new("PolyData");
    f.line("  <PolyData>");
    f.line(&format!(
        "    <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" \
         NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
    ));
    f.line("      <PointData Scalars=\"radius\" Vectors=\"velocity\">");
    for a in particle_arrays(particles) {
        f.array("        ", &a);
    }
    f.line("      </PointData>");
    f.line("      <Points>");
    let points = Array::vectors("Points", particles.iter().map(|p| p.pos));
    f.array("        ", &points);
    f.line("      </Points>");
    f.line("      <Verts>");
    let ids = 0..n as i64;
    f.array(
        "        ",
        &Array::scalars("connectivity", Values::I64(ids.clone().collect())),
    );
    f.array(
        "        ",
        &Array::scalars("offsets", Values::I64(ids.map(|i| i + 1).collect())),
    );
    f.line("      </Verts>");
    f.line("    </Piece>");
    f.line("  </PolyData>");
    f.finish()
}

fn xml_gas(grid: &GridGeometry, arrays: &[Array]) -> Vec<u8> {
    let [nx, ny, nz] = grid.n;
    let (lo, h) = (grid.lo, grid.h);
    let extent = format!("0 {nx} 0 {ny} 0 {nz}");
    let mut f = XmlFile::new("ImageData");
    f.line(&format!(
        "  <ImageData WholeExtent=\"{extent}\" Origin=\"{:?} {:?} {:?}\" \
         Spacing=\"{:?} {:?} {:?}\">",
        lo.x, lo.y, lo.z, h.x, h.y, h.z
    ));
    f.line(&format!("    <Piece Extent=\"{extent}\">"));
    f.line("      <CellData Scalars=\"gas_fraction\" Vectors=\"gas_velocity\">");
    for a in arrays {
        f.array("        ", a);
    }
    f.line("      </CellData>");
    f.line("    </Piece>");
    f.line("  </ImageData>");
    f.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("edpm-vtk-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    fn find(hay: &[u8], needle: &str) -> Option<usize> {
        hay.windows(needle.len())
            .position(|w| w == needle.as_bytes())
    }

    /// The `count` big-endian 8-byte words right after the line `header` of
    /// a legacy file.
    fn legacy_words(bytes: &[u8], header: &str, count: usize) -> Vec<[u8; 8]> {
        let line = format!("{header}\n");
        let at = find(bytes, &line).unwrap_or_else(|| panic!("no {header:?}")) + line.len();
        let words = bytes[at..at + 8 * count]
            .chunks(8)
            .map(|c| c.try_into().unwrap())
            .collect();
        assert_eq!(
            bytes[at + 8 * count],
            b'\n',
            "{header}: data not followed by newline"
        );
        words
    }

    fn legacy_f64(bytes: &[u8], header: &str, count: usize) -> Vec<f64> {
        legacy_words(bytes, header, count)
            .into_iter()
            .map(f64::from_be_bytes)
            .collect()
    }

    /// The raw bytes of XML array `name`, via its `offset` into the appended
    /// block and the block's UInt64 byte count.
    fn xml_array<'b>(bytes: &'b [u8], name: &str) -> &'b [u8] {
        let tag = format!("Name=\"{name}\"");
        let at = find(bytes, &tag).unwrap_or_else(|| panic!("no array {name}"));
        let end = at + find(&bytes[at..], "/>").unwrap();
        let rest = std::str::from_utf8(&bytes[at..end]).unwrap();
        let offset: usize = rest
            .split("offset=\"")
            .nth(1)
            .and_then(|s| s.split('"').next())
            .unwrap()
            .parse()
            .unwrap();
        let start = find(bytes, "<AppendedData encoding=\"raw\">\n   _").unwrap()
            + "<AppendedData encoding=\"raw\">\n   _".len()
            + offset;
        let len = u64::from_le_bytes(bytes[start..start + 8].try_into().unwrap()) as usize;
        &bytes[start + 8..start + 8 + len]
    }

    fn le_f64(b: &[u8]) -> Vec<f64> {
        b.chunks(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }

    fn particles(n: usize) -> Vec<VtkParticle> {
        (0..n)
            .map(|i| {
                let x = i as f64;
                VtkParticle {
                    id: 1_000_000_000_000 + i as u64,
                    pos: DVec3::new(x, 2.0 * x, -x),
                    vel: DVec3::new(3.0, 4.0 * x, 0.0),
                    omega: DVec3::new(0.0, 0.0, x + 0.5),
                    radius: 1e-3 * (x + 1.0),
                    material: i as u16 + 7,
                }
            })
            .collect()
    }

    #[test]
    fn legacy_particles_round_trip() {
        let dir = temp_dir("legacy-particles");
        let path = dir.join("p.vtk");
        let ps = particles(3);
        write_particles(&path, &ps).unwrap();
        let b = std::fs::read(&path).unwrap();
        assert!(b.starts_with(
            b"# vtk DataFile Version 3.0\nedpm particles\nBINARY\nDATASET POLYDATA\n"
        ));
        let pos = legacy_f64(&b, "POINTS 3 double", 9);
        assert_eq!(pos[3..6], [1.0, 2.0, -1.0]);
        let at = find(&b, "VERTICES 3 6\n").unwrap() + "VERTICES 3 6\n".len();
        let cells: Vec<i32> = b[at..at + 24]
            .chunks(4)
            .map(|c| i32::from_be_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(cells, [1, 0, 1, 1, 1, 2]);
        assert!(find(&b, "\nPOINT_DATA 3\n").is_some());
        assert!(find(&b, "\nFIELD FieldData 4\nspeed 1 3 double\n").is_some());
        let radius = legacy_f64(&b, "SCALARS radius double 1\nLOOKUP_TABLE default", 3);
        assert_eq!(radius, [1e-3, 2e-3, 3e-3]);
        let speed = legacy_f64(&b, "speed 1 3 double", 3);
        assert_eq!(speed, [3.0, 5.0, 73f64.sqrt()]);
        let vel = legacy_f64(&b, "VECTORS velocity double", 9);
        assert_eq!(vel[3..6], [3.0, 4.0, 0.0]);
        let omega = legacy_f64(&b, "omega 3 3 double", 9);
        assert_eq!(omega[8], 2.5);
        let ids: Vec<u64> = legacy_words(&b, "id 1 3 vtktypeuint64", 3)
            .into_iter()
            .map(u64::from_be_bytes)
            .collect();
        assert_eq!(
            ids,
            [1_000_000_000_000, 1_000_000_000_001, 1_000_000_000_002]
        );
        let line = "material 1 3 unsigned_short\n";
        let at = find(&b, line).unwrap() + line.len();
        assert_eq!(b[at..at + 6], [0, 7, 0, 8, 0, 9]);
        assert_eq!(&b[at + 6..], b"\n", "material is the last array");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn xml_particles_round_trip() {
        let dir = temp_dir("xml-particles");
        let path = dir.join("p.vtp");
        write_particles(&path, &particles(4)).unwrap();
        let b = std::fs::read(&path).unwrap();
        let text = String::from_utf8_lossy(&b);
        assert!(text.starts_with("<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\""));
        assert!(text.contains("NumberOfPoints=\"4\" NumberOfVerts=\"4\""));
        assert!(text.ends_with("\n  </AppendedData>\n</VTKFile>\n"));
        assert_eq!(le_f64(xml_array(&b, "radius")), [1e-3, 2e-3, 3e-3, 4e-3]);
        assert_eq!(le_f64(xml_array(&b, "Points"))[6..9], [2.0, 4.0, -2.0]);
        assert_eq!(le_f64(xml_array(&b, "speed"))[1], 5.0);
        let ids: Vec<u64> = xml_array(&b, "id")
            .chunks(8)
            .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(ids[3], 1_000_000_000_003);
        assert_eq!(xml_array(&b, "material"), [7, 0, 8, 0, 9, 0, 10, 0]);
        let offsets: Vec<i64> = xml_array(&b, "offsets")
            .chunks(8)
            .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(offsets, [1, 2, 3, 4]);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn zero_particles_give_valid_files() {
        let dir = temp_dir("zero-particles");
        write_particles(&dir.join("p.vtk"), &[]).unwrap();
        let b = std::fs::read(dir.join("p.vtk")).unwrap();
        assert_eq!(
            b,
            b"# vtk DataFile Version 3.0\nedpm particles\nBINARY\nDATASET POLYDATA\n\
              POINTS 0 double\n\n"
        );
        write_particles(&dir.join("p.vtp"), &[]).unwrap();
        let b = std::fs::read(dir.join("p.vtp")).unwrap();
        assert!(String::from_utf8_lossy(&b).contains("NumberOfPoints=\"0\" NumberOfVerts=\"0\""));
        assert!(xml_array(&b, "radius").is_empty());
        assert!(xml_array(&b, "offsets").is_empty());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn unknown_extensions_are_rejected() {
        let dir = temp_dir("ext");
        let err = write_particles(&dir.join("p.vti"), &[]).unwrap_err();
        assert!(err.to_string().contains(".vtk (legacy) or .vtp"), "{err}");
        let g = GridGeometry::new(DVec3::ZERO, DVec3::ONE, [1, 1, 1], [false; 3], false);
        let z = [0.0];
        let f = GasFields {
            gas_fraction: &z,
            pressure: &z,
            density: &z,
            face_velocity: [&[0.0; 2], &[0.0; 2], &[0.0; 2]],
        };
        let err = write_gas(&dir.join("g.vtp"), &g, &f).unwrap_err();
        assert!(err.to_string().contains(".vtk (legacy) or .vti"), "{err}");
        assert!(!dir.exists());
    }

    /// A 2×3×1 planar grid, walled in x and periodic in y, with hand-made
    /// face velocities: u_x(i, j) = i² + 100 j, u_y(i, j) = j² + 10 i.
    fn planar_grid() -> (GridGeometry, Vec<f64>, Vec<f64>) {
        let g = GridGeometry::new(
            DVec3::new(-1.0, 0.0, 0.0),
            DVec3::new(1.0, 0.3, 0.01),
            [2, 3, 1],
            [false, true, false],
            true,
        );
        assert_eq!(g.face_dims(0), [3, 3, 1]);
        assert_eq!(g.face_dims(1), [2, 3, 1]);
        let mut ux = vec![0.0; g.faces(0)];
        for (f, u) in ux.iter_mut().enumerate() {
            let [i, j, _] = g.face_coords(0, f);
            *u = (i * i + 100 * j) as f64;
        }
        let mut uy = vec![0.0; g.faces(1)];
        for (f, u) in uy.iter_mut().enumerate() {
            let [i, j, _] = g.face_coords(1, f);
            *u = (j * j + 10 * i) as f64;
        }
        (g, ux, uy)
    }

    /// Cells (0,0), (1,0), (0,1), (1,1), (0,2), (1,2); the last row's upper
    /// y face wraps to face row 0.
    const EXPECTED: [[f64; 3]; 6] = [
        [0.5, 0.5, 0.0],
        [2.5, 10.5, 0.0],
        [100.5, 2.5, 0.0],
        [102.5, 12.5, 0.0],
        [200.5, 2.0, 0.0],
        [202.5, 12.0, 0.0],
    ];

    #[test]
    fn cell_velocity_averages_faces_and_wraps_periodic_axes() {
        let (g, ux, uy) = planar_grid();
        let v = cell_velocities(&g, [&ux, &uy, &[]]);
        let v: Vec<[f64; 3]> = v.iter().map(|v| v.to_array()).collect();
        assert_eq!(v, EXPECTED);
    }

    #[test]
    fn gas_files_round_trip() {
        let dir = temp_dir("gas");
        let (g, ux, uy) = planar_grid();
        let eps = [0.4, 0.5, 0.6, 0.7, 0.8, 1.0];
        let p: Vec<f64> = (0..6).map(|c| 1e5 + c as f64).collect();
        let rho = [1.2; 6];
        let fields = GasFields {
            gas_fraction: &eps,
            pressure: &p,
            density: &rho,
            face_velocity: [&ux, &uy, &[]],
        };
        let flat: Vec<f64> = EXPECTED.concat();

        write_gas(&dir.join("g.vtk"), &g, &fields).unwrap();
        let b = std::fs::read(dir.join("g.vtk")).unwrap();
        let head = "# vtk DataFile Version 3.0\nedpm gas\nBINARY\nDATASET STRUCTURED_POINTS\n\
                    DIMENSIONS 3 4 2\nORIGIN -1.0 0.0 0.0\nSPACING 1.0 0.09999999999999999 0.01\n\
                    CELL_DATA 6\n";
        assert!(find(&b, "\nFIELD FieldData 4\nsolids_fraction 1 6 double\n").is_some());
        assert!(
            b.starts_with(head.as_bytes()),
            "{}",
            String::from_utf8_lossy(&b[..200])
        );
        assert_eq!(
            legacy_f64(&b, "SCALARS gas_fraction double 1\nLOOKUP_TABLE default", 6),
            eps
        );
        let solids = legacy_f64(&b, "solids_fraction 1 6 double", 6);
        assert_eq!(solids[0], 0.6);
        assert_eq!(solids[5], 0.0);
        assert_eq!(legacy_f64(&b, "pressure 1 6 double", 6), p);
        assert_eq!(legacy_f64(&b, "density 1 6 double", 6), rho);
        assert_eq!(legacy_f64(&b, "VECTORS gas_velocity double", 18), flat);
        let sup = legacy_f64(&b, "superficial_velocity 3 6 double", 18);
        assert_eq!(sup[3..6], [0.5 * 2.5, 0.5 * 10.5, 0.0]);

        write_gas(&dir.join("g.vti"), &g, &fields).unwrap();
        let b = std::fs::read(dir.join("g.vti")).unwrap();
        let text = String::from_utf8_lossy(&b);
        assert!(text.contains(
            "<ImageData WholeExtent=\"0 2 0 3 0 1\" Origin=\"-1.0 0.0 0.0\" \
             Spacing=\"1.0 0.09999999999999999 0.01\">"
        ));
        assert!(text.contains("<Piece Extent=\"0 2 0 3 0 1\">"));
        assert_eq!(le_f64(xml_array(&b, "gas_velocity")), flat);
        assert_eq!(le_f64(xml_array(&b, "pressure")), p);
        let sup = le_f64(xml_array(&b, "superficial_velocity"));
        assert_eq!(sup[12..15], [0.8 * 200.5, 0.8 * 2.0, 0.0]);

        // Wrong sizes are errors, not panics.
        let short = GasFields {
            face_velocity: [&ux[1..], &uy, &[]],
            ..fields
        };
        let err = write_gas(&dir.join("bad.vti"), &g, &short).unwrap_err();
        assert!(
            format!("{err:#}").contains("axis 0 has 8 values for 9 faces"),
            "{err:#}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn pvd_series_lists_xml_files() {
        let dir = temp_dir("pvd");
        let mut s = PvdSeries::new(dir.join("particles.pvd"));
        s.write().unwrap();
        let text = std::fs::read_to_string(s.path()).unwrap();
        assert!(text.contains("<Collection>\n  </Collection>"));
        s.push(0.0, "p_0.vtp");
        s.push(2.5e-3, "a&b/p_1.vtp");
        s.write().unwrap();
        let text = std::fs::read_to_string(s.path()).unwrap();
        assert!(
            text.starts_with(
                "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\""
            )
        );
        assert!(text.contains(
            "    <DataSet timestep=\"0.0\" group=\"\" part=\"0\" file=\"p_0.vtp\"/>\n    \
             <DataSet timestep=\"0.0025\" group=\"\" part=\"0\" file=\"a&amp;b/p_1.vtp\"/>\n  \
             </Collection>\n</VTKFile>\n"
        ));
        assert_eq!(s.entries().len(), 2);
        s.push(1.0, "legacy.vtk");
        let err = s.write().unwrap_err();
        assert!(
            err.to_string().contains("legacy.vtk cannot be listed"),
            "{err}"
        );
        // The failed write left the previous file.
        assert_eq!(std::fs::read_to_string(s.path()).unwrap(), text);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
