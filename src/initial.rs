//! Initial particles from the scenario's `[[particles]]` populations.
//!
//! Populations are placed in file order with one RNG, so the result is a
//! pure function of the scenario and the seed. Per population the RNG draws,
//! in this order: all diameters, then positions, then velocities.
//!
//! * Lattice: simple cubic sites (planar: square in x-y) with spacing
//!   `a = 1.0002 d_max` (largest diameter of the population), centred in the
//!   region with a clearance of `a / 2` from its faces, except on
//!   periodic axes that the region spans, where `n = floor(L / a)` sites are
//!   spread evenly with spacing `L / n`. Sites are filled in order: x fastest,
//!   the axis along gravity slowest, starting at the side gravity points to.
//!   Sites overlapping particles of earlier populations are skipped.
//! * Random: random sequential insertion. Diameters are sorted in descending
//!   order (large first: fewer rejections), each particle gets up to
//!   [`MAX_ATTEMPTS`] uniformly random trial centres, kept inside the region
//!   by `1.0001 R` (no clearance on periodic axes the region spans), accepted
//!   when its gap to every placed particle (minimum image on periodic axes) is
//!   at least `1e-4 (R_i + R_j)`. Overlap checks use a cell grid, so placement
//!   is O(N).
//! * Velocities: `mean + sqrt(T) ξ` per component (planar: x and y only),
//!   `ξ` standard normal. For `T > 0` and at least two particles, the
//!   fluctuations are then shifted to zero sample mean and scaled so that the
//!   sample temperature `Σ|v - mean|² / (D N)` (D = 3, planar D = 2) equals
//!   `T` exactly (up to round-off). Angular velocities are zero.

use glam::DVec3;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::particles::NewParticle;
use crate::scenario::{AxisBoundary, Placement, Population, Scenario, ScenarioError};

/// Relative clearance between particles, and between particles and walls or
/// region faces: centre distances are at least `(1 + GAP) (R_i + R_j)`.
pub const GAP: f64 = 1e-4;

/// Trial positions per particle in random placement before giving up.
pub const MAX_ATTEMPTS: usize = 100_000;

/// Places all populations of `s`. Deterministic for a given RNG state.
pub fn initial_particles(
    s: &Scenario,
    rng: &mut Xoshiro256PlusPlus,
) -> Result<Vec<NewParticle>, ScenarioError> {
    initial_particles_around(s, &[], rng)
}

/// Places all populations of `s` around `existing` particles (e.g. loaded
/// from a checkpoint), avoiding overlap with them. Returns only the new
/// particles.
pub fn initial_particles_around(
    s: &Scenario,
    existing: &[NewParticle],
    rng: &mut Xoshiro256PlusPlus,
) -> Result<Vec<NewParticle>, ScenarioError> {
    let d_range = existing
        .iter()
        .map(|p| 2.0 * p.radius)
        .chain(s.populations.iter().map(|p| p.diameter.max()))
        .fold(0.0, f64::max);
    let total = existing.len() + s.total_count();
    let mut grid = Grid::new(s, d_range, total);
    for p in existing {
        grid.insert(p.pos, p.radius);
    }
    let mut out = Vec::with_capacity(s.total_count().min(1 << 24));
    for (i, pop) in s.populations.iter().enumerate() {
        let start = out.len();
        let mut diameters: Vec<f64> = (0..pop.count).map(|_| pop.diameter.sample(rng)).collect();
        match pop.placement {
            Placement::Lattice => place_lattice(s, i, pop, &diameters, &mut grid, &mut out)?,
            Placement::Random => {
                diameters.sort_by(|a, b| b.total_cmp(a));
                place_random(s, i, pop, &diameters, &mut grid, &mut out, rng)?;
            }
        }
        assign_velocities(s.domain.planar, pop, &mut out[start..], rng);
    }
    Ok(out)
}

fn amount_path(i: usize, pop: &Population) -> String {
    if pop.solids_fraction.is_some() {
        format!("particles[{i}].solids_fraction")
    } else {
        format!("particles[{i}].count")
    }
}

