//! Particle (and gas) snapshots written during a run for `edpm analyse`,
//! and the per-cell collision tally that lets the analysis compare the
//! collisional pressure and dissipation with kinetic theory.
//!
//! A run with `[output] snapshot_interval` writes
//! `RUN_DIR/snapshots/NNNNNN.bin`, each a [`Snapshot`] in the checksummed
//! container of [`crate::io::container`] (magic `EDPMSNAP`, version
//! [`SNAPSHOT_VERSION`], the run id in its header; docs/data-files.md).
//! Files are written atomically. `edpm analyse` refuses a directory whose
//! snapshots come from different runs.

use std::path::{Path, PathBuf};

use anyhow::Context;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::engine::{CollisionRecord, ParticleView, Partner};
use crate::io::container::{self, Kind};
use crate::io::output::write_atomic;

/// Version of the snapshot format: 2 split the tally's dissipation into
/// normal and tangential parts and added the TC/guard alterations; 3 put
/// the snapshot in the checksummed container with the run id.
pub const SNAPSHOT_VERSION: u32 = 3;

/// The container kind of snapshots.
pub const SNAPSHOT_KIND: Kind = Kind {
    magic: *b"EDPMSNAP",
    what: "snapshot",
    version: SNAPSHOT_VERSION,
    legacy_up_to: 2,
};

/// One particle in a snapshot (SI units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SnapshotParticle {
    pub id: u64,
    pub material: u16,
    /// Radius (m) and mass (kg).
    pub radius: f64,
    pub mass: f64,
    /// Position (m, inside the box), velocity (m/s), angular velocity (rad/s).
    pub pos: DVec3,
    pub vel: DVec3,
    pub omega: DVec3,
}

impl From<ParticleView> for SnapshotParticle {
    fn from(p: ParticleView) -> Self {
        SnapshotParticle {
            id: p.id,
            material: p.material,
            radius: p.radius,
            mass: p.mass,
            pos: p.pos,
            vel: p.vel,
            omega: p.omega,
        }
    }
}

/// A uniform grid of cells over the box: the gas grid when there is gas,
/// otherwise the tally grid of the scenario.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TallyGrid {
    pub lo: DVec3,
    /// Cell size (m); in planar mode `h.z` is the bed depth.
    pub h: DVec3,
    pub n: [usize; 3],
}

impl TallyGrid {
    /// Linear index `i + n_x (j + n_y k)` of the cell holding `x`
    /// (clamped into the grid).
    pub fn cell_of(&self, x: DVec3) -> usize {
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let t = ((x[a] - self.lo[a]) / self.h[a]).floor();
            idx[a] = (t.max(0.0) as usize).min(self.n[a] - 1);
        }
        idx[0] + self.n[0] * (idx[1] + self.n[1] * idx[2])
    }

    pub fn cells(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }
}

/// Collisions per cell over an interval, located at the contact point
/// (walls: at the particle's centre).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CollisionTally {
    pub grid: TallyGrid,
    /// Length of the interval (s).
    pub interval: f64,
    /// Pair collisions per cell.
    pub pair_collisions: Vec<u64>,
    /// Collision virial Σ σ n·J per cell (J), for the collisional pressure
    /// p_c = Σ σ n·J / (d V Δt) with d the number of moving dimensions.
    pub virial: Vec<f64>,
    /// Kinetic energy dissipated in pair collisions per cell (J): by the
    /// normal impulses (`Σ ½ (1 − e_n²) m_ab v_n²`, what normal-only kinetic
    /// theory predicts) and the tangential rest (friction and spin).
    pub dissipated_normal: Vec<f64>,
    pub dissipated_tangential: Vec<f64>,
    /// Pair collisions the TC model or the collapse guard made elastic,
    /// and the energy they did not dissipate, nominal minus actual (J).
    pub pair_altered: Vec<u64>,
    pub pair_undissipated: Vec<f64>,
    /// Wall collisions per cell, the energy they dissipated (J), and the
    /// same alteration counts as for pairs.
    pub wall_collisions: Vec<u64>,
    pub wall_dissipated: Vec<f64>,
    pub wall_altered: Vec<u64>,
    pub wall_undissipated: Vec<f64>,
}

