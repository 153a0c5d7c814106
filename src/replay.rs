//! `edpm replay`: rebuild a run from its event log alone, verify it against
//! the log's checkpoints, write the state at any time, and compute collision
//! statistics that were not planned when the run was made.

use std::path::{Path, PathBuf};

use anyhow::Context;
use glam::DVec3;

use crate::collision::{self, Body};
use crate::io::eventlog::{
    Block, GasBlock, LogHeader, LogReader, LogRecord, RecordKind, Replay, ReplayParticle,
};
use crate::io::output::write_atomic;

/// What `edpm replay` should do.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReplayOptions {
    /// Write the state at this absolute time (s).
    pub at: Option<f64>,
    /// Compare with every checkpoint, bit for bit.
    pub verify: bool,
    /// Collision statistics.
    pub stats: bool,
    /// Output directory (default: the log's directory).
    pub out: Option<PathBuf>,
}

/// What a replay found.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ReplayOutcome {
    pub records: u64,
    pub checkpoints_verified: u64,
    /// The first difference from a checkpoint, if any.
    pub first_mismatch: Option<String>,
    /// Byte offset where a truncated log stopped.
    pub truncated_at: Option<u64>,
    /// Byte offset where a log without its end block stops (the run was
    /// killed, or blocks at its end are missing), when replayed to its end.
    pub missing_end_at: Option<u64>,
    /// Absolute time of the last record replayed (s).
    pub end_time: f64,
    pub particles: usize,
    pub stats: Option<CollisionStats>,
    /// Times of the gas blocks read (s): a gas run logs its fields with
    /// each checkpoint.
    pub gas_times: Vec<f64>,
    /// The gas fields at exactly `at`, when the log holds them.
    #[serde(skip)]
    pub gas_at: Option<Box<GasBlock>>,
}

/// `t` (s) as file names and messages show it: plainly (`0.005`), or in
/// exponent form where that would be long (`1e-320`, not 320 digits,
/// which no file system takes as a name).
fn time_label(t: f64) -> String {
    let plain = format!("{t}");
    if plain.len() <= 20 {
        plain
    } else {
        format!("{t:e}")
    }
}

/// Entry point of `edpm replay`.
pub fn replay_cli(path: &Path, opts: &ReplayOptions) -> anyhow::Result<()> {
    let (outcome, replay) = replay_log(path, opts)?;
    if let Some(offset) = outcome.truncated_at {
        eprintln!(
            "edpm: warning: {} is truncated at byte {offset}; replayed up to time {} s",
            path.display(),
            outcome.end_time
        );
    }
    if let Some(offset) = outcome.missing_end_at {
        eprintln!(
            "edpm: warning: {} has no end block after byte offset {offset}: the run that wrote it \
             was killed, or the blocks after that offset are missing; replayed up to time {} s",
            path.display(),
            outcome.end_time
        );
    }
    let out_dir = match &opts.out {
        Some(d) => d.clone(),
        None => path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .map_or(PathBuf::from("."), Path::to_path_buf),
    };
    if let Some(t) = opts.at {
        let particles = replay.positions_at(t);
        let label = time_label(t);
        let stem = format!("state_at_{label}");
        write_state_csv(&particles, &out_dir.join(format!("{stem}.csv")))?;
        write_state_vtk(&particles, &out_dir.join(format!("{stem}.vtk")))?;
        println!(
            "state at t = {label} s: {} particles written to {}/{stem}.{{csv,vtk}}",
            particles.len(),
            out_dir.display()
        );
        if let Some(g) = &outcome.gas_at {
            let name = format!("gas_at_{label}.vtk");
            write_gas_vtk(g, &out_dir.join(&name))?;
            println!(
                "gas fields at t = {label} s written to {}/{name}",
                out_dir.display()
            );
        } else if let Some(&last) = outcome.gas_times.last() {
            println!(
                "gas fields: not written; the log holds them at its checkpoints only (the last at or before {t} s is at {last} s; --log-checkpoint-steps sets how often)"
            );
        }
    }
    if let Some(stats) = &outcome.stats {
        let json = serde_json::to_string_pretty(stats).context("encoding statistics")?;
        write_atomic(&out_dir.join("collision_stats.json"), json.as_bytes())?;
        write_atomic(
            &out_dir.join("collision_histograms.csv"),
            stats.histogram_csv().as_bytes(),
        )?;
        println!("{}", stats.summary());
        println!(
            "statistics written to {}/collision_stats.json and collision_histograms.csv",
            out_dir.display()
        );
    }
    if opts.verify {
        match &outcome.first_mismatch {
            Some(m) => anyhow::bail!(
                "{}: replay differs from the log's checkpoint: {m}",
                path.display()
            ),
            None => println!(
                "verified: {} records, {} checkpoints, bit-identical",
                outcome.records, outcome.checkpoints_verified
            ),
        }
    }
    if !opts.verify && !opts.stats && opts.at.is_none() {
        println!(
            "replayed {} records to t = {} s: {} particles",
            outcome.records, outcome.end_time, outcome.particles
        );
    }
    Ok(())
}

