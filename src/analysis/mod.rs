//! `edpm analyse`: statistics of a run's particle snapshots for
//! comparison with kinetic theory and experiments. SI units throughout.
//!
//! The analyses are pure functions on plain data (slices of
//! [`SnapshotParticle`](crate::io::snapshot::SnapshotParticle), grids, tallies)
//! so that they can be tested on synthetic data; [`analyse_run`] drives them
//! over `RUN_DIR/snapshots/*.bin` and writes `RUN_DIR/analysis/`.
//!
//! # Sampling procedure
//!
//! - Snapshots at `t ≥ --t-start` are used, each as one sample of the
//!   state; statistics are pooled over all of them (every particle of every
//!   used snapshot is one sample). Consecutive snapshots are correlated, so
//!   the quoted standard errors (independent samples) are lower bounds.
//! - Analysis cells tile the box: `n = max(1, round(L/--cell-size))` cells
//!   per axis ([`grid::grid_for_cell_size`]); in planar mode one cell spans
//!   the bed depth. The first `--cell-size` (or the default: the run's tally
//!   grid, i.e. the gas grid in gas runs, when it has more than one cell,
//!   else 5 Sauter diameters) is the primary grid of distributions, fields,
//!   profiles and energies; every size given is also analysed for the
//!   cell-size dependence, and a one-cell grid (global mean) is added last.
//! - A particle belongs to the cell of its centre. The local mean velocity
//!   of a cell is mass-weighted; fluctuation velocities are relative to it
//!   ([`velocity`]). Cells with fewer than `--min-per-cell` particles are
//!   skipped in the velocity statistics (counted in the outputs).
//! - Temperatures are corrected for the degree of freedom each cell's own
//!   mean removes: every `m C²` of a cell of `N` particles counts
//!   `N/(N − 1)` times ([`velocity`]).
//! - Local fields are time averages over the used snapshots: solids
//!   fraction and flux as plain means per snapshot, temperatures pooled
//!   (`Σ_t Σ m C² / (d Σ_t Σ m)` over the snapshots in which the cell met
//!   `--min-per-cell`).
//! - Collisions the TC model or the collapse guard made elastic: the
//!   snapshots' collision tallies count them per cell. The KTGF test flags
//!   the samples (cell × interval) with any and leaves them out of its
//!   binned table and `test` ratios (the `all` ratios keep them); the
//!   velocity statistics are repeated without the primary cells holding a
//!   particle in such a tally cell (`velocity_unaffected`).
//!
//! # Definitions (with the seed equations)
//!
//! - Granular temperature (seed 003 Eq. 17, `θ = ⅓ ⟨C·C⟩`):
//!   `T_i = Σ m C_i² / Σ m`, `T = (1/d) Σ T_i` with `d` the number of moving
//!   dimensions (3, as in Eq. 17; 2 in planar mode, where z is frozen).
//!   Rotational: `T_rot = Σ I ω'² / (d_rot Σ m)`, `d_rot = 3` (1 in planar
//!   mode), from the rotational granular energy `(3/2) ε_s ρ_s Θ_r` of seed
//!   002 Eq. 7; `ω'` is relative to the cell's inertia-weighted mean.
//! - Distributions (seed 003 Fig. 4, seed 001 Sec. 6.2): `f(C_i/σ_i)` against
//!   the unit Gaussian, `f(|C|/√T)` against the Maxwellian speed density
//!   (2D form in planar mode), kurtosis `⟨C_i⁴⟩/⟨C_i²⟩²` (3 for a Gaussian),
//!   Sonine coefficient `a2 = (d/(d+2)) ⟨C⁴⟩/⟨C²⟩² − 1`, anisotropy `T_a/T_b`.
//!   Each twice: pooled over cells (one global σ, so cells of different
//!   temperatures make a2 and the kurtosis positive) and with each
//!   fluctuation normalised by its own cell's temperature (`_cell`
//!   columns, `*_cell_normalised` fields; [`velocity`]).
//! - Kinetic theory against the collision tally: hard spheres in 3D, hard
//!   disks in planar runs; collisional pressure, normal dissipation
//!   (normal-only theory), tangential dissipation (rough-sphere average):
//!   [`ktgf`].
//! - Energy budget (seed 002 Table 3): [`energy`].
//! - Degree of segregation (seed 001 Eq. 49): [`segregation`].
//! - Profiles, hold-up, pressure drop: [`profiles`]; bed height,
//!   expansion and voids (bubbles): [`bed`]; heterogeneity and the output
//!   files: [`driver`].
//!
//! # Output files (`RUN_DIR/analysis/`)
//!
//! | file | columns |
//! |---|---|
//! | `analysis.json` | [`AnalysisSummary`] |
//! | `velocity_distribution.csv` | `c_over_sigma, f_x, f_y[, f_z], f_x_cell, f_y_cell[, f_z_cell], gaussian` (`_cell`: `C_i/√T_c` on the same axis) |
//! | `speed_distribution.csv` | `c_over_sqrt_T, f, f_cell, maxwellian` |
//! | `cell_size_dependence.csv` | per grid: `cell_size_m, h_x_m, h_y_m, h_z_m, cells, cell_samples_used, cell_samples_skipped, particles_per_used_cell, samples, T_x_m2_s2, T_y_m2_s2[, T_z_m2_s2], T_m2_s2, T_rot_m2_s2, sonine_a2, sonine_a2_se, sonine_a2_cell, sonine_a2_cell_se, kurtosis_x, kurtosis_y[, kurtosis_z], kurtosis_x_cell, kurtosis_y_cell[, kurtosis_z_cell], solids_fraction_std_over_mean` |
//! | `temperature_timeseries.csv` | per snapshot: `time_s, particles, particles_used, cells_used, cells_skipped, T_x_m2_s2, T_y_m2_s2[, T_z_m2_s2], T_m2_s2, T_rot_m2_s2, T_global_m2_s2, sonine_a2, sonine_a2_cell, mean_solids_fraction` |
//! | `cell_fields.csv` | per primary cell: `cell, i, j, k, x_m, y_m, z_m, snapshots_used, mean_particles, solids_fraction, solids_flux_kg_m2_s, velocity_{x,y,z}_m_s, T_x_m2_s2, T_y_m2_s2[, T_z_m2_s2], T_m2_s2, T_rot_m2_s2` |
//! | `profiles_width.csv` | `height_m, layer_height_m, width_m, solids_fraction, solids_flux_kg_m2_s` |
//! | `profile_height.csv` | `height_m, solids_fraction, solids_flux_kg_m2_s` |
//! | `pressure_drop.csv` (gas runs) | `time_s, pressure_bottom_Pa, pressure_top_Pa, pressure_drop_Pa, bed_weight_per_area_Pa` |
//! | `bed_timeseries.csv` (runs with gravity) | per snapshot on the primary grid: `time_s, centroid_height_m, bed_height_m, height_95_m, voids, void_diameter_mean_m, void_fraction` ([`bed`]) |
//! | `energy_budget.csv` | `time_s, potential_J, kinetic_J, convective_J, granular_J, rotational_J, rotational_granular_J, total_J` |
//! | `ktgf_samples.csv` | per tally cell and interval: `time_s, cell, solids_fraction, packing_fraction, T_m2_s2, T_rot_m2_s2, density_kg_m3, particles, collisions, altered_collisions, g0, g0_ma, pk_Pa, pc_measured_Pa, pc_ktgf_Pa, pc_ktgf_ma_Pa, gamma_n_measured_W_m3, gamma_n_ktgf_W_m3, gamma_n_ktgf_ma_W_m3, gamma_t_measured_W_m3, gamma_t_theory_W_m3, undissipated_W_m3, gamma_n_ratio, pc_ratio, interval_s` (`g0`: Carnahan–Starling, or Henderson in planar runs; `_ma`: Ma–Ahmadi, 3D only, empty in planar runs) |
//! | `ktgf_binned.csv` | per packing-fraction bin of 0.02, samples without TC/guard alterations only: means and ratios of sums |
//! | `segregation.csv` (bidisperse) | `time_s, n_small, n_large, h_small_m, h_large_m, x_large, S, S_max, segregation_index` |
//!
//! Values that are undefined (an empty cell's temperature) are written as
//! empty CSV cells and `null` in JSON.

pub mod bed;
mod cli;
mod compare;
pub mod driver;
pub mod energy;
pub mod figure_spec;
mod figures;
pub mod fluidization;
pub mod grid;
pub mod ktgf;
pub mod profiles;
pub mod segregation;
pub mod velocity;

pub use cli::{analyse_cli, figures_cli};
pub use driver::{AnalyseOptions, AnalysisSummary, HEIGHT_BANDS, analyse_run};
pub use figure_spec::FIGURES;