fn err(s: &Scenario, path: String, message: String) -> ScenarioError {
    crate::scenario::scenario_error(s, path, message)
}

/// Per-axis admissible centre interval for a particle of radius `r`:
/// `None` when the axis wraps (region spans a periodic axis), else `[a, b]`.
fn wraps(s: &Scenario, pop: &Population, axis: usize) -> bool {
    s.boundaries.axes[axis] == AxisBoundary::Periodic
        && pop.region.lo[axis] <= s.domain.lo[axis]
        && pop.region.hi[axis] >= s.domain.hi[axis]
}

fn place_lattice(
    s: &Scenario,
    i: usize,
    pop: &Population,
    diameters: &[f64],
    grid: &mut Grid,
    out: &mut Vec<NewParticle>,
) -> Result<(), ScenarioError> {
    if diameters.is_empty() {
        return Ok(());
    }
    let d_max = pop.diameter.max();
    // Strictly above the overlap threshold (1 + GAP) d, so round-off in the
    // site coordinates cannot make neighbouring sites count as overlapping.
    let a = d_max * (1.0 + 2.0 * GAP);
    let clearance = 0.5 * a;
    let planar = s.domain.planar;
    // Sites per axis: (first centre, spacing, count).
    let mut axes = [(0.0, 0.0, 1usize); 3];
    for (ax, slot) in axes.iter_mut().enumerate() {
        let (lo, hi) = (pop.region.lo[ax], pop.region.hi[ax]);
        let len = hi - lo;
        *slot = if planar && ax == 2 {
            (s.domain.mid_z(), 0.0, 1)
        } else if wraps(s, pop, ax) {
            let n = (len / a).floor().max(0.0);
            let n = if n >= 1.0 { n.min(1e12) as usize } else { 0 };
            let step = if n > 0 { len / n as f64 } else { 0.0 };
            (lo + 0.5 * step, step, n)
        } else {
            let room = len - 2.0 * clearance;
            if room < 0.0 {
                (lo, a, 0)
            } else {
                let n = ((room / a).floor() + 1.0).min(1e12) as usize;
                let first = lo + 0.5 * (len - (n - 1) as f64 * a);
                (first, a, n)
            }
        };
    }
    // Fill order: x fastest, gravity axis slowest.
    let g = s.domain.gravity;
    let candidates: &[usize] = if planar { &[0, 1] } else { &[0, 1, 2] };
    let slow = if g == DVec3::ZERO {
        *candidates.last().unwrap_or(&2)
    } else {
        *candidates
            .iter()
            .max_by(|&&p, &&q| g[p].abs().total_cmp(&g[q].abs()))
            .unwrap_or(&2)
    };
    let mut order: Vec<usize> = (0..3).filter(|&ax| ax != slow).collect();
    order.push(slow);
    let reverse_slow = g[slow] > 0.0;
    let capacity = axes.iter().map(|t| t.2 as f64).product::<f64>();
    let mut placed = 0usize;
    let mut site = [0usize; 3];
    let mut sites_seen = 0f64;
    'outer: while placed < diameters.len() && sites_seen < capacity {
        let mut pos = DVec3::ZERO;
        for ax in 0..3 {
            let (first, step, n) = axes[ax];
            let k = if ax == slow && reverse_slow {
                n - 1 - site[ax]
            } else {
                site[ax]
            };
            pos[ax] = first + step * k as f64;
        }
        sites_seen += 1.0;
        let r = 0.5 * diameters[placed];
        if !grid.overlaps(pos, r) {
            grid.insert(pos, r);
            out.push(new_particle(pos, r, pop));
            placed += 1;
        }
        // advance the site counter
        for &ax in &order {
            site[ax] += 1;
            if site[ax] < axes[ax].2 {
                continue 'outer;
            }
            site[ax] = 0;
        }
        break;
    }
    if placed < diameters.len() {
        let skipped = sites_seen - placed as f64;
        let free = if skipped > 0.0 {
            format!(", of which {skipped} overlap earlier particles")
        } else {
            String::new()
        };
        return Err(err(
            s,
            amount_path(i, pop),
            format!(
                "population '{}': {} particles do not fit; the lattice (spacing {:?} m) in the region holds {} sites{}",
                pop.name,
                diameters.len(),
                a,
                capacity,
                free
            ),
        ));
    }
    Ok(())
}