/// A gas block's fields as a legacy VTK file.
fn write_gas_vtk(g: &GasBlock, path: &Path) -> anyhow::Result<()> {
    let grid = crate::domain::grid::GridGeometry {
        lo: g.lo,
        h: g.h,
        n: g.n.map(|k| k as usize),
        periodic: g.periodic,
        planar: g.planar,
    };
    let empty: &[f64] = &[];
    crate::io::vtk::write_gas(
        path,
        &grid,
        &crate::io::vtk::GasFields {
            gas_fraction: &g.gas_fraction,
            pressure: &g.pressure,
            density: &g.density,
            face_velocity: [
                &g.velocity[0],
                &g.velocity[1],
                if g.planar { empty } else { &g.velocity[2] },
            ],
        },
    )
}

/// Replays a log: up to `opts.at` if given, else to its end.
pub fn replay_log(path: &Path, opts: &ReplayOptions) -> anyhow::Result<(ReplayOutcome, Replay)> {
    if let Some(t) = opts.at
        && !(t.is_finite() && t >= 0.0)
    {
        anyhow::bail!("--at: must be a time >= 0 s, got {t}");
    }
    let mut reader = LogReader::open(path)?;
    let mut replay = Replay::start(&reader.header, reader.id_limit())
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let mut stats = opts.stats.then(|| CollisionStats::new(&reader.header));
    // Seeking: start from the last checkpoint at or before the time asked.
    if let (Some(t), false, false) = (opts.at, opts.verify, opts.stats)
        && let Some(&(offset, _)) = reader
            .checkpoint_index()?
            .iter()
            .rev()
            .find(|&&(_, time)| time <= t)
    {
        reader.seek(offset)?;
    }
    let mut outcome = ReplayOutcome {
        records: 0,
        checkpoints_verified: 0,
        first_mismatch: None,
        truncated_at: None,
        missing_end_at: None,
        end_time: 0.0,
        particles: 0,
        stats: None,
        gas_times: Vec::new(),
        gas_at: None,
    };
    // Whether the replay ran to the end of the log (not stopped at `at`).
    let mut reached_end = true;
    let mut blocks = 0u64;
    'blocks: loop {
        let block = reader.next_block().map_err(|e| {
            anyhow::anyhow!(
                "{e} (replayed {} records, up to time {} s)",
                outcome.records,
                replay.time
            )
        })?;
        let Some(block) = block else { break };
        blocks += 1;
        match block {
            Block::Records(records) => {
                for r in &records {
                    // The state at T is the end of the flow step at T: later
                    // records, and kicks or insertions at T itself, are the
                    // next step's.
                    let after = |t: f64| {
                        r.time > t || (r.time == t && r.kind != RecordKind::FlowStepEnd as u32)
                    };
                    if opts.at.is_some_and(after) {
                        reached_end = false;
                        break 'blocks;
                    }
                    if let Some(s) = stats.as_mut() {
                        s.observe(&reader.header, &replay, r);
                    }
                    replay
                        .apply(r)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
                    outcome.records += 1;
                }
                reader.recycle(records);
            }
            Block::Checkpoint(h, particles) => {
                if opts.at.is_some_and(|t| h.time > t) {
                    reached_end = false;
                    break;
                }
                if opts.verify && outcome.first_mismatch.is_none() {
                    match replay.compare(&particles) {
                        Some(m) => {
                            outcome.first_mismatch =
                                Some(format!("at t = {} s (flow step {}): {m}", h.time, h.step))
                        }
                        None => outcome.checkpoints_verified += 1,
                    }
                } else if !opts.verify && !opts.stats {
                    // Seeking: a checkpoint is the state itself.
                    replay
                        .load_checkpoint(&h, &particles)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
                }
            }
            other => {
                let applied = apply_set_block(other, opts.at, &mut replay, &mut outcome)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
                if !applied {
                    reached_end = false;
                    break;
                }
            }
        }
    }
    if blocks == 0 {
        anyhow::bail!(
            "{}: the log holds no blocks (no records and no checkpoints){}: nothing to replay",
            path.display(),
            match reader.truncated_at {
                Some(offset) => format!("; it is cut at byte {offset}, inside its first block"),
                None => "; the run that wrote it ended before its first block".to_string(),
            }
        );
    }
    if let Some(t) = opts.at
        && reached_end
        && t > replay.time
    {
        // Beyond the last record the state is unknown (forces act at flow
        // steps): extrapolating would be silently wrong.
        anyhow::bail!(
            "{}: --at {t} s is after the end of the log at {} s{}",
            path.display(),
            replay.time,
            if reader.truncated_at.is_some() {
                " (the log is truncated)"
            } else if reader.end.is_none() {
                " (the log has no end block: the run was killed or its last blocks are missing)"
            } else {
                ""
            }
        );
    }
    outcome.truncated_at = reader.truncated_at;
    if reached_end && reader.end.is_none() && reader.truncated_at.is_none() {
        outcome.missing_end_at = Some(reader.offset());
    }
    outcome.end_time = replay.time;
    outcome.particles = replay.len();
    if let Some(s) = stats.as_mut() {
        s.duration = replay.time;
    }
    outcome.stats = stats;
    Ok((outcome, replay))
}

