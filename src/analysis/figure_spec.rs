//! The figures of an analysis: which CSV file and columns each PNG shows.
//! Read by the driver (listed in `analysis.json`) and drawn by
//! [`super::figures`]; a module of its own so that neither depends on the
//! other for it.

use serde::Serialize;

/// A figure the plotting code (src/plot.rs) is meant to draw from a CSV
/// written here.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FigureSpec {
    /// PNG file name in `RUN_DIR/analysis/`.
    pub name: &'static str,
    /// CSV file in `RUN_DIR/analysis/`.
    pub data: &'static str,
    pub x: &'static str,
    /// Columns to draw against `x` (missing columns, e.g. z in planar
    /// mode, are left out).
    pub y: &'static [&'static str],
    pub what: &'static str,
}

/// The figures planned for the analysis (drawn by src/plot.rs).
pub const FIGURES: &[FigureSpec] = &[
    FigureSpec {
        name: "velocity_distribution.png",
        data: "velocity_distribution.csv",
        x: "c_over_sigma",
        y: &[
            "f_x", "f_y", "f_z", "f_x_cell", "f_y_cell", "f_z_cell", "gaussian",
        ],
        what: "pooled f(C_i/σ_i) and per-cell f(C_i/√T_c) vs the Gaussian",
    },
    FigureSpec {
        name: "speed_distribution.png",
        data: "speed_distribution.csv",
        x: "c_over_sqrt_T",
        y: &["f", "f_cell", "maxwellian"],
        what: "pooled f(|C|/√T) and per-cell f(|C|/√T_c) vs Maxwell",
    },
    FigureSpec {
        name: "temperature_timeseries.png",
        data: "temperature_timeseries.csv",
        x: "time_s",
        y: &["T_m2_s2", "T_rot_m2_s2", "T_global_m2_s2"],
        what: "granular temperatures against time",
    },
    FigureSpec {
        name: "cell_size_dependence.png",
        data: "cell_size_dependence.csv",
        x: "cell_size_m",
        y: &["T_m2_s2", "sonine_a2"],
        what: "T and a2 against the analysis cell size",
    },
    FigureSpec {
        name: "profiles_width.png",
        data: "profiles_width.csv",
        x: "width_m",
        y: &["solids_fraction", "solids_flux_kg_m2_s"],
        what: "lateral profiles, one line per height_m",
    },
    FigureSpec {
        name: "profile_height.png",
        data: "profile_height.csv",
        x: "height_m",
        y: &["solids_fraction"],
        what: "solids hold-up along the height",
    },
    FigureSpec {
        name: "pressure_drop.png",
        data: "pressure_drop.csv",
        x: "time_s",
        y: &["pressure_drop_Pa", "bed_weight_per_area_Pa"],
        what: "gas pressure drop against the bed weight (gas runs)",
    },
    FigureSpec {
        name: "energy_budget.png",
        data: "energy_budget.csv",
        x: "time_s",
        y: &["potential_J", "convective_J", "granular_J", "rotational_J"],
        what: "energy budget against time",
    },
    FigureSpec {
        name: "ktgf_pressure.png",
        data: "ktgf_binned.csv",
        x: "solids_fraction",
        y: &["pc_measured_Pa", "pc_ktgf_Pa", "pc_ktgf_ma_Pa"],
        what: "collisional pressure vs KTGF (cells without TC/guard)",
    },
    FigureSpec {
        name: "ktgf_dissipation.png",
        data: "ktgf_binned.csv",
        x: "solids_fraction",
        y: &[
            "gamma_n_measured_W_m3",
            "gamma_n_ktgf_W_m3",
            "gamma_n_ktgf_ma_W_m3",
        ],
        what: "normal dissipation vs KTGF (cells without TC/guard)",
    },
    FigureSpec {
        name: "segregation.png",
        data: "segregation.csv",
        x: "time_s",
        y: &["segregation_index"],
        what: "degree of segregation (bidisperse beds)",
    },
];
