//! The final state of a completed run: `final_state.bin` (a checkpoint a
//! later run can start from, `initial.checkpoint`) and
//! `final_particles.csv`. A failed run removes those of an earlier run in
//! the same directory, which would contradict its summary.

use std::path::{Path, PathBuf};

use anyhow::Context;

use super::{Recorder, RunEnd};
use crate::engine::Engine;
use crate::io::output::{CHECKPOINT_VERSION, Checkpoint, write_atomic};
use crate::particles::NewParticle;
use crate::queue::EventQueue;

pub struct FinalState {
    out_dir: PathBuf,
}

impl FinalState {
    pub fn new(out_dir: &Path) -> Self {
        FinalState {
            out_dir: out_dir.to_path_buf(),
        }
    }
}

impl<Q: EventQueue> Recorder<Q> for FinalState {
    fn finish(&mut self, engine: &mut Engine<Q>, end: &mut RunEnd) -> anyhow::Result<()> {
        if !end.completed {
            for stale in ["final_state.bin", "final_particles.csv"] {
                match std::fs::remove_file(self.out_dir.join(stale)) {
                    Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                        return Err(e)
                            .with_context(|| format!("removing {stale} of an earlier run"));
                    }
                    _ => {}
                }
            }
            return Ok(());
        }
        let final_particles: Vec<NewParticle> = engine.particles().map(NewParticle::from).collect();
        Checkpoint {
            // A checkpoint is a state, the same whichever run reached it:
            // no run id, so that equal states give equal files.
            run_id: 0,
            version: CHECKPOINT_VERSION,
            time: engine.time(),
            particles: final_particles,
        }
        .write(&self.out_dir.join("final_state.bin"))?;
        write_particles_csv(engine, &self.out_dir.join("final_particles.csv"))
    }
}

/// Final particle state as CSV (SI units).
fn write_particles_csv<Q: EventQueue>(engine: &Engine<Q>, path: &Path) -> anyhow::Result<()> {
    let mut text = String::from(
        "id,material,radius_m,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,wx_rad_s,wy_rad_s,wz_rad_s\n",
    );
    for p in engine.particles() {
        text.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            p.id,
            p.material,
            p.radius,
            p.pos.x,
            p.pos.y,
            p.pos.z,
            p.vel.x,
            p.vel.y,
            p.vel.z,
            p.omega.x,
            p.omega.y,
            p.omega.z
        ));
    }
    write_atomic(path, text.as_bytes())
}