/// Applies a velocities, states or gas block; `Ok(false)`, applying
/// nothing, when the block lies after `at` (the replay stops there).
fn apply_set_block(
    block: Block,
    at: Option<f64>,
    replay: &mut Replay,
    outcome: &mut ReplayOutcome,
) -> Result<bool, String> {
    match block {
        // The velocities after the gas kicks at the start of a flow step:
        // at T itself they are the next step's.
        Block::Velocities(h, v) if at.is_none_or(|t| h.time < t) => {
            replay.set_velocities(&h, &v)?
        }
        // The states at the end of a flow step (soft and hybrid).
        Block::States(h, v) if at.is_none_or(|t| h.time <= t) => replay.set_states(&h, &v)?,
        Block::Gas(g) if at.is_none_or(|t| g.time <= t) => {
            outcome.gas_times.push(g.time);
            if at == Some(g.time) {
                outcome.gas_at = Some(g);
            }
        }
        // `replay_log` applies these itself.
        Block::Records(_) | Block::Checkpoint(..) => {}
        _ => return Ok(false),
    }
    Ok(true)
}

/// Streaming histogram on log-spaced bins, 10 per decade from 1e-6 to 1e3.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LogHistogram {
    pub lower_edges: Vec<f64>,
    pub counts: Vec<u64>,
    /// Values below the first edge (including zero).
    pub below: u64,
}

impl LogHistogram {
    fn new() -> Self {
        let lower_edges = (0..90)
            .map(|k| 10f64.powf(-6.0 + k as f64 / 10.0))
            .collect();
        LogHistogram {
            lower_edges,
            counts: vec![0; 90],
            below: 0,
        }
    }

    fn add(&mut self, v: f64) {
        if v < 1e-6 || !v.is_finite() {
            self.below += 1;
            return;
        }
        let k = ((v.log10() + 6.0) * 10.0).floor() as usize;
        self.counts[k.min(89)] += 1;
    }
}

/// Statistics of one collision type (pair or wall).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TypeStats {
    pub collisions: u64,
    pub sticking: u64,
    pub sliding: u64,
    /// Kinetic energy dissipated (J): total and per collision.
    pub dissipated: f64,
    pub dissipated_per_collision: f64,
    /// Impact angle between the pre-collision contact velocity and the
    /// normal (degrees), 18 bins of 5°.
    pub impact_angle_deg: Vec<u64>,
    /// Normal and tangential pre-collision contact speeds (m/s).
    pub normal_speed: LogHistogram,
    pub tangential_speed: LogHistogram,
}

