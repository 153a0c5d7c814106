//! `edpm analyse RUN_DIR`: reads the snapshots of a run, applies the
//! analyses of this module and writes CSV files and `analysis.json` into
//! `RUN_DIR/analysis/`.
//!
//! Two passes over the snapshot files keep memory bounded by one or two
//! snapshots: the first accumulates every statistic, the second the
//! histograms (which are scaled by the standard deviations of the first)
//! and the cluster fraction (whose threshold depends on the mean solids
//! fraction of the first).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use glam::DVec3;
use serde::Serialize;

use super::bed::{BedFrame, BedSample, BedSummary, bed_sample, summarise};
use super::energy::{EnergyBudget, energy_budget};
use super::figure_spec::{FIGURES, FigureSpec};
use super::grid::{
    cell_centre, cell_coords, cell_sums, cell_volume, grid_for_cell_size, single_cell_grid,
    solids_fraction, sphere_volume,
};
use super::ktgf::{
    KineticTheory, KtgfSample, KtgfSettings, effective_restitution, ktgf_samples, sauter_diameter,
};
use super::profiles::{
    AXIS_NAMES, FieldAverages, Orientation, has_side_walls, is_wall_cell, layer_means, orientation,
    pressure_bottom_top, vertical_flux, width_profile,
};
use super::segregation::{Bidisperse, classify, segregation};
use super::velocity::{Histograms, MomentAccumulator, VelocityStats, local_fluctuations};
use crate::io::output::{CsvTable, write_atomic};
use crate::io::snapshot::{Snapshot, TallyGrid};

/// Options of `edpm analyse`.
#[derive(Clone, Debug, PartialEq)]
pub struct AnalyseOptions {
    /// Only snapshots at `t ≥ t_start` are used (s).
    pub t_start: f64,
    /// Analysis cell sizes (m); the first is the primary grid of profiles,
    /// fields and distributions, the others show the cell-size dependence.
    /// Empty: the run's tally grid (the gas grid in gas runs) when it has
    /// more than one cell, otherwise cells of about 5 Sauter diameters.
    pub cell_sizes: Vec<f64>,
    /// Cells with fewer particles are skipped in the velocity statistics
    /// and the KTGF test (at least 2).
    pub min_per_cell: usize,
    /// Histogram bins.
    pub bins: usize,
    /// Heights (m above the box bottom) of the lateral profiles; empty:
    /// 5 evenly spaced (centres of 5 equal bands).
    pub heights: Vec<f64>,
    /// Tally cells with fewer pair collisions in an interval are skipped in
    /// the KTGF test.
    pub min_collisions: u64,
}

impl Default for AnalyseOptions {
    fn default() -> Self {
        AnalyseOptions {
            t_start: 0.0,
            cell_sizes: Vec::new(),
            min_per_cell: 10,
            bins: 50,
            heights: Vec::new(),
            min_collisions: 10,
        }
    }
}

/// Default cell size in Sauter diameters when the run has no tally grid.
pub const DEFAULT_CELL_DIAMETERS: f64 = 5.0;

/// Largest number of analysis cells per grid.
pub const MAX_CELLS: usize = 10_000_000;

/// Width of the packing-fraction bins of `ktgf_binned.csv` (50 bins
/// cover 0..1).
pub const KTGF_BIN_WIDTH: f64 = 0.02;

/// Default cluster threshold: cells with a solids fraction above
/// `max(CLUSTER_FACTOR × mean, CLUSTER_MIN)` count as dense clusters.
pub const CLUSTER_FACTOR: f64 = 2.0;
pub const CLUSTER_MIN: f64 = 0.01;

/// An analysis grid.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GridInfo {
    /// Requested cell size (m); for the tally grid or the one-cell grid the
    /// largest cell edge.
    pub cell_size: f64,
    pub source: &'static str,
    pub n: [usize; 3],
    /// Cell edges (m); in planar mode `h[2]` is the bed depth.
    pub h: [f64; 3],
    pub cell_volume: f64,
}

impl GridInfo {
    fn new(grid: &TallyGrid, cell_size: f64, source: &'static str) -> Self {
        GridInfo {
            cell_size,
            source,
            n: grid.n,
            h: grid.h.to_array(),
            cell_volume: cell_volume(grid),
        }
    }
}

/// Velocity statistics on one grid.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CellSizeResult {
    pub grid: GridInfo,
    /// Cell-snapshot pairs that met / missed `min_per_cell`.
    pub cell_samples_used: u64,
    pub cell_samples_skipped: u64,
    pub particles_skipped: u64,
    pub stats: VelocityStats,
    /// Standard deviation over mean of the cell solids fraction.
    pub solids_fraction_std_over_mean: f64,
}

/// Spatial heterogeneity of the solids fraction (primary grid).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Heterogeneity {
    /// Cell-snapshot samples (all cells, empty ones included).
    pub cell_samples: u64,
    pub mean_solids_fraction: f64,
    pub std_solids_fraction: f64,
    pub std_over_mean: f64,
    /// What counting noise alone gives for randomly placed particles:
    /// √(V̄_p / (ε̄ V_cell)) (Poisson statistics of the particle count).
    pub poisson_std_over_mean: f64,
    /// √(max(0, (std/mean)² − poisson²)): heterogeneity beyond counting
    /// noise, the measure to compare between runs and grids.
    pub excess_std_over_mean: f64,
    /// `max(2 × mean, 0.01)`.
    pub cluster_threshold: f64,
    /// Particles in cells above the threshold over all particles.
    pub cluster_particle_fraction: f64,
    /// Mean solids fraction of the cells next to a side wall and of the
    /// others (`None` without side walls or without core cells).
    pub wall_layer_solids_fraction: Option<f64>,
    pub core_solids_fraction: Option<f64>,
    pub wall_to_core_ratio: Option<f64>,
}

/// Number of equal height bands of [`HeightBand`] heterogeneity.
pub const HEIGHT_BANDS: usize = 5;

/// Heterogeneity of the solids fraction within one height band of the
/// primary grid (`heterogeneity_by_height.csv`), to tell developing clusters
/// (e.g. near a riser's outlet) from developed ones. Dense cells are those
/// above `max(2 × band mean, 0.01)`, the band's own threshold.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HeightBand {
    /// Band limits, m above the box bottom.
    pub height_lo: f64,
    pub height_hi: f64,
    pub mean_solids_fraction: f64,
    pub std_over_mean: f64,
    /// Counting noise, √(V̄_p / (ε̄ V_cell)), with the run's mean particle
    /// volume.
    pub poisson_std_over_mean: f64,
    pub excess_std_over_mean: f64,
    pub cluster_particle_fraction: f64,
    /// Wall-layer over core mean solids fraction (`None` without side walls).
    pub wall_to_core_ratio: Option<f64>,
}

/// Pass-2 sums of one height band: Σε, Σε², cell samples, particles,
/// particles in dense cells, and [Σε, n] of wall and core cells.
#[derive(Clone, Copy, Default)]
struct BandSums {
    eps: [f64; 3],
    particles: u64,
    clustered: u64,
    wall: [f64; 2],
    core: [f64; 2],
}

/// Velocity statistics on the primary grid without the cells that the TC
/// model or the collapse guard affected.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UnaffectedVelocity {
    /// Cell-snapshot samples (of those meeting `min_per_cell`) left out
    /// because a particle of the cell lay in a tally cell where TC or the
    /// guard made a pair or wall collision elastic during the interval
    /// before the snapshot, and the particle samples they held.
    pub cell_samples_excluded: u64,
    pub particle_samples_excluded: u64,
    pub stats: VelocityStats,
}

/// Time-averaged gas pressure drop.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PressureDropSummary {
    /// Bottom minus top layer of gas cells (Pa).
    pub mean_pressure_drop: f64,
    /// Weight of the particles per cross-section area `Σ m |g| / A` (Pa).
    pub mean_bed_weight_per_area: f64,
    pub ratio: f64,
}

/// Time-averaged energy budget.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EnergySummary {
    pub mean: EnergyBudget,
    /// Percentages of the mean total (as seed 002 Table 3).
    pub percent_of_total: EnergyBudget,
}