fn place_random(
    s: &Scenario,
    i: usize,
    pop: &Population,
    diameters: &[f64],
    grid: &mut Grid,
    out: &mut Vec<NewParticle>,
    rng: &mut Xoshiro256PlusPlus,
) -> Result<(), ScenarioError> {
    use rand::RngExt;
    let planar = s.domain.planar;
    let wrap = [wraps(s, pop, 0), wraps(s, pop, 1), wraps(s, pop, 2)];
    for (k, &d) in diameters.iter().enumerate() {
        let r = 0.5 * d;
        let c = r * (1.0 + GAP);
        let mut lo = DVec3::ZERO;
        let mut width = DVec3::ZERO;
        for ax in 0..3 {
            if planar && ax == 2 {
                lo[ax] = s.domain.mid_z();
            } else if wrap[ax] {
                lo[ax] = pop.region.lo[ax];
                width[ax] = pop.region.hi[ax] - pop.region.lo[ax];
            } else {
                lo[ax] = pop.region.lo[ax] + c;
                width[ax] = pop.region.hi[ax] - pop.region.lo[ax] - 2.0 * c;
                if width[ax] < 0.0 {
                    return Err(err(
                        s,
                        format!("particles[{i}].region"),
                        format!(
                            "population '{}': a particle of diameter {d:?} does not fit between the region faces along {}",
                            pop.name,
                            ["x", "y", "z"][ax]
                        ),
                    ));
                }
            }
        }
        let mut ok = false;
        for _ in 0..MAX_ATTEMPTS {
            let u = DVec3::new(rng.random(), rng.random(), rng.random());
            let pos = lo + width * u;
            if !grid.overlaps(pos, r) {
                grid.insert(pos, r);
                out.push(new_particle(pos, r, pop));
                ok = true;
                break;
            }
        }
        if !ok {
            return Err(err(
                s,
                amount_path(i, pop),
                format!(
                    "population '{}': random placement gave up after placing {k} of {} particles ({MAX_ATTEMPTS} failed attempts for the next one); lower the amount or use placement = \"lattice\"",
                    pop.name,
                    diameters.len()
                ),
            ));
        }
    }
    Ok(())
}

fn new_particle(pos: DVec3, radius: f64, pop: &Population) -> NewParticle {
    NewParticle {
        pos,
        vel: pop.velocity,
        omega: DVec3::ZERO,
        radius,
        material: pop.material,
    }
}

fn assign_velocities(
    planar: bool,
    pop: &Population,
    ps: &mut [NewParticle],
    rng: &mut Xoshiro256PlusPlus,
) {
    let t = pop.temperature;
    let dims = if planar { 2 } else { 3 };
    if t <= 0.0 || ps.is_empty() {
        for p in ps.iter_mut() {
            p.vel = pop.velocity;
        }
        return;
    }
    let sd = t.sqrt();
    let mut fluct: Vec<DVec3> = ps
        .iter()
        .map(|_| {
            let mut v = DVec3::ZERO;
            for ax in 0..dims {
                v[ax] = sd * crate::scenario::gaussian(rng);
            }
            v
        })
        .collect();
    if fluct.len() >= 2 {
        let n = fluct.len() as f64;
        let mean = fluct.iter().copied().sum::<DVec3>() / n;
        for f in fluct.iter_mut() {
            *f -= mean;
        }
        let t_sample = fluct.iter().map(|f| f.length_squared()).sum::<f64>() / (dims as f64 * n);
        if t_sample > 0.0 {
            let scale = (t / t_sample).sqrt();
            for f in fluct.iter_mut() {
                *f *= scale;
            }
        }
    }
    for (p, f) in ps.iter_mut().zip(fluct) {
        p.vel = pop.velocity + f;
    }
}

