//! VTK snapshots for ParaView: particles (`vtk/particles_NNNNNN.vtp`) and
//! gas fields (`vtk/gas_NNNNNN.vti`) with `.pvd` series (src/io/vtk.rs).

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{Recorder, StepEnd, due, next_multiple};
use crate::engine::Engine;
use crate::gas::flow::GasRun;
use crate::io::vtk::{PvdSeries, VtkParticle};
use crate::queue::EventQueue;

/// VTK snapshots of particles (and gas) with ParaView `.pvd` series.
pub struct VtkSeries {
    dir: PathBuf,
    interval: f64,
    next: f64,
    count: usize,
    particles: PvdSeries,
    gas: Option<PvdSeries>,
}

impl VtkSeries {
    pub fn new(out_dir: &Path, interval: f64, gas: bool) -> Self {
        let dir = out_dir.join("vtk");
        VtkSeries {
            particles: PvdSeries::new(out_dir.join("particles.pvd")),
            gas: gas.then(|| PvdSeries::new(out_dir.join("gas.pvd"))),
            dir,
            interval,
            next: 0.0,
            count: 0,
        }
    }

    fn write<Q: EventQueue>(
        &mut self,
        engine: &Engine<Q>,
        gas: Option<&GasRun>,
    ) -> anyhow::Result<()> {
        std::fs::create_dir_all(&self.dir)
            .with_context(|| format!("creating {}", self.dir.display()))?;
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
        crate::io::vtk::write_particles(&self.dir.join(&name), &particles)?;
        self.particles.push(t, format!("vtk/{name}"));
        self.particles.write()?;
        if let (Some(series), Some(g)) = (self.gas.as_mut(), gas) {
            let name = format!("gas_{:06}.vti", self.count);
            write_gas_vtk(g, &self.dir.join(&name))?;
            series.push(t, format!("vtk/{name}"));
            series.write()?;
        }
        self.count += 1;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }
}

/// The gas fields of `g` as a VTK file for ParaView (format from the
/// extension: `.vti` XML ImageData in the `.pvd` series).
fn write_gas_vtk(g: &GasRun, path: &Path) -> anyhow::Result<()> {
    let empty: &[f64] = &[];
    let g = &g.gas;
    crate::io::vtk::write_gas(
        path,
        &g.grid,
        &crate::io::vtk::GasFields {
            gas_fraction: &g.gas_fraction,
            pressure: &g.pressure,
            density: &g.density,
            face_velocity: [
                &g.velocity[0],
                &g.velocity[1],
                if g.grid.planar { empty } else { &g.velocity[2] },
            ],
        },
    )
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
}