impl CollisionTally {
    pub fn new(grid: TallyGrid) -> Self {
        let n = grid.cells();
        CollisionTally {
            grid,
            interval: 0.0,
            pair_collisions: vec![0; n],
            virial: vec![0.0; n],
            dissipated_normal: vec![0.0; n],
            dissipated_tangential: vec![0.0; n],
            pair_altered: vec![0; n],
            pair_undissipated: vec![0.0; n],
            wall_collisions: vec![0; n],
            wall_dissipated: vec![0.0; n],
            wall_altered: vec![0; n],
            wall_undissipated: vec![0.0; n],
        }
    }

    /// Adds one collision; `wrap` maps a stored position into the box.
    pub fn add(&mut self, r: &CollisionRecord, wrap: impl Fn(DVec3) -> DVec3) {
        let a = r.after[0];
        let altered = u64::from(r.made_elastic.is_some());
        match r.b {
            Partner::Particle(_) => {
                // Contact distance from the positions, as the minimum image:
                // stored positions of a pair touching across a periodic
                // boundary are a box length apart.
                let box_size = self.grid.h
                    * DVec3::new(
                        self.grid.n[0] as f64,
                        self.grid.n[1] as f64,
                        self.grid.n[2] as f64,
                    );
                let mut d = a.pos - r.after[1].pos;
                for ax in 0..3 {
                    if box_size[ax] > 0.0 {
                        d[ax] -= (d[ax] / box_size[ax]).round() * box_size[ax];
                    }
                }
                let sigma = d.dot(r.normal).abs();
                let c = self.grid.cell_of(wrap(a.pos - 0.5 * sigma * r.normal));
                self.pair_collisions[c] += 1;
                self.virial[c] += sigma * r.impulse.dot(r.normal);
                self.dissipated_normal[c] += r.dissipated_normal;
                self.dissipated_tangential[c] += r.dissipated - r.dissipated_normal;
                self.pair_altered[c] += altered;
                self.pair_undissipated[c] += r.undissipated;
            }
            _ => {
                let c = self.grid.cell_of(wrap(a.pos));
                self.wall_collisions[c] += 1;
                self.wall_dissipated[c] += r.dissipated;
                self.wall_altered[c] += altered;
                self.wall_undissipated[c] += r.undissipated;
            }
        }
    }

    /// Whether the TC model or the collapse guard altered a collision
    /// (pair or wall) in cell `c` during the interval.
    pub fn altered(&self, c: usize) -> bool {
        self.pair_altered[c] + self.wall_altered[c] > 0
    }

    /// Clears the counts for the next interval.
    pub fn reset(&mut self) {
        *self = CollisionTally::new(self.grid.clone());
    }
}

/// Gas fields on the gas grid (cell-centred; interstitial velocity averaged
/// from the faces to the cell centres).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GasSnapshot {
    pub grid: TallyGrid,
    pub gas_fraction: Vec<f64>,
    /// Pa.
    pub pressure: Vec<f64>,
    /// Interstitial gas velocity at the cell centres (m/s).
    pub velocity: Vec<DVec3>,
}

/// Everything `edpm analyse` needs at one instant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// The run that wrote the snapshot (in the container header, not the
    /// payload).
    #[serde(skip)]
    pub run_id: u64,
    pub version: u32,
    /// Time (s).
    pub time: f64,
    /// The box (m), its periodic axes and planar mode.
    pub lo: DVec3,
    pub hi: DVec3,
    pub periodic: [bool; 3],
    pub planar: bool,
    /// Gravity (m/s²).
    pub gravity: DVec3,
    pub particles: Vec<SnapshotParticle>,
    pub gas: Option<GasSnapshot>,
    /// Collisions since the previous snapshot.
    pub collisions: Option<CollisionTally>,
}