impl TypeStats {
    fn new() -> Self {
        TypeStats {
            collisions: 0,
            sticking: 0,
            sliding: 0,
            dissipated: 0.0,
            dissipated_per_collision: 0.0,
            impact_angle_deg: vec![0; 18],
            normal_speed: LogHistogram::new(),
            tangential_speed: LogHistogram::new(),
        }
    }

    fn observe(&mut self, v_ab0: DVec3, n: DVec3, dissipated: f64, aux: u32) {
        let v_n = -v_ab0.dot(n);
        let v_t = (v_ab0 + v_n * n).length();
        let angle = v_t.atan2(v_n.abs()).to_degrees();
        self.impact_angle_deg[((angle / 5.0) as usize).min(17)] += 1;
        self.normal_speed.add(v_n.abs());
        self.tangential_speed.add(v_t);
        self.collisions += 1;
        self.dissipated += dissipated;
        self.dissipated_per_collision = self.dissipated / self.collisions as f64;
        match aux {
            1 => self.sticking += 1,
            2 => self.sliding += 1,
            _ => {}
        }
    }
}

/// Collision statistics of a replayed run.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CollisionStats {
    /// Replayed duration (s).
    pub duration: f64,
    /// Time-averaged particle count (particle-seconds / duration).
    pub mean_particles: f64,
    particle_seconds: f64,
    last_time: f64,
    pub pair: TypeStats,
    pub wall: TypeStats,
}

impl CollisionStats {
    fn new(_header: &LogHeader) -> Self {
        CollisionStats {
            duration: 0.0,
            mean_particles: 0.0,
            particle_seconds: 0.0,
            last_time: 0.0,
            pair: TypeStats::new(),
            wall: TypeStats::new(),
        }
    }

    /// Pair collisions per particle per second (each collision counts for
    /// both partners) and wall collisions per particle per second.
    pub fn frequencies(&self) -> (f64, f64) {
        let ps = self.particle_seconds.max(1e-300);
        (
            2.0 * self.pair.collisions as f64 / ps,
            self.wall.collisions as f64 / ps,
        )
    }

    fn observe(&mut self, header: &LogHeader, replay: &Replay, r: &LogRecord) {
        self.particle_seconds += replay.len() as f64 * (r.time - self.last_time);
        self.last_time = r.time;
        self.mean_particles = self.particle_seconds / r.time.max(1e-300);
        let body = |p: &ReplayParticle| Body {
            vel: p.state.vel,
            omega: p.state.omega,
            radius: p.radius,
            inv_mass: 1.0
                / (header.densities[p.material as usize] * 4.0 / 3.0
                    * std::f64::consts::PI
                    * p.radius.powi(3)),
        };
        let after = |b: &Body, s: &[f64; 9]| Body {
            vel: DVec3::new(s[3], s[4], s[5]),
            omega: DVec3::new(s[6], s[7], s[8]),
            ..*b
        };
        if r.kind == RecordKind::Pair as u32 {
            let (Some(pa), Some(pb)) = (replay.get(r.a), replay.get(r.b)) else {
                return;
            };
            let (a, b) = (body(pa), body(pb));
            let d = DVec3::new(r.state_a[0], r.state_a[1], r.state_a[2])
                - DVec3::new(r.state_b[0], r.state_b[1], r.state_b[2]);
            let d = d + header.domain.image_shift(header.domain.image_code(d));
            let n = d.normalize();
            let loss = collision::kinetic_energy(&a) + collision::kinetic_energy(&b)
                - collision::kinetic_energy(&after(&a, &r.state_a))
                - collision::kinetic_energy(&after(&b, &r.state_b));
            self.pair
                .observe(collision::contact_velocity(n, &a, &b), n, loss, r.aux);
        } else if r.kind == RecordKind::Wall as u32 {
            // An unknown particle or face is reported by `Replay::apply`.
            let (Some(pa), true) = (replay.get(r.a), r.b < 6) else {
                return;
            };
            let a = body(pa);
            let mut n = DVec3::ZERO;
            n[(r.b / 2) as usize] = if r.b.is_multiple_of(2) { 1.0 } else { -1.0 };
            let loss =
                collision::kinetic_energy(&a) - collision::kinetic_energy(&after(&a, &r.state_a));
            self.wall.observe(
                collision::contact_velocity(n, &a, &Body::WALL),
                n,
                loss,
                r.aux,
            );
        }
    }

