//! The figures of an analysis: which CSV file and columns each PNG shows,
//! with its title, axis labels (units in brackets) and legend entries.
//! Read by the driver (listed in `analysis.json`) and drawn by
//! [`super::figures`]; a module of its own so that neither depends on the
//! other for it.

use serde::Serialize;

/// A figure drawn from a CSV file written by the analysis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FigureSpec {
    /// PNG file name in `RUN_DIR/analysis/`.
    pub name: &'static str,
    /// CSV file in `RUN_DIR/analysis/`.
    pub data: &'static str,
    /// Column on the x axis.
    pub x: &'static str,
    /// Columns drawn against `x`, each with its legend entry (missing
    /// columns, e.g. z in planar mode, are left out).
    pub y: &'static [(&'static str, &'static str)],
    /// Title, after the run's name.
    pub title: &'static str,
    pub x_label: &'static str,
    pub y_label: &'static str,
    /// Logarithmic x axis (cell sizes span decades).
    pub log_x: bool,
}

/// Granular temperature axis label.
const TEMPERATURE: &str = "granular temperature (m²/s²)";
/// The lateral axis of a planar bed or riser, in every figure.
pub const LATERAL_POSITION: &str = "lateral position (m)";
const SOLIDS_FRACTION: &str = "solids fraction (−)";

/// The figures of an analysis.
pub const FIGURES: &[FigureSpec] = &[
    FigureSpec {
        name: "velocity_distribution.png",
        data: "velocity_distribution.csv",
        x: "c_over_sigma",
        y: &[
            ("f_x", "f(C_x/σ_x)"),
            ("f_y", "f(C_y/σ_y)"),
            ("f_z", "f(C_z/σ_z)"),
            ("f_x_cell", "f(C_x/√T_c), own cell's T"),
            ("f_y_cell", "f(C_y/√T_c), own cell's T"),
            ("f_z_cell", "f(C_z/√T_c), own cell's T"),
            ("gaussian", "Gaussian"),
        ],
        title: "velocity distribution per component",
        x_label: "C_i / σ_i or C_i / √T_c (−)",
        y_label: "probability density (−)",
        log_x: false,
    },
    FigureSpec {
        name: "speed_distribution.png",
        data: "speed_distribution.csv",
        x: "c_over_sqrt_T",
        y: &[
            ("f", "f(|C|/√T)"),
            ("f_cell", "f(|C|/√T_c), own cell's T"),
            ("maxwellian", "Maxwell"),
        ],
        title: "speed distribution",
        x_label: "|C| / √T or |C| / √T_c (−)",
        y_label: "probability density (−)",
        log_x: false,
    },
    FigureSpec {
        name: "temperature_timeseries.png",
        data: "temperature_timeseries.csv",
        x: "time_s",
        y: &[
            ("T_m2_s2", "translational, about each cell's mean velocity"),
            ("T_rot_m2_s2", "rotational"),
            (
                "T_global_m2_s2",
                "translational, about the mean of all particles",
            ),
        ],
        title: "granular temperature",
        x_label: "time (s)",
        y_label: TEMPERATURE,
        log_x: false,
    },
    FigureSpec {
        name: "cell_size_temperature.png",
        data: "cell_size_dependence.csv",
        x: "cell_size_m",
        y: &[
            ("T_x_m2_s2", "T_x"),
            ("T_y_m2_s2", "T_y"),
            ("T_z_m2_s2", "T_z"),
            ("T_m2_s2", "T, mean of the components"),
        ],
        title: "granular temperature against the analysis cell size",
        x_label: "analysis cell size (m)",
        y_label: TEMPERATURE,
        log_x: true,
    },
    FigureSpec {
        name: "cell_size_sonine_a2.png",
        data: "cell_size_dependence.csv",
        x: "cell_size_m",
        y: &[
            ("sonine_a2", "pooled (one σ per component)"),
            ("sonine_a2_cell", "each cell normalised by its own T"),
        ],
        title: "Sonine coefficient a₂ against the analysis cell size",
        x_label: "analysis cell size (m)",
        y_label: "a₂ (−)",
        log_x: true,
    },
    FigureSpec {
        name: "profiles_width.png",
        data: "profiles_width.csv",
        x: "width_m",
        // One line per height (column height_m), drawn by `figures`.
        y: &[("solids_fraction", "")],
        title: "solids fraction across the width",
        x_label: LATERAL_POSITION,
        y_label: SOLIDS_FRACTION,
        log_x: false,
    },
    FigureSpec {
        name: "profile_height.png",
        data: "profile_height.csv",
        x: "height_m",
        y: &[("solids_fraction", "time average")],
        title: "solids hold-up along the height",
        x_label: "height (m)",
        y_label: SOLIDS_FRACTION,
        log_x: false,
    },
    FigureSpec {
        name: "pressure_drop.png",
        data: "pressure_drop.csv",
        x: "time_s",
        y: &[
            ("pressure_drop_Pa", "gas pressure drop"),
            ("bed_weight_per_area_Pa", "buoyant bed weight per area"),
        ],
        title: "gas pressure drop against the bed weight",
        x_label: "time (s)",
        y_label: "pressure (Pa)",
        log_x: false,
    },
    FigureSpec {
        name: "energy_budget.png",
        data: "energy_budget.csv",
        x: "time_s",
        y: &[
            ("potential_J", "potential"),
            ("convective_J", "kinetic, of the cell mean velocities"),
            ("granular_J", "kinetic, of the fluctuations"),
            ("rotational_J", "rotational"),
        ],
        title: "energy budget",
        x_label: "time (s)",
        y_label: "energy (J)",
        log_x: false,
    },
    FigureSpec {
        name: "ktgf_pressure.png",
        data: "ktgf_binned.csv",
        x: "solids_fraction",
        // The first column is the measurement, the others predictions.
        y: &[
            ("pc_measured_Pa", "measured"),
            (
                "pc_ktgf_Pa",
                "KTGF, Carnahan–Starling (3D) or Henderson (2D) g0",
            ),
            ("pc_ktgf_ma_Pa", "KTGF, Ma–Ahmadi g0 (Table 5)"),
        ],
        title: "collisional pressure against kinetic theory (cells without TC or guard)",
        x_label: "measured collisional pressure (Pa)",
        y_label: "kinetic theory prediction (Pa)",
        log_x: true,
    },
    FigureSpec {
        name: "ktgf_dissipation.png",
        data: "ktgf_binned.csv",
        x: "solids_fraction",
        y: &[
            ("gamma_n_measured_W_m3", "measured"),
            (
                "gamma_n_ktgf_W_m3",
                "KTGF, Carnahan–Starling (3D) or Henderson (2D) g0",
            ),
            ("gamma_n_ktgf_ma_W_m3", "KTGF, Ma–Ahmadi g0 (Table 5)"),
        ],
        title: "normal dissipation rate against kinetic theory (cells without TC or guard)",
        x_label: "measured normal dissipation rate (W/m³)",
        y_label: "kinetic theory prediction (W/m³)",
        log_x: true,
    },
    FigureSpec {
        name: "segregation.png",
        data: "segregation.csv",
        x: "time_s",
        y: &[("segregation_index", "segregation index")],
        title: "degree of segregation",
        x_label: "time (s)",
        y_label: "segregation index (−)",
        log_x: false,
    },
];

/// The figure named `name`.
pub fn figure(name: &str) -> Option<&'static FigureSpec> {
    FIGURES.iter().find(|f| f.name == name)
}