/// Uniform cell grid over the domain for overlap queries.
struct Grid {
    lo: DVec3,
    len: DVec3,
    n: [usize; 3],
    cell: DVec3,
    periodic: [bool; 3],
    cells: Vec<Vec<(DVec3, f64)>>,
}

impl Grid {
    fn new(s: &Scenario, d_range: f64, expected: usize) -> Grid {
        let lo = s.domain.lo;
        let len = s.domain.extent();
        let planar = s.domain.planar;
        let dims = if planar { 2 } else { 3 };
        // At most ~4 cells per particle (and at least 4096 allowed) so sparse
        // huge domains do not allocate huge grids; cells never smaller than
        // the interaction range d_range.
        let max_cells = (4 * expected).max(4096) as f64;
        let vol: f64 = (0..dims).map(|a| len[a]).product();
        let size = (d_range * (1.0 + 2.0 * GAP)).max((vol / max_cells).powf(1.0 / dims as f64));
        let mut n = [1usize; 3];
        for a in 0..dims {
            let k = if size > 0.0 {
                (len[a] / size).floor()
            } else {
                1.0
            };
            n[a] = (k.clamp(1.0, max_cells)) as usize;
        }
        let cell = DVec3::new(
            len.x / n[0] as f64,
            len.y / n[1] as f64,
            len.z / n[2] as f64,
        );
        let periodic = [0, 1, 2].map(|a| s.boundaries.axes[a] == AxisBoundary::Periodic);
        Grid {
            lo,
            len,
            n,
            cell,
            periodic,
            cells: vec![Vec::new(); n[0] * n[1] * n[2]],
        }
    }

    fn coord(&self, pos: DVec3, a: usize) -> usize {
        let x = (pos[a] - self.lo[a]) / self.cell[a];
        let n = self.n[a] as f64;
        let x = if self.periodic[a] { x.rem_euclid(n) } else { x };
        (x.floor().clamp(0.0, n - 1.0)) as usize
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.n[1] + c[1]) * self.n[0] + c[0]
    }

    fn insert(&mut self, pos: DVec3, r: f64) {
        let c = [0, 1, 2].map(|a| self.coord(pos, a));
        let idx = self.index(c);
        self.cells[idx].push((pos, r));
    }

    /// Neighbouring cell coordinates along one axis (deduplicated).
    fn neighbours(&self, c: usize, a: usize) -> ([usize; 3], usize) {
        let n = self.n[a];
        let mut out = [0usize; 3];
        let mut k = 0;
        for off in [-1i64, 0, 1] {
            let mut j = c as i64 + off;
            if self.periodic[a] {
                j = j.rem_euclid(n as i64);
            } else if j < 0 || j >= n as i64 {
                continue;
            }
            let j = j as usize;
            if !out[..k].contains(&j) {
                out[k] = j;
                k += 1;
            }
        }
        (out, k)
    }

    fn delta(&self, a: DVec3, b: DVec3) -> DVec3 {
        let mut d = a - b;
        for ax in 0..3 {
            if self.periodic[ax] {
                d[ax] -= self.len[ax] * (d[ax] / self.len[ax]).round();
            }
        }
        d
    }

    /// True if a sphere of radius `r` at `pos` comes closer than
    /// `(1 + GAP)(r + r_j)` to any stored sphere.
    fn overlaps(&self, pos: DVec3, r: f64) -> bool {
        let c = [0, 1, 2].map(|a| self.coord(pos, a));
        let (nx, kx) = self.neighbours(c[0], 0);
        let (ny, ky) = self.neighbours(c[1], 1);
        let (nz, kz) = self.neighbours(c[2], 2);
        for &z in &nz[..kz] {
            for &y in &ny[..ky] {
                for &x in &nx[..kx] {
                    for &(q, rq) in &self.cells[self.index([x, y, z])] {
                        let min = (r + rq) * (1.0 + GAP);
                        if self.delta(pos, q).length_squared() < min * min {
                            return true;
                        }
                    }
                }
            }
        }
        false
    }
}