    /// A few lines for the terminal.
    pub fn summary(&self) -> String {
        let (fp, fw) = self.frequencies();
        let mut s = format!(
            "replayed {:.6} s, {:.1} particles on average\n\
             pair collisions: {} ({fp:.4e} per particle per s), {} sticking, {} sliding, {:.4e} J dissipated ({:.4e} J per collision)\n\
             wall collisions: {} ({fw:.4e} per particle per s), {} sticking, {} sliding, {:.4e} J dissipated ({:.4e} J per collision)",
            self.duration,
            self.mean_particles,
            self.pair.collisions,
            self.pair.sticking,
            self.pair.sliding,
            self.pair.dissipated,
            self.pair.dissipated_per_collision,
            self.wall.collisions,
            self.wall.sticking,
            self.wall.sliding,
            self.wall.dissipated,
            self.wall.dissipated_per_collision,
        );
        let angles = |t: &TypeStats| {
            let n = t.collisions.max(1) as f64;
            t.impact_angle_deg
                .iter()
                .map(|&c| format!("{:.3}", c as f64 / n))
                .collect::<Vec<_>>()
                .join(" ")
        };
        s.push_str(&format!(
            "\npair impact-angle fractions per 5 deg: {}",
            angles(&self.pair)
        ));
        s.push_str(&format!(
            "\nwall impact-angle fractions per 5 deg: {}",
            angles(&self.wall)
        ));
        s
    }

    /// Histograms as one CSV table.
    pub fn histogram_csv(&self) -> String {
        let mut s = String::from("quantity,type,bin_lower,bin_upper,count\n");
        for (name, t) in [("pair", &self.pair), ("wall", &self.wall)] {
            for (k, c) in t.impact_angle_deg.iter().enumerate() {
                s.push_str(&format!(
                    "impact_angle_deg,{name},{},{},{c}\n",
                    5 * k,
                    5 * (k + 1)
                ));
            }
            for (q, h) in [
                ("normal_speed_m_s", &t.normal_speed),
                ("tangential_speed_m_s", &t.tangential_speed),
            ] {
                s.push_str(&format!("{q},{name},0,1e-6,{}\n", h.below));
                for (k, c) in h.counts.iter().enumerate() {
                    let lo = h.lower_edges[k];
                    s.push_str(&format!(
                        "{q},{name},{lo:e},{:e},{c}\n",
                        lo * 10f64.powf(0.1)
                    ));
                }
            }
        }
        s
    }
}

fn write_state_csv(particles: &[(u64, ReplayParticle)], path: &Path) -> anyhow::Result<()> {
    let mut s = String::from(
        "id,material,radius_m,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,wx_rad_s,wy_rad_s,wz_rad_s\n",
    );
    for (id, p) in particles {
        let (x, v, w) = (p.state.pos, p.state.vel, p.state.omega);
        s.push_str(&format!(
            "{id},{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}\n",
            p.material, p.radius, x.x, x.y, x.z, v.x, v.y, v.z, w.x, w.y, w.z
        ));
    }
    write_atomic(path, s.as_bytes())
}

/// Legacy-format VTK polydata (ParaView): points with radius, velocity and
/// angular velocity.
fn write_state_vtk(particles: &[(u64, ReplayParticle)], path: &Path) -> anyhow::Result<()> {
    let particles = particles
        .iter()
        .map(|(id, p)| {
            Ok(crate::io::vtk::VtkParticle {
                id: *id,
                pos: p.state.pos,
                vel: p.state.vel,
                omega: p.state.omega,
                radius: p.radius,
                material: u16::try_from(p.material)
                    .with_context(|| format!("particle {id}: material {}", p.material))?,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    crate::io::vtk::write_particles(path, &particles)
}