/// Measured against kinetic theory over a set of samples: ratios of sums.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct KtgfRatios {
    pub samples: usize,
    pub collisions: u64,
    pub mean_solids_fraction: f64,
    /// Mean of the closures' packing fraction (`ε_s`, or `ν` in planar runs).
    pub mean_packing_fraction: f64,
    /// Σ p_c measured / Σ p_c KTGF, with the reference g0
    /// (Carnahan–Starling or Henderson) and with Ma–Ahmadi (3D only).
    pub pc_ratio: f64,
    pub pc_ratio_ma: f64,
    /// Σ γ_n measured / Σ γ_n KTGF: normal dissipation against the
    /// normal-only theory, with both g0.
    pub gamma_n_ratio: f64,
    pub gamma_n_ratio_ma: f64,
    /// Σ γ_t measured / Σ γ_t rough-sphere average (undefined for smooth
    /// particles) and the total (normal plus tangential) against the sum of
    /// both theories.
    pub gamma_t_ratio: f64,
    pub gamma_total_ratio: f64,
    /// The normal restitution that normal-only theory would need to
    /// dissipate the predicted total (equals `e_n` for smooth particles).
    pub effective_restitution: f64,
    /// Energy the altered collisions did not dissipate over what was
    /// dissipated plus that (0 in the test set, by construction).
    pub undissipated_fraction: f64,
}

/// The KTGF test (src/analysis/ktgf.rs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KtgfSummary {
    pub material: u16,
    /// Nominal collision parameters of the material's pairs.
    pub e_n: f64,
    pub beta_0: f64,
    pub mu: f64,
    /// `spheres` (3D, Carnahan–Starling g0) or `disks` (planar, Henderson
    /// g0).
    pub theory: KineticTheory,
    /// Particle diameter of the dissipation rate (Sauter mean, m).
    pub diameter: f64,
    pub tally_grid: GridInfo,
    /// The test: samples (cell × interval) in which neither the TC model
    /// nor the collapse guard altered a collision.
    pub test: KtgfRatios,
    /// Every sample, the altered ones included (flagged by
    /// `altered_collisions > 0` in `ktgf_samples.csv`).
    pub all: KtgfRatios,
}

/// Degree of segregation (seed 001 Eq. 49).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SegregationSummary {
    pub species: Bidisperse,
    pub snapshots: usize,
    pub first: f64,
    pub last: f64,
    pub mean: f64,
}

/// Contents of `analysis.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AnalysisSummary {
    pub run_dir: String,
    pub output_dir: String,
    pub snapshots_total: usize,
    pub snapshots_used: usize,
    pub t_start: f64,
    pub t_first: f64,
    pub t_last: f64,
    pub planar: bool,
    /// Moving and rotational dimensions.
    pub dimensions: usize,
    pub rotational_dimensions: usize,
    pub vertical_axis: &'static str,
    /// "+" when up is the positive vertical axis.
    pub up: &'static str,
    pub width_axis: &'static str,
    pub min_per_cell: usize,
    pub primary_grid: GridInfo,
    /// Velocity statistics on the primary grid (local mean subtracted).
    pub velocity: VelocityStats,
    /// The same without the cells TC or the collapse guard affected
    /// (`null` without collision tallies).
    pub velocity_unaffected: Option<UnaffectedVelocity>,
    /// Temperature with the global mean subtracted (one cell) (m²/s²).
    pub temperature_global: f64,
    /// Fractions of samples outside the histogram ranges (x, y, z, speed).
    pub histogram_outside_fraction: [f64; 4],
    /// Every grid, the primary first and the one-cell (global mean) last.
    pub cell_size_dependence: Vec<CellSizeResult>,
    pub heights: Vec<f64>,
    pub heterogeneity: Heterogeneity,
    /// The same per height band, bottom first.
    pub heterogeneity_by_height: Vec<HeightBand>,
    pub pressure_drop: Option<PressureDropSummary>,
    /// Bed height, expansion and voids (runs with gravity), see [`super::bed`].
    pub bed: Option<BedSummary>,
    pub energy: EnergySummary,
    pub ktgf: Option<KtgfSummary>,
    pub segregation: Option<SegregationSummary>,
    pub notes: Vec<String>,
    /// Files written into `output_dir`.
    pub files: Vec<String>,
    pub figures_planned: Vec<FigureSpec>,
}

fn check_options(o: &AnalyseOptions) -> anyhow::Result<()> {
    if !o.t_start.is_finite() {
        bail!(
            "--t-start: must be a finite time in seconds, got {}",
            o.t_start
        );
    }
    if let Some(x) = o.cell_sizes.iter().find(|x| !(x.is_finite() && **x > 0.0)) {
        bail!("--cell-size: must be a length > 0 in metres, got {x}");
    }
    if o.min_per_cell < 2 {
        bail!(
            "--min-per-cell: must be at least 2 (one particle has no fluctuation about its own mean), got {}",
            o.min_per_cell
        );
    }
    if !(1..=100_000).contains(&o.bins) {
        bail!("--bins: must be in 1..=100000, got {}", o.bins);
    }
    if let Some(h) = o.heights.iter().find(|h| !h.is_finite()) {
        bail!("--heights: must be finite heights in metres, got {h}");
    }
    Ok(())
}

const SNAPSHOT_HINT: &str = "run with `[output] snapshot_interval = T` in the scenario \
     (or `edpm run SCENARIO --set output.snapshot_interval=T`)";

/// The snapshot files of a run, in order, all written by the same run.
pub fn snapshot_paths(run_dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if !run_dir.is_dir() {
        bail!("{}: no such run directory", run_dir.display());
    }
    let dir = run_dir.join("snapshots");
    if !dir.is_dir() {
        bail!("{}: no snapshots: {SNAPSHOT_HINT}", dir.display());
    }
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "bin"))
        .collect();
    if paths.is_empty() {
        bail!(
            "{}: no snapshot files (*.bin): {SNAPSHOT_HINT}",
            dir.display()
        );
    }
    paths.sort();
    Snapshot::check_one_run(&paths)?;
    Ok(paths)
}

/// One analysis grid with its running statistics.
struct GridPass {
    info: GridInfo,
    grid: TallyGrid,
    moments: MomentAccumulator,
    cells_used: u64,
    cells_skipped: u64,
    particles_skipped: u64,
    /// Σ ε, Σ ε² and samples over cells and snapshots.
    eps: [f64; 3],
}

impl GridPass {
    fn new(grid: TallyGrid, cell_size: f64, source: &'static str) -> Self {
        GridPass {
            info: GridInfo::new(&grid, cell_size, source),
            grid,
            moments: MomentAccumulator::default(),
            cells_used: 0,
            cells_skipped: 0,
            particles_skipped: 0,
            eps: [0.0; 3],
        }
    }

    fn result(&self, d: usize, d_rot: usize) -> CellSizeResult {
        let [s, s2, n] = self.eps;
        let mean = s / n;
        let std = (s2 / n - mean * mean).max(0.0).sqrt();
        CellSizeResult {
            grid: self.info.clone(),
            cell_samples_used: self.cells_used,
            cell_samples_skipped: self.cells_skipped,
            particles_skipped: self.particles_skipped,
            stats: self.moments.stats(d, d_rot),
            solids_fraction_std_over_mean: std / mean,
        }
    }
}

/// Per cell of the primary grid, pooled over snapshots.
#[derive(Clone, Copy, Debug, Default)]
struct CellPool {
    snapshots_used: usize,
    particles: usize,
    mass_used: f64,
    mass_c2: [f64; 3],
    inertia_w2: f64,
    mass: f64,
    momentum: DVec3,
}

/// Velocity statistics of the primary cells the TC model and the collapse
/// guard did not affect.
#[derive(Clone, Debug, Default)]
struct UnaffectedPass {
    moments: MomentAccumulator,
    cell_samples_excluded: u64,
    particle_samples_excluded: u64,
}

/// Sums of a set of KTGF samples.
#[derive(Clone, Copy, Debug, Default)]
struct KtgfSums {
    samples: usize,
    collisions: u64,
    eps: f64,
    packing: f64,
    temperature: f64,
    pc: [f64; 3],
    gamma_n: [f64; 3],
    gamma_t: [f64; 2],
    undissipated: f64,
}

impl KtgfSums {
    fn add(&mut self, s: &KtgfSample) {
        self.samples += 1;
        self.collisions += s.collisions;
        self.eps += s.solids_fraction;
        self.packing += s.packing_fraction;
        self.temperature += s.temperature;
        self.pc[0] += s.pc_measured;
        self.pc[1] += s.pc_ktgf;
        self.pc[2] += s.pc_ktgf_ma;
        self.gamma_n[0] += s.gamma_n_measured;
        self.gamma_n[1] += s.gamma_n_ktgf;
        self.gamma_n[2] += s.gamma_n_ktgf_ma;
        self.gamma_t[0] += s.gamma_t_measured;
        self.gamma_t[1] += s.gamma_t_theory;
        self.undissipated += s.undissipated;
    }

