//! VTK snapshots for ParaView: particles (`vtk/particles_NNNNNN.vtp`) and
//! gas fields (`vtk/gas_NNNNNN.vti`) with `.pvd` series (src/io/vtk.rs).

use std::path::{Path, PathBuf};

use super::{Recorder, RunEnd, StepEnd, due, next_multiple};
use crate::domain::grid::GridGeometry;
use crate::engine::Engine;
use crate::gas::flow::GasRun;
use crate::io::output::BackgroundWriter;
use crate::io::vtk::{PvdSeries, VtkParticle};
use crate::queue::EventQueue;

/// VTK snapshots of particles (and gas) with ParaView `.pvd` series,
/// encoded and written on a thread of their own: a run waits for the copy
/// of the particles and the gas fields, and for the disk only when
/// [`BackgroundWriter::PENDING`] frames already wait.
pub struct VtkSeries {
    dir: PathBuf,
    interval: f64,
    next: f64,
    count: usize,
    particles: PvdSeries,
    gas: Option<PvdSeries>,
    writer: BackgroundWriter,
}

impl VtkSeries {
    pub fn new(out_dir: &Path, interval: f64, gas: bool) -> anyhow::Result<Self> {
        let dir = out_dir.join("vtk");
        Ok(VtkSeries {
            particles: PvdSeries::new(out_dir.join("particles.pvd")),
            gas: gas.then(|| PvdSeries::new(out_dir.join("gas.pvd"))),
            dir,
            interval,
            next: 0.0,
            count: 0,
            writer: BackgroundWriter::new("vtk writer")?,
        })
    }

    fn write<Q: EventQueue>(
        &mut self,
        engine: &Engine<Q>,
        gas: Option<&GasRun>,
    ) -> anyhow::Result<()> {
        let t = engine.time();
        let name = format!("particles_{:06}.vtp", self.count);
        let particles: Vec<VtkParticle> = engine
            .particles()
            .map(|p| VtkParticle {
                id: p.id,
                pos: p.pos,
                vel: p.vel,
                omega: p.omega,
                radius: p.radius,
                material: p.material,
            })
            .collect();
        self.particles.push(t, format!("vtk/{name}"));
        let particle_series = self.particles.clone();
        let gas_frame = match (self.gas.as_mut(), gas) {
            (Some(series), Some(g)) => {
                let name = format!("gas_{:06}.vti", self.count);
                series.push(t, format!("vtk/{name}"));
                Some((GasFrame::of(g), name, series.clone()))
            }
            _ => None,
        };
        let dir = self.dir.clone();
        self.writer.submit(move || {
            crate::io::vtk::write_particles(&dir.join(&name), &particles)?;
            particle_series.write()?;
            if let Some((frame, name, series)) = gas_frame {
                frame.write(&dir.join(&name))?;
                series.write()?;
            }
            Ok(())
        })?;
        self.count += 1;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }
}

/// A copy of the gas fields for a VTK file, to be written on the writer's
/// thread.
struct GasFrame {
    grid: GridGeometry,
    gas_fraction: Vec<f64>,
    pressure: Vec<f64>,
    density: Vec<f64>,
    face_velocity: [Vec<f64>; 3],
}

impl GasFrame {
    fn of(g: &GasRun) -> Self {
        let g = &g.gas;
        GasFrame {
            grid: g.grid.clone(),
            gas_fraction: g.gas_fraction.clone(),
            pressure: g.pressure.clone(),
            density: g.density.clone(),
            // Planar grids carry no z velocity (the writer reads none).
            face_velocity: [
                g.velocity[0].clone(),
                g.velocity[1].clone(),
                if g.grid.planar {
                    Vec::new()
                } else {
                    g.velocity[2].clone()
                },
            ],
        }
    }

    /// The fields as a VTK file for ParaView (format from the extension:
    /// `.vti` XML ImageData in the `.pvd` series).
    fn write(&self, path: &Path) -> anyhow::Result<()> {
        crate::io::vtk::write_gas(
            path,
            &self.grid,
            &crate::io::vtk::GasFields {
                gas_fraction: &self.gas_fraction,
                pressure: &self.pressure,
                density: &self.density,
                face_velocity: [
                    &self.face_velocity[0],
                    &self.face_velocity[1],
                    &self.face_velocity[2],
                ],
            },
        )
    }
}

impl<Q: EventQueue> Recorder<Q> for VtkSeries {
    fn start(&mut self, engine: &mut Engine<Q>, gas: Option<&mut GasRun>) -> anyhow::Result<()> {
        self.write(engine, gas.as_deref())
    }

    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        if due(end, self.next) {
            self.write(engine, gas.as_deref())?;
        }
        Ok(())
    }

    /// Every VTK file is on disk before the run reports its end.
    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        self.writer.finish()
    }
}