impl Snapshot {
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        write_atomic(path, &container::encode(&SNAPSHOT_KIND, self.run_id, self)?)
    }

    pub fn read(path: &Path) -> anyhow::Result<Snapshot> {
        let (header, mut s): (_, Snapshot) = container::read(&SNAPSHOT_KIND, path)?;
        if s.version != SNAPSHOT_VERSION {
            anyhow::bail!(
                "{}: the payload says snapshot version {}, the header {SNAPSHOT_VERSION}: the snapshot is damaged",
                path.display(),
                s.version
            );
        }
        s.run_id = header.run_id;
        Ok(s)
    }

    /// The snapshot files of a run directory, in time order (by name).
    pub fn paths(run_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        let dir = run_dir.join("snapshots");
        let mut paths: Vec<_> = std::fs::read_dir(&dir)
            .with_context(|| {
                format!(
                    "{}: no snapshots (run with [output] snapshot_interval)",
                    dir.display()
                )
            })?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "bin"))
            .collect();
        paths.sort();
        Ok(paths)
    }

    /// Checks from the headers alone that every snapshot in `paths` was
    /// written by the same run, and returns its id: a directory reused by
    /// several runs must not be analysed as one.
    pub fn check_one_run(paths: &[PathBuf]) -> anyhow::Result<Option<u64>> {
        let mut first: Option<(u64, &PathBuf)> = None;
        for p in paths {
            let id = container::read_header(&SNAPSHOT_KIND, p)?.run_id;
            match first {
                None => first = Some((id, p)),
                Some((id0, p0)) if id0 != id => anyhow::bail!(
                    "{}: written by run {}, but {} by run {}: the directory holds snapshots of \
                     different runs; run again into an empty directory (or with --force)",
                    p.display(),
                    run_id_text(id),
                    p0.display(),
                    run_id_text(id0)
                ),
                _ => {}
            }
        }
        Ok(first.map(|(id, _)| id))
    }

    /// All snapshots of a run directory, in time order, all from one run.
    pub fn read_all(run_dir: &Path) -> anyhow::Result<Vec<Snapshot>> {
        let paths = Snapshot::paths(run_dir)?;
        Snapshot::check_one_run(&paths)?;
        let mut snaps: Vec<Snapshot> = Vec::with_capacity(paths.len());
        for (k, p) in paths.iter().enumerate() {
            let snap = Snapshot::read(p)?;
            if k > 0 {
                Snapshot::check_follows(&paths[k - 1], snaps[k - 1].time, p, snap.time)?;
            }
            snaps.push(snap);
        }
        Ok(snaps)
    }

    /// Refuses a snapshot at `path` (time `time`, s) that does not come
    /// strictly after the one before it in file order (`previous`, at
    /// `previous_time`): a copied or renamed file would count a state
    /// twice or out of order.
    pub fn check_follows(
        previous: &Path,
        previous_time: f64,
        path: &Path,
        time: f64,
    ) -> anyhow::Result<()> {
        if time > previous_time {
            return Ok(());
        }
        anyhow::bail!(
            "{}: its time t = {time} s does not follow t = {previous_time} s of {}: the snapshots of a run are numbered in time order (a copied or renamed file?)",
            path.display(),
            previous.display()
        )
    }
}

/// A run id as written in messages and `summary.json`: 16 hex digits.
pub fn run_id_text(id: u64) -> String {
    format!("{id:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snapshot_round_trips() {
        let s = Snapshot {
            run_id: 0x1234_5678_9abc_def0,
            version: SNAPSHOT_VERSION,
            time: 0.5,
            lo: DVec3::ZERO,
            hi: DVec3::ONE,
            periodic: [true, false, false],
            planar: false,
            gravity: DVec3::new(0.0, -9.81, 0.0),
            particles: vec![SnapshotParticle {
                id: 3,
                material: 1,
                radius: 0.01,
                mass: 1e-3,
                pos: DVec3::splat(0.5),
                vel: DVec3::X,
                omega: DVec3::Z,
            }],
            gas: None,
            collisions: Some(CollisionTally::new(TallyGrid {
                lo: DVec3::ZERO,
                h: DVec3::splat(0.5),
                n: [2, 2, 2],
            })),
        };
        let path = std::env::temp_dir().join(format!("edpm-snap-{}.bin", std::process::id()));
        s.write(&path).unwrap();
        assert_eq!(Snapshot::read(&path).unwrap(), s);
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn cell_of_clamps_into_the_grid() {
        let g = TallyGrid {
            lo: DVec3::ZERO,
            h: DVec3::splat(0.5),
            n: [2, 3, 1],
        };
        assert_eq!(g.cell_of(DVec3::new(0.75, 0.25, 0.1)), 1);
        assert_eq!(g.cell_of(DVec3::new(0.75, 1.25, 0.1)), 1 + 2 * 2);
        assert_eq!(g.cell_of(DVec3::new(-1.0, 9.0, 9.0)), 2 * 2);
    }
}