    fn ratios(&self, e_n: f64) -> KtgfRatios {
        let n = self.samples as f64;
        let predicted_total = self.gamma_n[1] + self.gamma_t[1];
        let dissipated = self.gamma_n[0] + self.gamma_t[0];
        KtgfRatios {
            samples: self.samples,
            collisions: self.collisions,
            mean_solids_fraction: self.eps / n,
            mean_packing_fraction: self.packing / n,
            pc_ratio: self.pc[0] / self.pc[1],
            pc_ratio_ma: self.pc[0] / self.pc[2],
            gamma_n_ratio: self.gamma_n[0] / self.gamma_n[1],
            gamma_n_ratio_ma: self.gamma_n[0] / self.gamma_n[2],
            gamma_t_ratio: self.gamma_t[0] / self.gamma_t[1],
            gamma_total_ratio: dissipated / predicted_total,
            effective_restitution: effective_restitution(e_n, self.gamma_t[1] / self.gamma_n[1]),
            undissipated_fraction: self.undissipated / (dissipated + self.undissipated),
        }
    }
}

/// KTGF settings resolved from the scenario, and the samples so far.
struct KtgfState {
    settings: KtgfSettings,
    material: u16,
    samples: CsvTable,
    test: KtgfSums,
    all: KtgfSums,
    /// Per packing-fraction bin, test samples only.
    bins: Vec<KtgfSums>,
}

const KTGF_SAMPLE_HEADER: [&str; 25] = [
    "time_s",
    "cell",
    "solids_fraction",
    "packing_fraction",
    "T_m2_s2",
    "T_rot_m2_s2",
    "density_kg_m3",
    "particles",
    "collisions",
    "altered_collisions",
    "g0",
    "g0_ma",
    "pk_Pa",
    "pc_measured_Pa",
    "pc_ktgf_Pa",
    "pc_ktgf_ma_Pa",
    "gamma_n_measured_W_m3",
    "gamma_n_ktgf_W_m3",
    "gamma_n_ktgf_ma_W_m3",
    "gamma_t_measured_W_m3",
    "gamma_t_theory_W_m3",
    "undissipated_W_m3",
    "gamma_n_ratio",
    "pc_ratio",
    "interval_s",
];

const KTGF_BIN_HEADER: [&str; 20] = [
    "packing_lo",
    "packing_hi",
    "samples",
    "collisions",
    "solids_fraction",
    "packing_fraction",
    "T_m2_s2",
    "pc_measured_Pa",
    "pc_ktgf_Pa",
    "pc_ktgf_ma_Pa",
    "pc_ratio",
    "pc_ratio_ma",
    "gamma_n_measured_W_m3",
    "gamma_n_ktgf_W_m3",
    "gamma_n_ktgf_ma_W_m3",
    "gamma_n_ratio",
    "gamma_n_ratio_ma",
    "gamma_t_measured_W_m3",
    "gamma_t_theory_W_m3",
    "gamma_t_ratio",
];

impl KtgfState {
    fn add(&mut self, samples: &[KtgfSample], interval: f64) {
        for s in samples {
            self.samples.row(&[
                s.time,
                s.cell as f64,
                s.solids_fraction,
                s.packing_fraction,
                s.temperature,
                s.temperature_rotational,
                s.density,
                s.particles,
                s.collisions as f64,
                s.altered_collisions as f64,
                s.g0,
                s.g0_ma,
                s.pk,
                s.pc_measured,
                s.pc_ktgf,
                s.pc_ktgf_ma,
                s.gamma_n_measured,
                s.gamma_n_ktgf,
                s.gamma_n_ktgf_ma,
                s.gamma_t_measured,
                s.gamma_t_theory,
                s.undissipated,
                s.gamma_n_measured / s.gamma_n_ktgf,
                s.pc_measured / s.pc_ktgf,
                interval,
            ]);
            self.all.add(s);
            if s.altered_collisions > 0 {
                continue;
            }
            self.test.add(s);
            let k = ((s.packing_fraction / KTGF_BIN_WIDTH).floor().max(0.0) as usize)
                .min(self.bins.len() - 1);
            self.bins[k].add(s);
        }
    }

    fn binned(&self) -> CsvTable {
        let mut t = CsvTable::new(&KTGF_BIN_HEADER);
        for (k, b) in self.bins.iter().enumerate() {
            if b.samples == 0 {
                continue;
            }
            let n = b.samples as f64;
            let r = b.ratios(self.settings.e_n);
            t.row(&[
                k as f64 * KTGF_BIN_WIDTH,
                (k + 1) as f64 * KTGF_BIN_WIDTH,
                n,
                b.collisions as f64,
                r.mean_solids_fraction,
                r.mean_packing_fraction,
                b.temperature / n,
                b.pc[0] / n,
                b.pc[1] / n,
                b.pc[2] / n,
                r.pc_ratio,
                r.pc_ratio_ma,
                b.gamma_n[0] / n,
                b.gamma_n[1] / n,
                b.gamma_n[2] / n,
                r.gamma_n_ratio,
                r.gamma_n_ratio_ma,
                b.gamma_t[0] / n,
                b.gamma_t[1] / n,
                r.gamma_t_ratio,
            ]);
        }
        t
    }
}

/// Everything accumulated in the first pass.
struct Pass1<'a> {
    opts: &'a AnalyseOptions,
    lo: DVec3,
    hi: DVec3,
    planar: bool,
    periodic: [bool; 3],
    gravity: DVec3,
    d: usize,
    d_rot: usize,
    orient: Orientation,
    grids: Vec<GridPass>,
    heights: Vec<f64>,
    snapshots: usize,
    t_first: f64,
    t_last: f64,
    series: CsvTable,
    cells: Vec<CellPool>,
    fields: FieldAverages,
    /// Σ ε and samples over wall-layer and core cells.
    wall: [f64; 2],
    core: [f64; 2],
    energy: CsvTable,
    energy_sum: EnergyBudget,
    pressure: Option<CsvTable>,
    pressure_sum: [f64; 3],
    /// `None` until the first snapshot with particles decides.
    species: Option<Result<Bidisperse, String>>,
    segregation: CsvTable,
    segregation_values: Vec<f64>,
    /// `None` until the first snapshot with particles decides.
    ktgf: Option<Result<KtgfState, String>>,
    scenario: Result<crate::scenario::Scenario, String>,
    global_t: [f64; 2],
    /// Velocity statistics without TC- or guard-affected cells (runs with
    /// collision tallies).
    unaffected: Option<UnaffectedPass>,
    /// The collision tally grid (the KTGF cells).
    tally: Option<TallyGrid>,
    /// Bed height and voids per snapshot (runs with gravity), and the
    /// solids volume of the last snapshot (m³).
    bed: Vec<BedSample>,
    solids_volume: f64,
    notes: Vec<String>,
}

fn header(cols: &[&str]) -> CsvTable {
    CsvTable::new(cols)
}

/// The analysis grids: the requested cell sizes (or the run's tally grid,
/// or cells of [`DEFAULT_CELL_DIAMETERS`] Sauter diameters), then the
/// one-cell grid of the global mean.
fn analysis_grids(
    first: &Snapshot,
    opts: &AnalyseOptions,
    tally: Option<&TallyGrid>,
    d: usize,
) -> anyhow::Result<Vec<GridPass>> {
    let (lo, hi, planar) = (first.lo, first.hi, first.planar);
    let mut grids = Vec::new();
    if opts.cell_sizes.is_empty() {
        match tally.filter(|g| g.cells() > 1) {
            Some(g) => {
                let size = (0..d).map(|a| g.h[a]).fold(0.0, f64::max);
                grids.push(GridPass::new(g.clone(), size, "tally grid of the run"));
            }
            None => {
                let dp = sauter_diameter(&first.particles);
                if !dp.is_finite() {
                    bail!(
                        "--cell-size: no particles in the first snapshot analysed (t = {} s) to size the default cells; give --cell-size",
                        first.time
                    );
                }
                let size = DEFAULT_CELL_DIAMETERS * dp;
                grids.push(GridPass::new(
                    grid_for_cell_size(lo, hi, planar, size),
                    size,
                    "default: 5 Sauter diameters",
                ));
            }
        }
    } else {
        for &size in &opts.cell_sizes {
            grids.push(GridPass::new(
                grid_for_cell_size(lo, hi, planar, size),
                size,
                "--cell-size",
            ));
        }
    }
    for g in &grids {
        if g.grid.cells() > MAX_CELLS {
            bail!(
                "--cell-size: {} m gives {} cells ({:?} per axis), more than {MAX_CELLS}",
                g.info.cell_size,
                g.grid.cells(),
                g.grid.n
            );
        }
    }
    let e = hi - lo;
    grids.push(GridPass::new(
        single_cell_grid(lo, hi),
        e.x.max(e.y).max(if planar { 0.0 } else { e.z }),
        "one cell: global mean",
    ));
    Ok(grids)
}

