//! The time series: `timeseries.csv` (particles, every
//! `output.sample_interval`) and, in gas runs, `gas_timeseries.csv` (rows
//! from [`GasRun::sample_row`]). Both are written as the run goes, one
//! `write` per row, so a killed run keeps every row computed before it
//! died (whole lines only).

use std::path::Path;

use glam::DVec3;

use super::{Recorder, RunEnd, StepEnd, due, next_multiple};
use crate::engine::{Counters, Engine};
use crate::gas::flow::{GAS_SERIES_HEADER, GasRun};
use crate::io::output::CsvStream;
use crate::queue::EventQueue;

const TIME_SERIES_HEADER: [&str; 17] = [
    "time_s",
    "particles",
    "pair_collisions",
    "wall_collisions",
    "ke_translational_J",
    "ke_rotational_J",
    "momentum_x_kg_m_s",
    "momentum_y_kg_m_s",
    "momentum_z_kg_m_s",
    "granular_temperature_m2_s2",
    "pressure_kinetic_Pa",
    "pressure_collisional_Pa",
    "dissipated_J",
    "collapse_reports",
    "centre_of_mass_x_m",
    "centre_of_mass_y_m",
    "centre_of_mass_z_m",
];

/// The time series of a run in progress.
pub struct TimeSeries {
    interval: f64,
    next: f64,
    series: CsvStream,
    gas_series: Option<CsvStream>,
    /// Counters and time at the previous row.
    last: Counters,
    last_time: f64,
    /// Collapse reports already counted in a row.
    collapse_seen: usize,
    /// Soft or hybrid model: a last column `soft_fraction`.
    soft: bool,
}

impl TimeSeries {
    /// Creates `timeseries.csv` (and `gas_timeseries.csv` with `gas`) in
    /// `out_dir`, with their header lines; a row every `interval` (s).
    /// `soft` (soft or hybrid model): a last column `soft_fraction`.
    pub fn create(out_dir: &Path, interval: f64, gas: bool, soft: bool) -> anyhow::Result<Self> {
        let header = if soft {
            [&TIME_SERIES_HEADER[..], &["soft_fraction"]].concat()
        } else {
            TIME_SERIES_HEADER.to_vec()
        };
        Ok(TimeSeries {
            interval,
            next: interval,
            series: CsvStream::create(&out_dir.join("timeseries.csv"), &header)?,
            gas_series: if gas {
                Some(CsvStream::create(
                    &out_dir.join("gas_timeseries.csv"),
                    &GAS_SERIES_HEADER,
                )?)
            } else {
                None
            },
            last: Counters::default(),
            last_time: 0.0,
            collapse_seen: 0,
            soft,
        })
    }
}

impl<Q: EventQueue> Recorder<Q> for TimeSeries {
    fn start(&mut self, engine: &mut Engine<Q>, gas: Option<&mut GasRun>) -> anyhow::Result<()> {
        self.last = engine.counters;
        let t = engine.time();
        if t > 0.0 {
            // A restarted run (`--restart`): no row at the restart time
            // (the gas row would cut the gas interval statistics short);
            // the first row is the next sample of the uninterrupted run.
            // Its interval columns cover the time since the restart.
            self.last_time = t;
            self.next = next_multiple(t, self.interval);
            self.collapse_seen = engine.collapse_reports.len();
            return Ok(());
        }
        if let (Some(series), Some(g)) = (self.gas_series.as_mut(), gas) {
            series.row(&g.sample_row())?;
        }
        sample_interval_row(engine, &mut self.series, &self.last, 0.0, 0, self.soft)
    }

    fn needs_sync(&self, end: &StepEnd) -> bool {
        due(end, self.next)
    }

    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        if !due(end, self.next) {
            return Ok(());
        }
        let t = end.time;
        let new_reports = engine.collapse_reports.len() - self.collapse_seen;
        self.collapse_seen = engine.collapse_reports.len();
        sample_interval_row(
            engine,
            &mut self.series,
            &self.last,
            t - self.last_time,
            new_reports,
            self.soft,
        )?;
        if let (Some(series), Some(g)) = (self.gas_series.as_mut(), gas) {
            series.row(&g.sample_row())?;
        }
        self.last = engine.counters;
        self.last_time = t;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }

    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        self.series.sync()?;
        if let Some(series) = self.gas_series.as_mut() {
            series.sync()?;
        }
        Ok(())
    }
}

/// One time-series row. Collision counts, dissipation and the collisional
/// pressure refer to the interval since the previous row. Pressures:
/// kinetic `Σ m C² / (d V)` with `C` the velocity relative to the mean,
/// collisional `Σ r_ab · J / (d V Δt)` (the collision virial), with `d`
/// the number of moving dimensions and `V` the domain volume. With `soft`,
/// a last column: the fraction of the particles moved by soft steps.
fn sample_interval_row<Q: EventQueue>(
    engine: &Engine<Q>,
    series: &mut CsvStream,
    last: &Counters,
    interval: f64,
    reports: usize,
    soft: bool,
) -> anyhow::Result<()> {
    let c = &engine.counters;
    // Two passes: the sums, then the fluctuations about the mean velocity.
    let totals = engine.motion_totals();
    let ((ke_t, ke_r), momentum, mass) = (totals.kinetic, totals.momentum, totals.mass);
    let d = engine.domain().dimensions() as f64;
    let volume = engine.domain().volume();
    let mean = if mass > 0.0 {
        momentum / mass
    } else {
        DVec3::ZERO
    };
    // From −0.0, as `Iterator::sum` starts: an empty system still writes
    // -0.0 here, as before the passes were fused.
    let (fluct, spread) = engine.particles().fold((-0.0, -0.0), |(f, s), p| {
        let c2 = (p.vel - mean).length_squared();
        (f + p.mass * c2, s + c2)
    });
    let n = engine.len().max(1) as f64;
    let centre = if mass > 0.0 {
        totals.mass_moment / mass
    } else {
        DVec3::ZERO
    };
    let temperature = spread / (d * n);
    let p_coll = if interval > 0.0 {
        (c.virial - last.virial) / (d * volume * interval)
    } else {
        0.0
    };
    let row = [
        engine.time(),
        engine.len() as f64,
        (c.pair_collisions - last.pair_collisions) as f64,
        (c.wall_collisions - last.wall_collisions) as f64,
        ke_t,
        ke_r,
        momentum.x,
        momentum.y,
        momentum.z,
        temperature,
        fluct / (d * volume),
        p_coll,
        (c.dissipated_pair + c.dissipated_wall + c.dissipated_soft)
            - (last.dissipated_pair + last.dissipated_wall + last.dissipated_soft),
        reports as f64,
        centre.x,
        centre.y,
        centre.z,
    ];
    if soft {
        series.row(&[&row[..], &[engine.soft_fraction_now()]].concat())
    } else {
        series.row(&row)
    }
}