/// Heights of the lateral profiles (m above the box bottom): `--heights`,
/// checked against the box, or the centres of 5 equal bands.
fn profile_heights(
    opts: &AnalyseOptions,
    orient: &Orientation,
    box_height: f64,
) -> anyhow::Result<Vec<f64>> {
    Ok(if opts.heights.is_empty() {
        (0..5)
            .map(|k| (k as f64 + 0.5) / 5.0 * box_height)
            .collect()
    } else {
        if let Some(h) = opts.heights.iter().find(|h| **h < 0.0 || **h > box_height) {
            bail!(
                "--heights: {h} m is outside the box, whose height along {} is 0 to {box_height} m",
                AXIS_NAMES[orient.vertical]
            );
        }
        opts.heights.clone()
    })
}

/// Header of `temperature_timeseries.csv` in `d` dimensions.
fn series_header(d: usize) -> CsvTable {
    let axes: Vec<&str> = AXIS_NAMES[..d].to_vec();
    let mut cols: Vec<String> = [
        "time_s",
        "particles",
        "particles_used",
        "cells_used",
        "cells_skipped",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    cols.extend(axes.iter().map(|a| format!("T_{a}_m2_s2")));
    cols.extend(
        [
            "T_m2_s2",
            "T_rot_m2_s2",
            "T_global_m2_s2",
            "sonine_a2",
            "sonine_a2_cell",
            "mean_solids_fraction",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    header(&cols.iter().map(String::as_str).collect::<Vec<_>>())
}

/// The run's `scenario.toml`, or why it cannot be read.
fn run_scenario(run_dir: &Path) -> Result<crate::scenario::Scenario, String> {
    let scenario_path = run_dir.join("scenario.toml");
    std::fs::read_to_string(&scenario_path)
        .map_err(|e| format!("{}: {e}", scenario_path.display()))
        .and_then(|text| {
            crate::scenario::Scenario::from_str_named(
                &text,
                &scenario_path.display().to_string(),
                &[],
            )
            .map_err(|e| e.to_string())
        })
}

impl<'a> Pass1<'a> {
    /// Empty accumulators for the run whose first snapshot analysed is
    /// `first`.
    fn new(run_dir: &Path, first: &Snapshot, opts: &'a AnalyseOptions) -> anyhow::Result<Self> {
        let (lo, hi, planar) = (first.lo, first.hi, first.planar);
        let d = if planar { 2 } else { 3 };
        let d_rot = if planar { 1 } else { 3 };
        let mut notes = Vec::new();
        let tally = first.collisions.as_ref().map(|c| c.grid.clone());
        let grids = analysis_grids(first, opts, tally.as_ref(), d)?;
        let primary = grids[0].grid.clone();
        let orient = orientation(first.gravity, primary.n, planar);
        let box_height = orient.box_height(lo, hi);
        let heights = profile_heights(opts, &orient, box_height)?;
        let series = series_header(d);
        let pressure = first.gas.as_ref().map(|_| {
            header(&[
                "time_s",
                "pressure_bottom_Pa",
                "pressure_top_Pa",
                "pressure_drop_Pa",
                "bed_weight_per_area_Pa",
            ])
        });
        let scenario = run_scenario(run_dir);
        if planar {
            notes.push(
                "planar mode: solids fractions are slab fractions (particle volume over cell area × bed depth); \
                 temperatures use d = 2 and d_rot = 1; the KTGF test uses the hard-disk closures with the area fraction"
                    .to_string(),
            );
        }
        let cells = primary.cells();
        Ok(Pass1 {
            opts,
            lo,
            hi,
            planar,
            periodic: first.periodic,
            gravity: first.gravity,
            d,
            d_rot,
            orient,
            grids,
            heights,
            bed: Vec::new(),
            solids_volume: 0.0,
            snapshots: 0,
            t_first: first.time,
            t_last: first.time,
            series,
            cells: vec![CellPool::default(); cells],
            fields: FieldAverages::new(cells),
            wall: [0.0; 2],
            core: [0.0; 2],
            energy: CsvTable::new(&EnergyBudget::HEADER),
            energy_sum: EnergyBudget::default(),
            pressure,
            pressure_sum: [0.0; 3],
            species: None,
            segregation: header(&[
                "time_s",
                "n_small",
                "n_large",
                "h_small_m",
                "h_large_m",
                "x_large",
                "S",
                "S_max",
                "segregation_index",
            ]),
            segregation_values: Vec::new(),
            ktgf: None,
            scenario,
            global_t: [0.0; 2],
            unaffected: first.collisions.as_ref().map(|_| UnaffectedPass::default()),
            tally,
            notes,
        })
    }

    fn primary(&self) -> &TallyGrid {
        &self.grids[0].grid
    }

    fn bed_frame(&self) -> BedFrame {
        BedFrame {
            lo: self.lo,
            hi: self.hi,
            vertical: self.orient.vertical,
            up: self.orient.up,
        }
    }

    /// Resolves the KTGF settings and the species at the first snapshot
    /// with particles.
    fn decide(&mut self, snap: &Snapshot) {
        let Some(first) = snap.particles.first() else {
            return;
        };
        if self.species.is_none() {
            self.species = Some(classify(&snap.particles));
        }
        if self.ktgf.is_none() {
            let m = first.material;
            let state = match &self.scenario {
                Err(e) => Err(format!(
                    "KTGF test skipped: cannot read the run's scenario: {e}"
                )),
                Ok(s) => match s.contacts.get(m, m) {
                    None => Err(format!(
                        "KTGF test skipped: no collision parameters for material {m} in scenario.toml"
                    )),
                    Some(c) => {
                        if c.e_n < 1.0 {
                            let tc = if s.collisions.tc > 0.0 {
                                format!("TC model (tc = {} s) and ", s.collisions.tc)
                            } else {
                                String::new()
                            };
                            self.notes.push(format!(
                                "{tc}collapse guard (max_collisions_per_step = {}, i.e. above {:.3e} collisions/s per particle at dt_flow = {} s): \
                                 cells where they made collisions elastic are flagged (altered_collisions in ktgf_samples.csv) and left out of \
                                 ktgf_binned.csv and the `test` ratios, and left out of `velocity_unaffected`",
                                s.collisions.max_collisions_per_step,
                                s.collisions.max_collisions_per_step as f64 / s.time.dt_flow,
                                s.time.dt_flow
                            ));
                        }
                        if !c.is_smooth() {
                            self.notes.push(
                                "rough particles: the normal dissipation is compared with normal-only KTGF, the tangential \
                                 (friction and spin) with the rough-sphere average (gamma_t)"
                                    .to_string(),
                            );
                        }
                        if s.materials.iter().filter(|m| m.density.is_some()).count() > 1 {
                            self.notes.push(format!(
                                "several particle materials: the KTGF test uses the parameters of the pair ({m}, {m}), the first particle's material"
                            ));
                        }
                        Ok(KtgfState {
                            settings: KtgfSettings {
                                d: self.d,
                                e_n: c.e_n,
                                beta_0: c.beta_0,
                                mu: c.mu,
                                diameter: sauter_diameter(&snap.particles),
                                min_per_cell: self.opts.min_per_cell,
                                min_collisions: self.opts.min_collisions,
                            },
                            material: m,
                            samples: CsvTable::new(&KTGF_SAMPLE_HEADER),
                            test: KtgfSums::default(),
                            all: KtgfSums::default(),
                            bins: vec![
                                KtgfSums::default();
                                (1.0 / KTGF_BIN_WIDTH).round() as usize
                            ],
                        })
                    }
                },
            };
            self.ktgf = Some(state);
        }
    }

    /// Pressure drop against the bed weight per area (gas runs).
    fn add_pressure_drop(&mut self, snap: &Snapshot) {
        let ps = &snap.particles;
        if let (Some(table), Some(gas)) = (self.pressure.as_mut(), snap.gas.as_ref()) {
            let (pb, pt) = pressure_bottom_top(gas, &self.orient);
            let ext = self.hi - self.lo;
            let area = (0..3)
                .filter(|&a| a != self.orient.vertical)
                .map(|a| ext[a])
                .product::<f64>();
            let weight = ps.iter().map(|p| p.mass).sum::<f64>() * self.gravity.length() / area;
            table.row(&[snap.time, pb, pt, pb - pt, weight]);
            self.pressure_sum[0] += pb - pt;
            self.pressure_sum[1] += weight;
            self.pressure_sum[2] += 1.0;
        }
    }

    /// Degree of segregation (bidisperse beds).
    fn add_segregation(&mut self, snap: &Snapshot) {
        let ps = &snap.particles;
        if let Some(Ok(species)) = &self.species
            && let Some(s) = segregation(ps, species, &self.orient, self.lo, self.hi)
        {
            self.segregation.row(&[
                snap.time,
                s.n_small as f64,
                s.n_large as f64,
                s.h_small,
                s.h_large,
                s.x_large,
                s.ratio,
                s.ratio_max,
                s.index,
            ]);
            self.segregation_values.push(s.index);
        }
    }

    fn add(&mut self, snap: &Snapshot, prev: Option<&Snapshot>) {
        self.decide(snap);
        self.snapshots += 1;
        self.t_last = snap.time;
        let ps = &snap.particles;
        let (d, d_rot) = (self.d, self.d_rot);
        // Velocity statistics on every grid.
        let mut primary_fl = None;
        for (k, g) in self.grids.iter_mut().enumerate() {
            let fl = local_fluctuations(ps, &g.grid, self.opts.min_per_cell);
            g.moments.add_all(&fl, d);
            g.cells_used += fl.cells_used as u64;
            g.cells_skipped += fl.cells_skipped as u64;
            g.particles_skipped += fl.particles_skipped as u64;
            let (sums, _) = cell_sums(ps, &g.grid);
            for e in solids_fraction(&sums, &g.grid) {
                g.eps[0] += e;
                g.eps[1] += e * e;
                g.eps[2] += 1.0;
            }
            if k == 0 {
                primary_fl = Some(fl);
            }
        }
        let fl = primary_fl.unwrap_or_default();
        let grid = self.primary().clone();
        // Per-snapshot temperatures.
        let mut snap_moments = MomentAccumulator::default();
        snap_moments.add_all(&fl, d);
        let st = snap_moments.stats(d, d_rot);
        let global = local_fluctuations(ps, &single_cell_grid(self.lo, self.hi), 1);
        let (gm, gmc2) = global.samples.iter().fold((0.0, 0.0), |(m, e), f| {
            (m + f.mass, e + f.unbias() * f.mass * f.c.length_squared())
        });
        let t_global = gmc2 / (d as f64 * gm);
        self.global_t[0] += gmc2;
        self.global_t[1] += gm;
        // Cell pools.
        for f in &fl.samples {
            let c = &mut self.cells[f.cell];
            let unbias = f.unbias();
            c.mass_used += f.mass;
            for a in 0..3 {
                c.mass_c2[a] += unbias * f.mass * f.c[a] * f.c[a];
            }
            c.inertia_w2 += unbias * f.inertia * f.w.length_squared();
        }
        // The same statistics without the primary cells holding a particle
        // in a tally cell where TC or the guard altered a collision during
        // the interval before this snapshot.
        if let (Some(u), Some(tally)) = (self.unaffected.as_mut(), snap.collisions.as_ref()) {
            let mut affected = vec![false; grid.cells()];
            for f in &fl.samples {
                affected[f.cell] |= tally.altered(tally.grid.cell_of(ps[f.index].pos));
            }
            u.cell_samples_excluded += affected.iter().filter(|&&a| a).count() as u64;
            let kept: Vec<_> = fl
                .samples
                .iter()
                .filter(|f| !affected[f.cell])
                .copied()
                .collect();
            u.particle_samples_excluded += (fl.samples.len() - kept.len()) as u64;
            u.moments.add_samples(&kept, d);
        }
        let (sums, _) = cell_sums(ps, &grid);
        let min = self.opts.min_per_cell;
        for (c, s) in self.cells.iter_mut().zip(&sums) {
            c.particles += s.count;
            c.mass += s.mass;
            c.momentum += s.momentum;
            if s.count >= min {
                c.snapshots_used += 1;
            }
        }
        let eps = solids_fraction(&sums, &grid);
        let flux = vertical_flux(&sums, &grid, &self.orient);
        self.fields.add(&eps, &flux);
        self.solids_volume = ps.iter().map(|q| sphere_volume(q.radius)).sum();
        if self.gravity != DVec3::ZERO
            && let Some(b) = bed_sample(snap.time, ps, &eps, &grid, &self.bed_frame())
        {
            self.bed.push(b);
        }
        for (c, e) in eps.iter().enumerate() {
            let acc = if is_wall_cell(&grid, c, &self.orient, self.periodic, self.planar) {
                &mut self.wall
            } else {
                &mut self.core
            };
            acc[0] += e;
            acc[1] += 1.0;
        }
        let mean_eps = eps.iter().sum::<f64>() / eps.len().max(1) as f64;
        let mut row = vec![
            snap.time,
            ps.len() as f64,
            fl.samples.len() as f64,
            fl.cells_used as f64,
            fl.cells_skipped as f64,
        ];
        row.extend(&st.temperature_components);
        row.extend([
            st.temperature,
            st.temperature_rotational,
            t_global,
            st.sonine_a2,
            st.sonine_a2_cell_normalised,
            mean_eps,
        ]);
        self.series.row(&row);
        // Energy budget.
        let e = energy_budget(ps, &grid, self.gravity, self.lo, self.hi);
        self.energy.row(&e.row(snap.time));
        self.energy_sum.add(&e);
        self.add_pressure_drop(snap);
        self.add_segregation(snap);
        // KTGF test over the interval since the previous snapshot.
        if let (Some(Ok(k)), Some(prev), Some(tally)) =
            (self.ktgf.as_mut(), prev, snap.collisions.as_ref())
        {
            let samples = ktgf_samples(&prev.particles, ps, tally, snap.time, &k.settings);
            k.add(&samples, tally.interval);
        }
    }
}

/// Checks that `snap` comes from the same box as `first`.
fn same_run(
    path: &Path,
    snap: &Snapshot,
    lo: DVec3,
    hi: DVec3,
    planar: bool,
) -> anyhow::Result<()> {
    if snap.lo != lo || snap.hi != hi || snap.planar != planar {
        bail!(
            "{}: box {}..{} (planar {}) differs from the first snapshot's {}..{} (planar {}): not from the same run",
            path.display(),
            snap.lo,
            snap.hi,
            snap.planar,
            lo,
            hi,
            planar
        );
    }
    Ok(())
}

fn used(snap: &Snapshot, t_start: f64) -> bool {
    snap.time >= t_start - 1e-12 * t_start.abs()
}

/// Pass-2 sums on the primary grid: the velocity histograms (scaled by the
/// pass-1 statistics), the cluster counts (threshold from the pass-1 mean
/// solids fraction) and the per-height-band sums.
struct Pass2 {
    hist: Histograms,
    /// Particle samples in cells above the cluster threshold, and in all.
    in_clusters: u64,
    particles_total: u64,
    /// Σ particle volume over the snapshots used (m³).
    particle_volume_sum: f64,
    bands: [BandSums; HEIGHT_BANDS],
}

/// `RUN_DIR/analysis/` and the names of the files written into it, in the
/// order written.
struct OutputFiles {
    dir: PathBuf,
    names: Vec<String>,
}

impl OutputFiles {
    fn write(&mut self, name: &str, table: &CsvTable) -> anyhow::Result<()> {
        table.write(&self.dir.join(name))?;
        self.names.push(name.to_string());
        Ok(())
    }
}

/// Pass 1 over the snapshots at `t ≥ t_start`: every statistic.
fn first_pass<'a>(
    run_dir: &Path,
    paths: &[PathBuf],
    opts: &'a AnalyseOptions,
) -> anyhow::Result<Pass1<'a>> {
    let mut pass: Option<Pass1> = None;
    let mut prev: Option<Snapshot> = None;
    let mut last_time = f64::NAN;
    for (k, path) in paths.iter().enumerate() {
        let snap = Snapshot::read(path)?;
        if k > 0 {
            Snapshot::check_follows(&paths[k - 1], last_time, path, snap.time)?;
        }
        last_time = snap.time;
        if used(&snap, opts.t_start) {
            match pass.as_ref() {
                Some(p) => same_run(path, &snap, p.lo, p.hi, p.planar)?,
                None => pass = Some(Pass1::new(run_dir, &snap, opts)?),
            }
            if let Some(p) = pass.as_mut() {
                let prev_used = prev.as_ref().filter(|q| used(q, opts.t_start));
                p.add(&snap, prev_used);
            }
        }
        prev = Some(snap);
    }
    let Some(p) = pass else {
        bail!(
            "--t-start: no snapshot at t >= {} s (the last of {} is at t = {last_time} s)",
            opts.t_start,
            paths.len()
        );
    };
    Ok(p)
}

/// Pass 2 over the snapshots at `t ≥ t_start`: histograms, clusters above
/// `cluster_threshold` and the height bands on the primary `grid`.
fn second_pass(
    p: &Pass1,
    paths: &[PathBuf],
    grid: &TallyGrid,
    stats: &VelocityStats,
    mean_eps_field: &[f64],
    cluster_threshold: f64,
) -> anyhow::Result<Pass2> {
    let opts = p.opts;
    let mut hist = Histograms::new(opts.bins, stats, p.d);
    let (mut in_clusters, mut particles_total) = (0u64, 0u64);
    let mut particle_volume_sum = 0.0;
    let layers = grid.n[p.orient.vertical];
    let band_of = |c: usize| p.orient.layer(grid, c) * HEIGHT_BANDS / layers;
    let mut band_mean = [[0.0f64; 2]; HEIGHT_BANDS];
    for (c, e) in mean_eps_field.iter().enumerate() {
        band_mean[band_of(c)][0] += e;
        band_mean[band_of(c)][1] += 1.0;
    }
    let band_threshold = band_mean.map(|[s, n]| (CLUSTER_FACTOR * s / n.max(1.0)).max(CLUSTER_MIN));
    let mut bands = [BandSums::default(); HEIGHT_BANDS];
    for path in paths {
        let snap = Snapshot::read(path)?;
        if !used(&snap, opts.t_start) {
            continue;
        }
        for f in &local_fluctuations(&snap.particles, grid, opts.min_per_cell).samples {
            hist.add(f);
        }
        particle_volume_sum += snap
            .particles
            .iter()
            .map(|q| sphere_volume(q.radius))
            .sum::<f64>();
        let (sums, cells) = cell_sums(&snap.particles, grid);
        let eps = solids_fraction(&sums, grid);
        particles_total += cells.len() as u64;
        in_clusters += cells
            .iter()
            .filter(|&&c| eps[c] > cluster_threshold)
            .count() as u64;
        for (c, &e) in eps.iter().enumerate() {
            let b = &mut bands[band_of(c)];
            b.eps[0] += e;
            b.eps[1] += e * e;
            b.eps[2] += 1.0;
            let side = if is_wall_cell(grid, c, &p.orient, p.periodic, p.planar) {
                &mut b.wall
            } else {
                &mut b.core
            };
            side[0] += e;
            side[1] += 1.0;
        }
        for &c in &cells {
            let b = band_of(c);
            bands[b].particles += 1;
            bands[b].clustered += u64::from(eps[c] > band_threshold[b]);
        }
    }
    Ok(Pass2 {
        hist,
        in_clusters,
        particles_total,
        particle_volume_sum,
        bands,
    })
}

/// `velocity_distribution.csv`: component distributions, pooled and per
/// cell, with the Gaussian.
fn velocity_distribution_table(hist: &Histograms, axes: &[&str]) -> CsvTable {
    let mut cols = vec!["c_over_sigma".to_string()];
    cols.extend(axes.iter().map(|a| format!("f_{a}")));
    cols.extend(axes.iter().map(|a| format!("f_{a}_cell")));
    cols.push("gaussian".to_string());
    let mut t = header(&cols.iter().map(String::as_str).collect::<Vec<_>>());
    for row in hist.component_rows() {
        t.row(&row);
    }
    t
}

/// `speed_distribution.csv`: speed distributions with the Maxwellian.
fn speed_distribution_table(hist: &Histograms) -> CsvTable {
    let mut t = header(&["c_over_sqrt_T", "f", "f_cell", "maxwellian"]);
    for row in hist.speed_rows() {
        t.row(&row);
    }
    t
}

/// `cell_size_dependence.csv`: one row per analysis grid.
fn cell_size_table(results: &[CellSizeResult], axes: &[&str]) -> CsvTable {
    let mut cols: Vec<String> = [
        "cell_size_m",
        "h_x_m",
        "h_y_m",
        "h_z_m",
        "cells",
        "cell_samples_used",
        "cell_samples_skipped",
        "particles_per_used_cell",
        "samples",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    cols.extend(axes.iter().map(|a| format!("T_{a}_m2_s2")));
    cols.extend(
        [
            "T_m2_s2",
            "T_rot_m2_s2",
            "sonine_a2",
            "sonine_a2_se",
            "sonine_a2_cell",
            "sonine_a2_cell_se",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    cols.extend(axes.iter().map(|a| format!("kurtosis_{a}")));
    cols.extend(axes.iter().map(|a| format!("kurtosis_{a}_cell")));
    cols.push("solids_fraction_std_over_mean".to_string());
    let mut t = header(&cols.iter().map(String::as_str).collect::<Vec<_>>());
    for r in results {
        let mut row = vec![
            r.grid.cell_size,
            r.grid.h[0],
            r.grid.h[1],
            r.grid.h[2],
            (r.grid.n[0] * r.grid.n[1] * r.grid.n[2]) as f64,
            r.cell_samples_used as f64,
            r.cell_samples_skipped as f64,
            r.stats.samples as f64 / r.cell_samples_used.max(1) as f64,
            r.stats.samples as f64,
        ];
        row.extend(&r.stats.temperature_components);
        row.extend([
            r.stats.temperature,
            r.stats.temperature_rotational,
            r.stats.sonine_a2,
            r.stats.sonine_a2_se,
            r.stats.sonine_a2_cell_normalised,
            r.stats.sonine_a2_cell_normalised_se,
        ]);
        row.extend(&r.stats.kurtosis);
        row.extend(&r.stats.kurtosis_cell_normalised);
        row.push(r.solids_fraction_std_over_mean);
        t.row(&row);
    }
    t
}

/// `cell_fields.csv`: time-averaged fields per primary-grid cell.
fn cell_fields_table(
    p: &Pass1,
    grid: &TallyGrid,
    mean_eps_field: &[f64],
    mean_flux_field: &[f64],
    axes: &[&str],
) -> CsvTable {
    let (d, d_rot) = (p.d, p.d_rot);
    let mut cols: Vec<String> = [
        "cell",
        "i",
        "j",
        "k",
        "x_m",
        "y_m",
        "z_m",
        "snapshots_used",
        "mean_particles",
        "solids_fraction",
        "solids_flux_kg_m2_s",
        "velocity_x_m_s",
        "velocity_y_m_s",
        "velocity_z_m_s",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    cols.extend(axes.iter().map(|a| format!("T_{a}_m2_s2")));
    cols.extend(["T_m2_s2", "T_rot_m2_s2"].iter().map(|s| s.to_string()));
    let mut t = header(&cols.iter().map(String::as_str).collect::<Vec<_>>());
    let snapshots = p.snapshots.max(1) as f64;
    for (c, pool) in p.cells.iter().enumerate() {
        let [i, j, k] = cell_coords(grid, c);
        let x = cell_centre(grid, c);
        let v = pool.momentum / pool.mass;
        let mut row = vec![
            c as f64,
            i as f64,
            j as f64,
            k as f64,
            x.x,
            x.y,
            x.z,
            pool.snapshots_used as f64,
            pool.particles as f64 / snapshots,
            mean_eps_field[c],
            mean_flux_field[c],
            v.x,
            v.y,
            v.z,
        ];
        let ti: Vec<f64> = (0..d).map(|a| pool.mass_c2[a] / pool.mass_used).collect();
        row.extend(&ti);
        row.push(ti.iter().sum::<f64>() / d as f64);
        row.push(pool.inertia_w2 / (d_rot as f64 * pool.mass_used));
        t.row(&row);
    }
    t
}

/// `profiles_width.csv`: lateral profiles at the profile heights.
fn width_profiles_table(
    p: &Pass1,
    grid: &TallyGrid,
    mean_eps_field: &[f64],
    mean_flux_field: &[f64],
) -> CsvTable {
    let o = p.orient;
    let mut t = header(&[
        "height_m",
        "layer_height_m",
        "width_m",
        "solids_fraction",
        "solids_flux_kg_m2_s",
    ]);
    for &h in &p.heights {
        let layer = o.layer_of_height(grid, h);
        let eps = width_profile(mean_eps_field, grid, &o, layer);
        let flux = width_profile(mean_flux_field, grid, &o, layer);
        for ((w, e), (_, f)) in eps.iter().zip(&flux) {
            t.row(&[h, o.layer_height(grid, layer), *w, *e, *f]);
        }
    }
    t
}

/// `profile_height.csv`: layer means along the vertical.
fn height_profile_table(
    o: &Orientation,
    grid: &TallyGrid,
    mean_eps_field: &[f64],
    mean_flux_field: &[f64],
) -> CsvTable {
    let mut t = header(&["height_m", "solids_fraction", "solids_flux_kg_m2_s"]);
    let eps_layers = layer_means(mean_eps_field, grid, o);
    let flux_layers = layer_means(mean_flux_field, grid, o);
    for (l, (e, f)) in eps_layers.iter().zip(&flux_layers).enumerate() {
        t.row(&[o.layer_height(grid, l), *e, *f]);
    }
    t
}

/// Writes `pressure_drop.csv` (gas runs) and returns its time average;
/// without gas, a note.
fn pressure_drop_summary(
    p: &mut Pass1,
    out: &mut OutputFiles,
) -> anyhow::Result<Option<PressureDropSummary>> {
    Ok(match &p.pressure {
        Some(table) => {
            out.write("pressure_drop.csv", table)?;
            let [dp, w, n] = p.pressure_sum;
            Some(PressureDropSummary {
                mean_pressure_drop: dp / n,
                mean_bed_weight_per_area: w / n,
                ratio: dp / w,
            })
        }
        None => {
            p.notes
                .push("no gas phase: no pressure-drop time series".to_string());
            None
        }
    })
}

/// `bed_timeseries.csv`: bed height and voids per snapshot.
fn bed_timeseries_table(bed: &[BedSample]) -> CsvTable {
    let mut t = header(&[
        "time_s",
        "centroid_height_m",
        "bed_height_m",
        "height_95_m",
        "voids",
        "void_diameter_mean_m",
        "void_fraction",
    ]);
    for b in bed {
        let mean_d =
            b.voids.iter().map(|v| v.equivalent_diameter).sum::<f64>() / b.voids.len() as f64;
        t.row(&[
            b.time,
            b.centroid_height,
            2.0 * b.centroid_height,
            b.height_95,
            b.voids.len() as f64,
            mean_d,
            b.void_fraction,
        ]);
    }
    t
}

/// Mean, standard deviation and count of the primary grid's cell solids
/// fractions over all snapshots used (`[mean, std, samples]`).
fn primary_solids_fraction(p: &Pass1) -> [f64; 3] {
    let [es, es2, en] = p.grids[0].eps;
    let eps_mean = es / en;
    let eps_std = (es2 / en - eps_mean * eps_mean).max(0.0).sqrt();
    [eps_mean, eps_std, en]
}

/// Heterogeneity of the solids fraction on the primary grid; a note when
/// there is no wall-layer/core comparison.
fn heterogeneity_summary(
    p: &mut Pass1,
    p2: &Pass2,
    grid: &TallyGrid,
    cluster_threshold: f64,
) -> Heterogeneity {
    let [eps_mean, eps_std, en] = primary_solids_fraction(p);
    let side_walls = has_side_walls(&p.orient, p.periodic, p.planar);
    let (wall, core) = if side_walls && p.core[1] > 0.0 && p.wall[1] > 0.0 {
        (Some(p.wall[0] / p.wall[1]), Some(p.core[0] / p.core[1]))
    } else {
        p.notes.push(if side_walls {
            "every analysis cell touches a side wall: no wall-layer/core comparison".to_string()
        } else {
            "no side walls: no wall-layer/core comparison".to_string()
        });
        (None, None)
    };
    let mean_particle_volume = p2.particle_volume_sum / p2.particles_total.max(1) as f64;
    let poisson = (mean_particle_volume / (eps_mean * super::grid::cell_volume(grid))).sqrt();
    Heterogeneity {
        cell_samples: en as u64,
        mean_solids_fraction: eps_mean,
        std_solids_fraction: eps_std,
        std_over_mean: eps_std / eps_mean,
        poisson_std_over_mean: poisson,
        excess_std_over_mean: ((eps_std / eps_mean).powi(2) - poisson * poisson)
            .max(0.0)
            .sqrt(),
        cluster_threshold,
        cluster_particle_fraction: p2.in_clusters as f64 / p2.particles_total.max(1) as f64,
        wall_layer_solids_fraction: wall,
        core_solids_fraction: core,
        wall_to_core_ratio: wall.zip(core).map(|(w, c)| w / c),
    }
}

/// The heterogeneity per height band, bottom first.
fn heterogeneity_by_height(p: &Pass1, p2: &Pass2, grid: &TallyGrid) -> Vec<HeightBand> {
    let o = p.orient;
    let side_walls = has_side_walls(&o, p.periodic, p.planar);
    let mean_particle_volume = p2.particle_volume_sum / p2.particles_total.max(1) as f64;
    let layers = grid.n[o.vertical];
    let band_height = grid.h[o.vertical] * layers as f64 / HEIGHT_BANDS as f64;
    p2.bands
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let mean = b.eps[0] / b.eps[2];
            let std_over_mean = (b.eps[1] / b.eps[2] - mean * mean).max(0.0).sqrt() / mean;
            let poisson = (mean_particle_volume / (mean * super::grid::cell_volume(grid))).sqrt();
            HeightBand {
                height_lo: i as f64 * band_height,
                height_hi: (i + 1) as f64 * band_height,
                mean_solids_fraction: mean,
                std_over_mean,
                poisson_std_over_mean: poisson,
                excess_std_over_mean: (std_over_mean.powi(2) - poisson * poisson).max(0.0).sqrt(),
                cluster_particle_fraction: b.clustered as f64 / b.particles.max(1) as f64,
                wall_to_core_ratio: (side_walls && b.wall[1] > 0.0 && b.core[1] > 0.0)
                    .then(|| (b.wall[0] / b.wall[1]) / (b.core[0] / b.core[1])),
            }
        })
        .collect()
}

/// `heterogeneity_by_height.csv`.
fn heterogeneity_by_height_table(bands: &[HeightBand]) -> CsvTable {
    let mut t = header(&[
        "height_lo_m",
        "height_hi_m",
        "mean_solids_fraction",
        "std_over_mean",
        "poisson_std_over_mean",
        "excess_std_over_mean",
        "cluster_particle_fraction",
        "wall_to_core_ratio",
    ]);
    for b in bands {
        t.row(&[
            b.height_lo,
            b.height_hi,
            b.mean_solids_fraction,
            b.std_over_mean,
            b.poisson_std_over_mean,
            b.excess_std_over_mean,
            b.cluster_particle_fraction,
            b.wall_to_core_ratio.unwrap_or(f64::NAN),
        ]);
    }
    t
}

/// Writes `ktgf_samples.csv` and `ktgf_binned.csv` and returns the KTGF
/// test; otherwise (or when no sample qualified) a note.
fn ktgf_summary(
    p: &mut Pass1,
    out: &mut OutputFiles,
    grid: &TallyGrid,
) -> anyhow::Result<Option<KtgfSummary>> {
    let (d, opts) = (p.d, p.opts);
    Ok(match p.ktgf.take() {
        Some(Ok(k)) => {
            out.write("ktgf_samples.csv", &k.samples)?;
            out.write("ktgf_binned.csv", &k.binned())?;
            if k.all.samples == 0 {
                p.notes.push(format!(
                    "KTGF test: no tally cell had {} particles and {} collisions in an interval (see --min-per-cell, --min-collisions)",
                    opts.min_per_cell, opts.min_collisions
                ));
            } else if k.test.samples == 0 {
                p.notes.push(format!(
                    "KTGF test: all {} samples had collisions made elastic by the TC model or the collapse guard; \
                     only the `all` ratios are defined",
                    k.all.samples
                ));
            }
            let tally = p.tally.as_ref().map_or_else(
                || GridInfo::new(grid, f64::NAN, "none"),
                |g| {
                    GridInfo::new(
                        g,
                        (0..d).map(|a| g.h[a]).fold(0.0, f64::max),
                        "tally grid of the run",
                    )
                },
            );
            let e_n = k.settings.e_n;
            Some(KtgfSummary {
                material: k.material,
                e_n,
                beta_0: k.settings.beta_0,
                mu: k.settings.mu,
                theory: KineticTheory::for_dimensions(d),
                diameter: k.settings.diameter,
                tally_grid: tally,
                test: k.test.ratios(e_n),
                all: k.all.ratios(e_n),
            })
        }
        Some(Err(note)) => {
            p.notes.push(note);
            None
        }
        None => {
            p.notes
                .push("KTGF test skipped: no particles in the snapshots".to_string());
            None
        }
    })
}

/// Writes `segregation.csv` (bidisperse runs) and returns the segregation
/// index summary; otherwise a note.
fn segregation_summary(
    p: &mut Pass1,
    out: &mut OutputFiles,
) -> anyhow::Result<Option<SegregationSummary>> {
    Ok(match p.species.take() {
        Some(Ok(species)) if !p.segregation_values.is_empty() => {
            out.write("segregation.csv", &p.segregation)?;
            let v = &p.segregation_values;
            Some(SegregationSummary {
                species,
                snapshots: v.len(),
                first: v[0],
                last: v[v.len() - 1],
                mean: v.iter().sum::<f64>() / v.len() as f64,
            })
        }
        Some(Err(why)) => {
            p.notes.push(format!("segregation index skipped: {why}"));
            None
        }
        _ => {
            p.notes
                .push("segregation index skipped: a species is missing".to_string());
            None
        }
    })
}

/// Draws the figures from the CSV files written, and the last snapshot; a
/// figure that fails becomes a note.
fn draw_figures(
    run_dir: &Path,
    paths: &[PathBuf],
    vertical: usize,
    out: &mut OutputFiles,
    notes: &mut Vec<String>,
) -> anyhow::Result<()> {
    let title = run_dir
        .file_name()
        .map_or("run".to_string(), |n| n.to_string_lossy().into_owned());
    match super::figures::draw_all(&out.dir, &title) {
        Ok(names) => out.names.extend(names),
        Err(e) => notes.push(format!("figures not drawn: {e:#}")),
    }
    if let Some(last) = paths.last() {
        let snap = Snapshot::read(last)?;
        let png = out.dir.join("snapshot.png");
        match super::figures::snapshot_comparison(&png, &[(title.clone(), snap)], vertical) {
            Ok(()) => out.names.push("snapshot.png".to_string()),
            Err(e) => notes.push(format!("snapshot figure not drawn: {e:#}")),
        }
    }
    Ok(())
}

/// Velocity statistics on every grid, with a note for each grid where no
/// cell ever held `min_per_cell` particles.
fn cell_size_results(p: &mut Pass1) -> Vec<CellSizeResult> {
    let (d, d_rot) = (p.d, p.d_rot);
    let results: Vec<CellSizeResult> = p.grids.iter().map(|g| g.result(d, d_rot)).collect();
    for r in &results {
        if r.cell_samples_used == 0 {
            p.notes.push(format!(
                "cell size {} m: no cell ever held --min-per-cell = {} particles; its statistics are undefined (NaN)",
                r.grid.cell_size, p.opts.min_per_cell
            ));
        }
    }
    results
}

/// Analyses the snapshots of `run_dir` and writes the results into
/// `run_dir/analysis/`: two passes over the snapshots, then one table per
/// output file, the summaries, the figures and `analysis.json`.
pub fn analyse_run(run_dir: &Path, opts: &AnalyseOptions) -> anyhow::Result<AnalysisSummary> {
    check_options(opts)?;
    let paths = snapshot_paths(run_dir)?;
    let mut p = first_pass(run_dir, &paths, opts)?;
    let (d, d_rot) = (p.d, p.d_rot);
    let results = cell_size_results(&mut p);
    let stats = results[0].stats.clone();
    let grid = p.primary().clone();
    let (mean_eps_field, mean_flux_field) = p.fields.mean();
    let cluster_threshold = (CLUSTER_FACTOR * primary_solids_fraction(&p)[0]).max(CLUSTER_MIN);
    let p2 = second_pass(
        &p,
        &paths,
        &grid,
        &stats,
        &mean_eps_field,
        cluster_threshold,
    )?;

    let out_dir = run_dir.join("analysis");
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let mut out = OutputFiles {
        dir: out_dir.clone(),
        names: Vec::new(),
    };
    let axes: Vec<&str> = AXIS_NAMES[..d].to_vec();
    out.write(
        "velocity_distribution.csv",
        &velocity_distribution_table(&p2.hist, &axes),
    )?;
    out.write(
        "speed_distribution.csv",
        &speed_distribution_table(&p2.hist),
    )?;
    out.write(
        "cell_size_dependence.csv",
        &cell_size_table(&results, &axes),
    )?;
    out.write("temperature_timeseries.csv", &p.series)?;
    let fields = cell_fields_table(&p, &grid, &mean_eps_field, &mean_flux_field, &axes);
    out.write("cell_fields.csv", &fields)?;
    let width = width_profiles_table(&p, &grid, &mean_eps_field, &mean_flux_field);
    out.write("profiles_width.csv", &width)?;
    let height = height_profile_table(&p.orient, &grid, &mean_eps_field, &mean_flux_field);
    out.write("profile_height.csv", &height)?;
    let pressure_drop = pressure_drop_summary(&mut p, &mut out)?;
    let bed = (!p.bed.is_empty()).then(|| summarise(&p.bed, p.solids_volume, &p.bed_frame()));
    if bed.is_some() {
        out.write("bed_timeseries.csv", &bed_timeseries_table(&p.bed))?;
    }
    out.write("energy_budget.csv", &p.energy)?;
    let mean_energy = p.energy_sum.scaled(1.0 / p.snapshots.max(1) as f64);
    let energy = EnergySummary {
        mean: mean_energy,
        percent_of_total: mean_energy.scaled(100.0 / mean_energy.total),
    };
    let heterogeneity = heterogeneity_summary(&mut p, &p2, &grid, cluster_threshold);
    let heterogeneity_by_height = heterogeneity_by_height(&p, &p2, &grid);
    out.write(
        "heterogeneity_by_height.csv",
        &heterogeneity_by_height_table(&heterogeneity_by_height),
    )?;
    let ktgf = ktgf_summary(&mut p, &mut out, &grid)?;
    let segregation = segregation_summary(&mut p, &mut out)?;
    draw_figures(run_dir, &paths, p.orient.vertical, &mut out, &mut p.notes)?;

    out.names.push("analysis.json".to_string());
    let o = p.orient;
    let total = p2.hist.total.max(1) as f64;
    let summary = AnalysisSummary {
        run_dir: run_dir.display().to_string(),
        output_dir: out_dir.display().to_string(),
        snapshots_total: paths.len(),
        snapshots_used: p.snapshots,
        t_start: opts.t_start,
        t_first: p.t_first,
        t_last: p.t_last,
        planar: p.planar,
        dimensions: d,
        rotational_dimensions: d_rot,
        vertical_axis: AXIS_NAMES[o.vertical],
        up: if o.up > 0.0 { "+" } else { "-" },
        width_axis: AXIS_NAMES[o.width],
        min_per_cell: opts.min_per_cell,
        primary_grid: results[0].grid.clone(),
        velocity: stats,
        velocity_unaffected: p.unaffected.as_ref().map(|u| UnaffectedVelocity {
            cell_samples_excluded: u.cell_samples_excluded,
            particle_samples_excluded: u.particle_samples_excluded,
            stats: u.moments.stats(d, d_rot),
        }),
        temperature_global: p.global_t[0] / (d as f64 * p.global_t[1]),
        histogram_outside_fraction: p2.hist.outside.map(|n| n as f64 / total),
        cell_size_dependence: results,
        heights: p.heights.clone(),
        heterogeneity,
        heterogeneity_by_height,
        pressure_drop,
        bed,
        energy,
        ktgf,
        segregation,
        notes: p.notes.clone(),
        files: out.names,
        figures_planned: FIGURES.to_vec(),
    };
    let json = serde_json::to_string_pretty(&summary).context("encoding analysis.json")?;
    write_atomic(&out_dir.join("analysis.json"), json.as_bytes())?;
    Ok(summary)
}
