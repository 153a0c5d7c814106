//! Binary event logs: every state change of a run, replayable bit for bit.
//!
//! Layout (all integers and floats little-endian; see docs/event-log.md):
//!
//! ```text
//! file header   32 bytes: magic "EDPMLOG\0", version u32, header length u32,
//!               header CRC-32 u32, 12 reserved bytes
//! header        bincode (serde, fixed-int, little-endian) of LogHeader
//! block*        24-byte block header: magic "BLK\0", kind u32 (1 records,
//!               2 checkpoint, 3 end, 4 velocities, 5 states, 6 gas),
//!               count u32, payload length u32, CRC-32
//!               u32 (of kind, count, length, sequence and payload),
//!               sequence number u32 (0, 1, 2, … in file order); then the
//!               payload
//! ```
//!
//! A records payload is `count` records of exactly [`RECORD_BYTES`] bytes
//! ([`LogRecord`]). A checkpoint payload is a [`CheckpointHeader`] followed
//! by `count` particles of exactly [`PARTICLE_BYTES`] bytes
//! ([`LogParticle`]). The end block, written when the run ends, holds the
//! number of records and the end time ([`LogEnd`]). A velocities block
//! (gas runs: the velocities after each flow step's gas kicks) or a states
//! block (soft and hybrid runs: every state after each flow step) is a
//! [`SetHeader`] followed by `count` entries of [`VELOCITY_ENTRY_BYTES`]
//! or [`STATE_ENTRY_BYTES`] bytes: an id and the values replay sets. A
//! gas block (with each checkpoint of a gas run) holds the gas fields
//! ([`GasBlock`], bincode), for `replay --at`'s VTK files; replay itself
//! never needs them.
//! Blocks are written
//! whole and flushed, so a killed run leaves a log that reads up to its
//! last complete block; the sequence numbers and the end block expose a
//! block missing in the middle or at the end.

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use glam::DVec3;

use crate::domain::Domain;
use crate::engine::{CollisionRecord, Partner, Record, State};
use crate::particles::NewParticle;

/// Format version written by this build: 2 added block sequence numbers,
/// the end block, and block checksums that cover the block header; 3 added
/// the velocities and states blocks (gas, soft and hybrid runs).
pub const FORMAT_VERSION: u32 = 3;
/// Oldest format version read: a version 2 log is a version 3 log without
/// velocities or states blocks.
pub const OLDEST_READ_VERSION: u32 = 2;
pub const FILE_MAGIC: [u8; 8] = *b"EDPMLOG\0";
pub const BLOCK_MAGIC: [u8; 4] = *b"BLK\0";
/// Size of the fixed file header (bytes).
pub const FILE_HEADER_BYTES: usize = 32;
/// Size of a block header (bytes).
pub const BLOCK_HEADER_BYTES: usize = 24;
/// Size of one encoded [`LogRecord`] (bytes).
pub const RECORD_BYTES: usize = 184;
/// Size of one encoded [`LogParticle`] (bytes).
pub const PARTICLE_BYTES: usize = 96;
/// Size of an encoded [`CheckpointHeader`] (bytes).
pub const CHECKPOINT_HEADER_BYTES: usize = 24;
/// Size of an end block's payload ([`LogEnd`], bytes).
pub const END_BYTES: usize = 16;
/// Records per block: about 750 kB, flushed as one write.
pub const RECORDS_PER_BLOCK: usize = 4096;

const KIND_RECORDS: u32 = 1;
const KIND_CHECKPOINT: u32 = 2;
const KIND_END: u32 = 3;
const KIND_VELOCITIES: u32 = 4;
const KIND_STATES: u32 = 5;
const KIND_GAS: u32 = 6;
/// Bytes of the header of a velocities or states block ([`SetHeader`]).
pub const SET_HEADER_BYTES: usize = 16;
/// Bytes of one velocities entry: id u64, velocity 3 × f64.
pub const VELOCITY_ENTRY_BYTES: usize = 32;
/// Bytes of one states entry: id u64, state 9 × f64.
pub const STATE_ENTRY_BYTES: usize = 80;

/// The end block's payload: what a complete log holds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LogEnd {
    /// Records in the whole log.
    pub records: u64,
    /// Absolute time at which the run ended (s).
    pub time: f64,
}

/// What a record describes ([`LogRecord::kind`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum RecordKind {
    /// Pair collision: `a`, `b` ids, states after the collision.
    Pair = 1,
    /// Wall collision: `a` id, `b` the face (2 axis + hi), state after.
    Wall = 2,
    /// Periodic wrap: `a` id, its state at `clock` in the new image.
    Wrap = 3,
    /// Insertion: `a` id, its state, `aux` material, `state_b[0]` radius.
    Insert = 4,
    /// Removal: `a` id, its state when it left.
    Remove = 5,
    /// End of a flow step at `clock`: every particle is moved to `clock`,
    /// then clocks restart at 0.
    FlowStepEnd = 6,
    /// Uniform velocity kick: `state_a[0..3]` is added to every velocity.
    Kick = 7,
}

/// The file header's payload.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LogHeader {
    /// `edpm` version that wrote the log.
    pub writer: String,
    /// Scenario text exactly as read, and the `--set` overrides applied.
    pub scenario_text: String,
    pub overrides: Vec<String>,
    pub seed: u64,
    /// Flow step (s).
    pub dt_flow: f64,
    pub domain: Domain,
    /// Density per material (kg/m³; 0 for wall-only materials).
    pub densities: Vec<f64>,
    /// Particles at time 0 with their ids.
    pub initial: Vec<(u64, NewParticle)>,
}

/// One fixed-size record ([`RECORD_BYTES`] bytes encoded).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LogRecord {
    /// A [`RecordKind`] as u32.
    pub kind: u32,
    /// Collision branch (0 smooth, 1 sticking, 2 sliding) or material.
    pub aux: u32,
    /// Absolute time (s).
    pub time: f64,
    /// Engine clock within the flow step (s); what replay extrapolates with.
    pub clock: f64,
    pub a: u64,
    pub b: u64,
    /// Position, velocity, angular velocity of a (SI).
    pub state_a: [f64; 9],
    pub state_b: [f64; 9],
}

/// One particle of a checkpoint ([`PARTICLE_BYTES`] bytes encoded).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LogParticle {
    pub id: u64,
    pub material: u32,
    pub reserved: u32,
    pub radius: f64,
    /// Position, velocity, angular velocity (SI).
    pub state: [f64; 9],
}

/// Start of a checkpoint payload.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CheckpointHeader {
    /// Absolute time (s).
    pub time: f64,
    /// Engine clock (s), 0 right after a flow step.
    pub clock: f64,
    /// Flow steps completed.
    pub step: u64,
}

fn config() -> impl bincode::config::Config {
    bincode::config::standard()
        .with_little_endian()
        .with_fixed_int_encoding()
}

fn state_array(s: &State) -> [f64; 9] {
    let mut a = [0.0; 9];
    a[0..3].copy_from_slice(&s.pos.to_array());
    a[3..6].copy_from_slice(&s.vel.to_array());
    a[6..9].copy_from_slice(&s.omega.to_array());
    a
}

fn array_state(a: &[f64; 9]) -> State {
    State {
        pos: DVec3::new(a[0], a[1], a[2]),
        vel: DVec3::new(a[3], a[4], a[5]),
        omega: DVec3::new(a[6], a[7], a[8]),
    }
}

impl LogRecord {
    /// Decodes one record from its [`RECORD_BYTES`] little-endian bytes:
    /// the same result as bincode's decoding (tested), without its
    /// per-field dispatch, since replay reads millions of them.
    pub fn decode(b: &[u8]) -> LogRecord {
        let u32_at = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"));
        let u64_at = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"));
        let f64_at = |at: usize| f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"));
        LogRecord {
            kind: u32_at(0),
            aux: u32_at(4),
            time: f64_at(8),
            clock: f64_at(16),
            a: u64_at(24),
            b: u64_at(32),
            state_a: std::array::from_fn(|k| f64_at(40 + 8 * k)),
            state_b: std::array::from_fn(|k| f64_at(112 + 8 * k)),
        }
    }

    /// The log form of an engine record.
    pub fn from_engine(r: &Record) -> LogRecord {
        match *r {
            Record::Collision(CollisionRecord {
                time,
                clock,
                b,
                ids,
                after,
                kind,
                ..
            }) => {
                let aux = kind as u32;
                match b {
                    Partner::Particle(_) => LogRecord {
                        kind: RecordKind::Pair as u32,
                        aux,
                        time,
                        clock,
                        a: ids[0],
                        b: ids[1],
                        state_a: state_array(&after[0]),
                        state_b: state_array(&after[1]),
                    },
                    Partner::Wall(face) => LogRecord {
                        kind: RecordKind::Wall as u32,
                        aux,
                        time,
                        clock,
                        a: ids[0],
                        b: face as u64,
                        state_a: state_array(&after[0]),
                        state_b: [0.0; 9],
                    },
                }
            }
            Record::Wrap {
                time,
                clock,
                id,
                state,
            } => LogRecord {
                kind: RecordKind::Wrap as u32,
                time,
                clock,
                a: id,
                state_a: state_array(&state),
                ..Default::default()
            },
            Record::Insert {
                time,
                clock,
                id,
                particle,
            } => {
                let mut state_b = [0.0; 9];
                state_b[0] = particle.radius;
                LogRecord {
                    kind: RecordKind::Insert as u32,
                    aux: particle.material as u32,
                    time,
                    clock,
                    a: id,
                    b: 0,
                    state_a: state_array(&State {
                        pos: particle.pos,
                        vel: particle.vel,
                        omega: particle.omega,
                    }),
                    state_b,
                }
            }
            Record::Remove {
                time,
                clock,
                id,
                state,
            } => LogRecord {
                kind: RecordKind::Remove as u32,
                time,
                clock,
                a: id,
                state_a: state_array(&state),
                ..Default::default()
            },
        }
    }
}

/// Writes an event log block by block; each block is one `write` call
/// straight to the file, so a killed run loses at most the pending block.
pub struct LogWriter {
    file: std::fs::File,
    /// Block header space followed by the encoded pending records.
    pending: Vec<u8>,
    pending_count: usize,
    /// Bytes written so far, including the pending block once flushed.
    pub bytes: u64,
    pub records: u64,
    /// Blocks written so far: the sequence number of the next block.
    blocks: u32,
}

impl LogWriter {
    /// Creates `path` and writes the file header.
    pub fn create(path: &Path, header: &LogHeader) -> anyhow::Result<LogWriter> {
        let payload =
            bincode::serde::encode_to_vec(header, config()).context("encoding log header")?;
        let file = std::fs::File::create(path)
            .with_context(|| format!("creating event log {}", path.display()))?;
        let mut file = file;
        let len = u32::try_from(payload.len()).context("log header exceeds 4 GiB")?;
        let mut fixed = [0u8; FILE_HEADER_BYTES];
        fixed[0..8].copy_from_slice(&FILE_MAGIC);
        fixed[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        fixed[12..16].copy_from_slice(&len.to_le_bytes());
        fixed[16..20].copy_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        file.write_all(&[&fixed[..], &payload].concat())?;
        Ok(LogWriter {
            file,
            pending: Self::empty_block(),
            pending_count: 0,
            bytes: (FILE_HEADER_BYTES + payload.len()) as u64,
            records: 0,
            blocks: 0,
        })
    }

    /// Appends one record; full blocks are written and flushed.
    pub fn push(&mut self, r: &LogRecord) -> anyhow::Result<()> {
        let at = self.pending.len();
        self.pending.resize(at + RECORD_BYTES, 0);
        let n = bincode::serde::encode_into_slice(r, &mut self.pending[at..], config())
            .context("encoding record")?;
        debug_assert_eq!(n, RECORD_BYTES);
        self.pending_count += 1;
        self.records += 1;
        if self.pending_count == RECORDS_PER_BLOCK {
            self.flush()?;
        }
        Ok(())
    }

    fn empty_block() -> Vec<u8> {
        let mut v = Vec::with_capacity(BLOCK_HEADER_BYTES + RECORDS_PER_BLOCK * RECORD_BYTES);
        v.resize(BLOCK_HEADER_BYTES, 0);
        v
    }

    /// Writes the pending records as one block (one write call).
    pub fn flush(&mut self) -> anyhow::Result<()> {
        if self.pending_count > 0 {
            let mut block = std::mem::take(&mut self.pending);
            let header = block_header(
                KIND_RECORDS,
                self.pending_count as u32,
                self.next_sequence()?,
                &block[BLOCK_HEADER_BYTES..],
            )?;
            block[..BLOCK_HEADER_BYTES].copy_from_slice(&header);
            self.file.write_all(&block)?;
            self.bytes += block.len() as u64;
            block.truncate(BLOCK_HEADER_BYTES);
            self.pending = block;
            self.pending_count = 0;
        }
        Ok(())
    }

    /// Writes a full-state checkpoint block (after flushing pending records).
    pub fn checkpoint(
        &mut self,
        header: CheckpointHeader,
        particles: &[LogParticle],
    ) -> anyhow::Result<()> {
        self.flush()?;
        let mut payload =
            bincode::serde::encode_to_vec(header, config()).context("encoding checkpoint")?;
        let mut scratch = [0u8; PARTICLE_BYTES];
        for p in particles {
            bincode::serde::encode_into_slice(p, &mut scratch, config())
                .context("encoding checkpoint")?;
            payload.extend_from_slice(&scratch);
        }
        let count =
            u32::try_from(particles.len()).context("checkpoint holds too many particles")?;
        let header = block_header(KIND_CHECKPOINT, count, self.next_sequence()?, &payload)?;
        self.file.write_all(&[&header[..], &payload].concat())?;
        self.bytes += (BLOCK_HEADER_BYTES + payload.len()) as u64;
        Ok(())
    }

    /// Writes a velocities block (after flushing pending records): the
    /// velocity of every particle given, set at `clock` (s).
    pub fn velocities(
        &mut self,
        time: f64,
        clock: f64,
        particles: impl Iterator<Item = (u64, DVec3)>,
    ) -> anyhow::Result<()> {
        let mut payload = Vec::new();
        payload.extend_from_slice(&time.to_le_bytes());
        payload.extend_from_slice(&clock.to_le_bytes());
        for (id, v) in particles {
            payload.extend_from_slice(&id.to_le_bytes());
            for x in v.to_array() {
                payload.extend_from_slice(&x.to_le_bytes());
            }
        }
        self.set_block(KIND_VELOCITIES, VELOCITY_ENTRY_BYTES, payload)
    }

    /// Writes a states block (after flushing pending records): the state
    /// of every particle given, at `clock` (s).
    pub fn states(
        &mut self,
        time: f64,
        clock: f64,
        particles: impl Iterator<Item = (u64, State)>,
    ) -> anyhow::Result<()> {
        let mut payload = Vec::new();
        payload.extend_from_slice(&time.to_le_bytes());
        payload.extend_from_slice(&clock.to_le_bytes());
        for (id, s) in particles {
            payload.extend_from_slice(&id.to_le_bytes());
            for x in state_array(&s) {
                payload.extend_from_slice(&x.to_le_bytes());
            }
        }
        self.set_block(KIND_STATES, STATE_ENTRY_BYTES, payload)
    }

    /// Writes a gas block (after flushing pending records).
    pub fn gas(&mut self, g: &GasBlock) -> anyhow::Result<()> {
        self.flush()?;
        let payload = bincode::serde::encode_to_vec(g, config()).context("encoding gas block")?;
        let count = u32::try_from(g.gas_fraction.len()).context("too many gas cells")?;
        let header = block_header(KIND_GAS, count, self.next_sequence()?, &payload)?;
        self.file.write_all(&[&header[..], &payload].concat())?;
        self.bytes += (BLOCK_HEADER_BYTES + payload.len()) as u64;
        Ok(())
    }

    fn set_block(&mut self, kind: u32, entry: usize, payload: Vec<u8>) -> anyhow::Result<()> {
        self.flush()?;
        let count = u32::try_from((payload.len() - SET_HEADER_BYTES) / entry)
            .context("block holds too many particles")?;
        let header = block_header(kind, count, self.next_sequence()?, &payload)?;
        self.file.write_all(&[&header[..], &payload].concat())?;
        self.bytes += (BLOCK_HEADER_BYTES + payload.len()) as u64;
        Ok(())
    }

    /// Flushes the pending records and writes the end block: the log is
    /// complete. `time` is the end of the run (s).
    pub fn finish(&mut self, time: f64) -> anyhow::Result<()> {
        self.flush()?;
        let mut payload = Vec::with_capacity(END_BYTES);
        payload.extend_from_slice(&self.records.to_le_bytes());
        payload.extend_from_slice(&time.to_le_bytes());
        let header = block_header(KIND_END, 0, self.next_sequence()?, &payload)?;
        self.file.write_all(&[&header[..], &payload].concat())?;
        self.bytes += (BLOCK_HEADER_BYTES + payload.len()) as u64;
        Ok(())
    }

    fn next_sequence(&mut self) -> anyhow::Result<u32> {
        let seq = self.blocks;
        self.blocks = seq
            .checked_add(1)
            .context("the event log exceeds 2^32 blocks")?;
        Ok(seq)
    }
}

/// The 24-byte header of block number `seq` with this payload.
fn block_header(
    kind: u32,
    count: u32,
    seq: u32,
    payload: &[u8],
) -> anyhow::Result<[u8; BLOCK_HEADER_BYTES]> {
    let mut h = [0u8; BLOCK_HEADER_BYTES];
    h[0..4].copy_from_slice(&BLOCK_MAGIC);
    h[4..8].copy_from_slice(&kind.to_le_bytes());
    h[8..12].copy_from_slice(&count.to_le_bytes());
    let len = u32::try_from(payload.len()).context("log block exceeds 4 GiB")?;
    h[12..16].copy_from_slice(&len.to_le_bytes());
    h[20..24].copy_from_slice(&seq.to_le_bytes());
    let crc = block_crc(&h, payload);
    h[16..20].copy_from_slice(&crc.to_le_bytes());
    Ok(h)
}

/// CRC-32 of a block: its header's kind, count and length (bytes 4..16)
/// and sequence number (20..24), then its payload.
fn block_crc(header: &[u8; BLOCK_HEADER_BYTES], payload: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&header[4..16]);
    h.update(&header[20..24]);
    h.update(payload);
    h.finalize()
}

/// Decodes a header payload; a forged length cannot make the decoder
/// allocate more than the payload can hold
/// ([`crate::io::container::decode_bounded`]).
fn decode_header(payload: &[u8]) -> Result<LogHeader, bincode::error::DecodeError> {
    crate::io::container::decode_bounded(payload).map(|(h, _)| h)
}

/// Why reading a log stopped early or failed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LogError {
    #[error("{file}: not an edpm event log (bad magic)")]
    NotALog { file: String },
    #[error(
        "{file}: event log format version {found} is not supported (this edpm reads versions {OLDEST_READ_VERSION} to {FORMAT_VERSION})"
    )]
    Version { file: String, found: u32 },
    #[error(
        "{file}: event log format version 1 (written by an older edpm, without block sequence numbers) is no longer read; this edpm reads versions {OLDEST_READ_VERSION} to {FORMAT_VERSION}: run the scenario again with --log"
    )]
    OldVersion { file: String },
    #[error(
        "{file}: checksum mismatch in {what} at byte offset {offset}: the log is corrupted from there on"
    )]
    Checksum {
        file: String,
        what: String,
        offset: u64,
    },
    #[error(
        "{file}: block {expected} is missing: the block at byte offset {offset} is block {found}; the log was cut or spliced there"
    )]
    MissingBlock {
        file: String,
        expected: u32,
        found: u32,
        offset: u64,
    },
    #[error("{file}: malformed {what} at byte offset {offset}")]
    Malformed {
        file: String,
        what: String,
        offset: u64,
    },
    #[error("{file}: {message}")]
    Io { file: String, message: String },
}

/// One block as read from a log.
#[derive(Clone, Debug, PartialEq)]
pub enum Block {
    Records(Vec<LogRecord>),
    Checkpoint(CheckpointHeader, Vec<LogParticle>),
    /// Velocities set on the particles named (m/s).
    Velocities(SetHeader, Vec<(u64, [f64; 3])>),
    /// States set on the particles named (position, velocity, angular
    /// velocity, as in records).
    States(SetHeader, Vec<(u64, [f64; 9])>),
    /// The gas fields at a checkpoint of a gas run.
    Gas(Box<GasBlock>),
}

/// The gas fields of a gas run at a time (SI units), written with each
/// checkpoint: the payload of a gas block (bincode, as the header).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GasBlock {
    /// Absolute time (s).
    pub time: f64,
    /// Grid: lower corner (m), cell size (m), cells per axis, periodic
    /// axes, planar mode (as `crate::domain::grid::GridGeometry`).
    pub lo: DVec3,
    pub h: DVec3,
    pub n: [u64; 3],
    pub periodic: [bool; 3],
    pub planar: bool,
    /// Per cell: gas fraction, pressure (Pa), density (kg/m³).
    pub gas_fraction: Vec<f64>,
    pub pressure: Vec<f64>,
    pub density: Vec<f64>,
    /// Interstitial velocity normal to the faces of each axis (m/s).
    pub velocity: [Vec<f64>; 3],
}

/// When the values of a velocities or states block apply: absolute time
/// and engine clock (s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SetHeader {
    pub time: f64,
    pub clock: f64,
}

/// Reads a log sequentially, block by block through one reused buffer.
/// Blocks are verified against their checksums.
pub struct LogReader {
    name: String,
    file: std::io::BufReader<std::fs::File>,
    /// File length (bytes).
    len: u64,
    /// Byte offset of the next block.
    offset: u64,
    buf: Vec<u8>,
    pub header: LogHeader,
    /// Where the reader stopped because the file ended inside a block
    /// (a truncated log), if it did.
    pub truncated_at: Option<u64>,
    /// A record buffer handed back by [`LogReader::recycle`].
    spare: Vec<LogRecord>,
    /// Sequence number the next block must carry.
    next_seq: u32,
    /// The end block, once read: the log is complete.
    pub end: Option<LogEnd>,
}

impl LogReader {
    /// Opens a log and checks its magic, version and header checksum.
    pub fn open(path: &Path) -> Result<LogReader, LogError> {
        use std::io::Read;
        let name = path.display().to_string();
        let io = |e: std::io::Error| LogError::Io {
            file: name.clone(),
            message: e.to_string(),
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut file = std::io::BufReader::with_capacity(1 << 16, file);
        let mut fixed = [0u8; FILE_HEADER_BYTES];
        if len < FILE_HEADER_BYTES as u64
            || file.read_exact(&mut fixed).is_err()
            || fixed[0..8] != FILE_MAGIC
        {
            return Err(LogError::NotALog { file: name });
        }
        let word = |at: usize| u32::from_le_bytes(fixed[at..at + 4].try_into().expect("4 bytes"));
        let version = word(8);
        if version == 1 {
            return Err(LogError::OldVersion { file: name });
        }
        if !(OLDEST_READ_VERSION..=FORMAT_VERSION).contains(&version) {
            return Err(LogError::Version {
                file: name,
                found: version,
            });
        }
        let header_len = word(12) as u64;
        if len < FILE_HEADER_BYTES as u64 + header_len {
            return Err(LogError::Malformed {
                file: name,
                what: "file header (truncated)".into(),
                offset: 0,
            });
        }
        let mut payload = vec![0u8; header_len as usize];
        file.read_exact(&mut payload).map_err(io)?;
        if crc32fast::hash(&payload) != word(16) {
            return Err(LogError::Checksum {
                file: name,
                what: "file header".into(),
                offset: FILE_HEADER_BYTES as u64,
            });
        }
        let header = decode_header(&payload).map_err(|_| LogError::Malformed {
            file: name.clone(),
            what: "file header".into(),
            offset: 0,
        })?;
        Ok(LogReader {
            name,
            file,
            len,
            offset: FILE_HEADER_BYTES as u64 + header_len,
            buf: Vec::new(),
            header,
            truncated_at: None,
            spare: Vec::new(),
            next_seq: 0,
            end: None,
        })
    }

    /// Bound on the particle ids of this log: every id is an initial
    /// particle's or was given by an insertion record, so it is below the
    /// initial count plus the number of records the file can hold.
    pub fn id_limit(&self) -> u64 {
        self.header.initial.len() as u64 + self.len / RECORD_BYTES as u64
    }

    /// Hands a block's record buffer back for reuse by the next block
    /// (saves a large allocation per block when replaying).
    pub fn recycle(&mut self, records: Vec<LogRecord>) {
        self.spare = records;
    }

    /// Byte offset of the next block.
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// Byte offsets and times of the checkpoint blocks from here on, found
    /// by reading block headers only (payloads are skipped, not verified;
    /// they are when read). Stops quietly at a damaged or truncated block;
    /// a block missing before it (a gap in the sequence numbers) is an
    /// error. The reader's position is left unchanged.
    pub fn checkpoint_index(&mut self) -> Result<Vec<(u64, f64)>, LogError> {
        use std::io::{Read, Seek, SeekFrom};
        let io = |e: std::io::Error| LogError::Io {
            file: self.name.clone(),
            message: e.to_string(),
        };
        let (start, start_seq) = (self.offset, self.next_seq);
        let mut at = start;
        let mut seq = start_seq;
        let mut index = Vec::new();
        while self.len - at >= BLOCK_HEADER_BYTES as u64 {
            let mut h = [0u8; BLOCK_HEADER_BYTES];
            self.file.seek(SeekFrom::Start(at)).map_err(io)?;
            self.file.read_exact(&mut h).map_err(io)?;
            let word = |k: usize| u32::from_le_bytes(h[k..k + 4].try_into().expect("4 bytes"));
            let len = word(12) as u64;
            if h[0..4] != BLOCK_MAGIC || self.len - at - (BLOCK_HEADER_BYTES as u64) < len {
                break;
            }
            if word(20) != seq {
                return Err(LogError::MissingBlock {
                    file: self.name.clone(),
                    expected: seq,
                    found: word(20),
                    offset: at,
                });
            }
            if word(4) == KIND_CHECKPOINT && len >= 8 {
                let mut t = [0u8; 8];
                self.file.read_exact(&mut t).map_err(io)?;
                index.push((at, f64::from_le_bytes(t)));
            }
            at += BLOCK_HEADER_BYTES as u64 + len;
            seq = seq.wrapping_add(1);
        }
        self.seek(start)?;
        self.next_seq = start_seq;
        Ok(index)
    }

    /// Continues reading at byte `offset`, which must be a block start
    /// (from [`LogReader::offset`] or [`LogReader::checkpoint_index`]);
    /// the block there sets the sequence number expected from then on.
    pub fn seek(&mut self, offset: u64) -> Result<(), LogError> {
        use std::io::{Read, Seek, SeekFrom};
        let io = |e: std::io::Error| LogError::Io {
            file: self.name.clone(),
            message: e.to_string(),
        };
        self.file.seek(SeekFrom::Start(offset)).map_err(io)?;
        self.offset = offset;
        if self.len.saturating_sub(offset) >= BLOCK_HEADER_BYTES as u64 {
            let mut h = [0u8; BLOCK_HEADER_BYTES];
            self.file.read_exact(&mut h).map_err(io)?;
            self.next_seq = u32::from_le_bytes(h[20..24].try_into().expect("4 bytes"));
            self.file.seek(SeekFrom::Start(offset)).map_err(io)?;
        }
        Ok(())
    }

    /// The next block, `Ok(None)` at the end of the file, after the end
    /// block (then `end` is set) or where a truncated block starts (then
    /// `truncated_at` is set).
    pub fn next_block(&mut self) -> Result<Option<Block>, LogError> {
        use std::io::Read;
        let start = self.offset;
        let rest = self.len - start;
        if rest == 0 || self.end.is_some() {
            return Ok(None);
        }
        if rest < BLOCK_HEADER_BYTES as u64 {
            self.truncated_at = Some(start);
            return Ok(None);
        }
        let io = |e: std::io::Error| LogError::Io {
            file: self.name.clone(),
            message: e.to_string(),
        };
        let malformed = |what: &str| LogError::Malformed {
            file: self.name.clone(),
            what: what.into(),
            offset: start,
        };
        let mut h = [0u8; BLOCK_HEADER_BYTES];
        self.file.read_exact(&mut h).map_err(io)?;
        let word = |at: usize| u32::from_le_bytes(h[at..at + 4].try_into().expect("4 bytes"));
        if h[0..4] != BLOCK_MAGIC {
            return Err(malformed("block header"));
        }
        let (kind, count, len, crc, seq) = (
            word(4),
            word(8) as usize,
            word(12) as usize,
            word(16),
            word(20),
        );
        // The block header has no checksum of its own: check that kind,
        // count and length agree before taking a short file for truncation,
        // so that a damaged length is reported, not silently cut.
        let consistent = match kind {
            KIND_RECORDS => len == count * RECORD_BYTES,
            KIND_CHECKPOINT => len == CHECKPOINT_HEADER_BYTES + count * PARTICLE_BYTES,
            KIND_END => len == END_BYTES && count == 0,
            KIND_VELOCITIES => len == SET_HEADER_BYTES + count * VELOCITY_ENTRY_BYTES,
            KIND_STATES => len == SET_HEADER_BYTES + count * STATE_ENTRY_BYTES,
            // Its cells times the cell fields, at least.
            KIND_GAS => len >= count * 3 * 8,
            _ => false,
        };
        if !consistent {
            return Err(malformed("block header (kind, count and length disagree)"));
        }
        if rest - (BLOCK_HEADER_BYTES as u64) < len as u64 {
            self.truncated_at = Some(start);
            return Ok(None);
        }
        self.buf.resize(len, 0);
        self.file.read_exact(&mut self.buf).map_err(io)?;
        let payload = &self.buf[..];
        if block_crc(&h, payload) != crc {
            return Err(LogError::Checksum {
                file: self.name.clone(),
                what: "block".into(),
                offset: start,
            });
        }
        if seq != self.next_seq {
            return Err(LogError::MissingBlock {
                file: self.name.clone(),
                expected: self.next_seq,
                found: seq,
                offset: start,
            });
        }
        self.next_seq = seq.wrapping_add(1);
        let next = start + (BLOCK_HEADER_BYTES + len) as u64;
        if kind == KIND_END {
            if next != self.len {
                return Err(LogError::Malformed {
                    file: self.name.clone(),
                    what: format!("log: {} bytes after the end block", self.len - next),
                    offset: next,
                });
            }
            let f = |at: usize| payload[at..at + 8].try_into().expect("8 bytes");
            self.end = Some(LogEnd {
                records: u64::from_le_bytes(f(0)),
                time: f64::from_le_bytes(f(8)),
            });
            self.offset = next;
            return Ok(None);
        }
        let block = match kind {
            KIND_RECORDS => {
                let mut records = std::mem::take(&mut self.spare);
                records.clear();
                records.extend(payload.chunks_exact(RECORD_BYTES).map(LogRecord::decode));
                Block::Records(records)
            }
            KIND_GAS => {
                let g: GasBlock = crate::io::container::decode_bounded(payload)
                    .map(|(g, _)| g)
                    .map_err(|_| malformed("gas block"))?;
                if g.gas_fraction.len() != count {
                    return Err(malformed("gas block (cell count)"));
                }
                Block::Gas(Box::new(g))
            }
            KIND_VELOCITIES | KIND_STATES => {
                let f = |b: &[u8], at: usize| {
                    f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
                };
                let h = SetHeader {
                    time: f(payload, 0),
                    clock: f(payload, 8),
                };
                let entries = &payload[SET_HEADER_BYTES..];
                let id = |e: &[u8]| u64::from_le_bytes(e[..8].try_into().expect("8 bytes"));
                if kind == KIND_VELOCITIES {
                    let v = entries
                        .chunks_exact(VELOCITY_ENTRY_BYTES)
                        .map(|e| (id(e), std::array::from_fn(|k| f(e, 8 + 8 * k))))
                        .collect();
                    Block::Velocities(h, v)
                } else {
                    let v = entries
                        .chunks_exact(STATE_ENTRY_BYTES)
                        .map(|e| (id(e), std::array::from_fn(|k| f(e, 8 + 8 * k))))
                        .collect();
                    Block::States(h, v)
                }
            }
            _ => {
                let (ch, _): (CheckpointHeader, usize) = bincode::serde::decode_from_slice(
                    &payload[..CHECKPOINT_HEADER_BYTES],
                    config(),
                )
                .map_err(|_| malformed("checkpoint"))?;
                let mut particles = Vec::with_capacity(count);
                for chunk in payload[CHECKPOINT_HEADER_BYTES..].chunks_exact(PARTICLE_BYTES) {
                    let (p, _): (LogParticle, usize) =
                        bincode::serde::decode_from_slice(chunk, config())
                            .map_err(|_| malformed("checkpoint"))?;
                    particles.push(p);
                }
                Block::Checkpoint(ch, particles)
            }
        };
        self.offset = next;
        Ok(Some(block))
    }
}

/// One particle of a replayed state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplayParticle {
    pub radius: f64,
    pub material: u32,
    pub state: State,
    /// Engine clock the state refers to (s).
    pub clock: f64,
}

/// The trajectory rebuilt from records alone: no scheduler, no forces.
#[derive(Clone, Debug)]
pub struct Replay {
    /// Particles indexed by id (ids are dense: 0, 1, 2, … in insertion order).
    particles: Vec<Option<ReplayParticle>>,
    /// Number of particles present.
    count: usize,
    /// Absolute time at which the current flow step started (s).
    pub origin: f64,
    /// Flow steps completed.
    pub step: u64,
    /// Absolute time of the last record applied (s).
    pub time: f64,
    /// Ids must stay below this (see [`LogReader::id_limit`]): a damaged or
    /// forged id cannot make the id-indexed table allocate without bound.
    id_limit: u64,
    /// Number of materials in the header: particle materials index them.
    materials: usize,
}

impl Replay {
    /// The state at time 0 from the header; particle ids must be below
    /// `id_limit` ([`LogReader::id_limit`] for a log being read).
    pub fn start(header: &LogHeader, id_limit: u64) -> Result<Replay, String> {
        let mut replay = Replay {
            particles: Vec::new(),
            count: 0,
            origin: 0.0,
            step: 0,
            time: 0.0,
            id_limit,
            materials: header.densities.len(),
        };
        for (id, p) in &header.initial {
            let state = State {
                pos: p.pos,
                vel: p.vel,
                omega: p.omega,
            };
            replay.insert(
                *id,
                ReplayParticle {
                    radius: p.radius,
                    material: p.material as u32,
                    state,
                    clock: 0.0,
                },
            )?;
        }
        Ok(replay)
    }

    /// Number of particles present.
    pub fn len(&self) -> usize {
        self.count
    }

    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The particle with this id, if present.
    pub fn get(&self, id: u64) -> Option<&ReplayParticle> {
        self.particles.get(id as usize).and_then(Option::as_ref)
    }

    /// Present particles with their ids, in id order.
    pub fn iter(&self) -> impl Iterator<Item = (u64, &ReplayParticle)> + '_ {
        self.particles
            .iter()
            .enumerate()
            .filter_map(|(id, p)| p.as_ref().map(|p| (id as u64, p)))
    }

    fn insert(&mut self, id: u64, p: ReplayParticle) -> Result<(), String> {
        if p.material as usize >= self.materials {
            return Err(format!(
                "particle {id} has material {}, but the header lists {} materials",
                p.material, self.materials
            ));
        }
        if id >= self.id_limit {
            return Err(format!(
                "particle id {id} is beyond the {} ids this log can hold (initial particles plus one per record)",
                self.id_limit
            ));
        }
        let k = id as usize;
        if k >= self.particles.len() {
            self.particles.resize(k + 1, None);
        }
        if self.particles[k].replace(p).is_none() {
            self.count += 1;
        }
        Ok(())
    }

    /// Applies one record, exactly as the engine changed its state.
    pub fn apply(&mut self, r: &LogRecord) -> Result<(), String> {
        let mut set = |id: u64, s: &[f64; 9]| match self
            .particles
            .get_mut(id as usize)
            .and_then(Option::as_mut)
        {
            Some(p) => {
                p.state = array_state(s);
                p.clock = r.clock;
                Ok(())
            }
            None => Err(format!(
                "record at time {} names unknown particle {id}",
                r.time
            )),
        };
        match r.kind {
            k if k == RecordKind::Pair as u32 => {
                set(r.a, &r.state_a)?;
                set(r.b, &r.state_b)?;
            }
            k if k == RecordKind::Wall as u32 && r.b >= 6 => {
                return Err(format!(
                    "wall record at time {} names face {}; faces are 0..5",
                    r.time, r.b
                ));
            }
            k if k == RecordKind::Wall as u32 || k == RecordKind::Wrap as u32 => {
                set(r.a, &r.state_a)?
            }
            k if k == RecordKind::Insert as u32 => {
                let p = ReplayParticle {
                    radius: r.state_b[0],
                    material: r.aux,
                    state: array_state(&r.state_a),
                    clock: r.clock,
                };
                self.insert(r.a, p)
                    .map_err(|e| format!("record at time {}: {e}", r.time))?;
            }
            k if k == RecordKind::Remove as u32 => {
                match self.particles.get_mut(r.a as usize).and_then(Option::take) {
                    Some(_) => self.count -= 1,
                    None => return Err(format!("removal of unknown particle {}", r.a)),
                }
            }
            k if k == RecordKind::FlowStepEnd as u32 => {
                for p in self.particles.iter_mut().flatten() {
                    p.state.pos += p.state.vel * (r.clock - p.clock);
                    p.clock = 0.0;
                }
                self.origin = r.time;
                self.step += 1;
            }
            k if k == RecordKind::Kick as u32 => {
                let dv = DVec3::new(r.state_a[0], r.state_a[1], r.state_a[2]);
                for p in self.particles.iter_mut().flatten() {
                    p.state.vel += dv;
                }
            }
            k => return Err(format!("unknown record kind {k} at time {}", r.time)),
        }
        self.time = r.time;
        Ok(())
    }

    /// Applies a velocities block: sets the velocity of each particle
    /// named (positions and clocks unchanged: the engine kicks without
    /// moving).
    pub fn set_velocities(&mut self, h: &SetHeader, v: &[(u64, [f64; 3])]) -> Result<(), String> {
        for &(id, vel) in v {
            match self.particles.get_mut(id as usize).and_then(Option::as_mut) {
                Some(p) => p.state.vel = DVec3::from_array(vel),
                None => {
                    return Err(format!(
                        "velocities block at time {} names unknown particle {id}",
                        h.time
                    ));
                }
            }
        }
        self.time = h.time;
        Ok(())
    }

    /// Applies a states block: sets the state of each particle named, at
    /// the block's clock.
    pub fn set_states(&mut self, h: &SetHeader, v: &[(u64, [f64; 9])]) -> Result<(), String> {
        for (id, s) in v {
            match self
                .particles
                .get_mut(*id as usize)
                .and_then(Option::as_mut)
            {
                Some(p) => {
                    p.state = array_state(s);
                    p.clock = h.clock;
                }
                None => {
                    return Err(format!(
                        "states block at time {} names unknown particle {id}",
                        h.time
                    ));
                }
            }
        }
        self.time = h.time;
        Ok(())
    }

    /// Replaces the state by a checkpoint's.
    pub fn load_checkpoint(
        &mut self,
        h: &CheckpointHeader,
        particles: &[LogParticle],
    ) -> Result<(), String> {
        self.particles.clear();
        self.count = 0;
        for p in particles {
            let rp = ReplayParticle {
                radius: p.radius,
                material: p.material,
                state: array_state(&p.state),
                clock: h.clock,
            };
            self.insert(p.id, rp)
                .map_err(|e| format!("checkpoint at time {}: {e}", h.time))?;
        }
        self.origin = h.time - h.clock;
        self.step = h.step;
        self.time = h.time;
        Ok(())
    }

    /// First difference from a checkpoint, or `None` when bit-identical.
    pub fn compare(&self, particles: &[LogParticle]) -> Option<String> {
        if particles.len() != self.count {
            return Some(format!(
                "{} particles replayed, {} in the checkpoint",
                self.count,
                particles.len()
            ));
        }
        for p in particles {
            let Some(r) = self.get(p.id) else {
                return Some(format!("particle {} is missing from the replay", p.id));
            };
            let replayed = state_array(&r.state);
            for (k, (a, b)) in replayed.iter().zip(&p.state).enumerate() {
                if a.to_bits() != b.to_bits() {
                    let names = ["x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz"];
                    return Some(format!(
                        "particle {} {}: replayed {a:e}, checkpoint {b:e}",
                        p.id, names[k]
                    ));
                }
            }
        }
        None
    }

    /// Positions at absolute time `t` within the current flow step, in id
    /// order.
    pub fn positions_at(&self, t: f64) -> Vec<(u64, ReplayParticle)> {
        let clock = t - self.origin;
        self.iter()
            .map(|(id, p)| {
                let mut q = *p;
                q.state.pos += p.state.vel * (clock - p.clock);
                q.clock = clock;
                (id, q)
            })
            .collect()
    }
}

/// Checkpoint particles from engine views (slot order).
pub fn checkpoint_particles<'a>(
    views: impl Iterator<Item = crate::engine::ParticleView> + 'a,
) -> Vec<LogParticle> {
    views
        .map(|p| LogParticle {
            id: p.id,
            material: p.material as u32,
            reserved: 0,
            radius: p.radius,
            state: state_array(&State {
                pos: p.pos,
                vel: p.vel,
                omega: p.omega,
            }),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_and_particles_have_their_documented_fixed_sizes() {
        let r = LogRecord {
            kind: 1,
            aux: 2,
            time: 1.5,
            clock: 0.5,
            a: 7,
            b: 9,
            state_a: [1.0; 9],
            state_b: [-2.0; 9],
        };
        let bytes = bincode::serde::encode_to_vec(r, config()).unwrap();
        assert_eq!(bytes.len(), RECORD_BYTES);
        // Little-endian fields at fixed offsets: kind at 0, time at 8, a at 24.
        assert_eq!(&bytes[0..4], &1u32.to_le_bytes());
        assert_eq!(&bytes[8..16], &1.5f64.to_le_bytes());
        assert_eq!(&bytes[24..32], &7u64.to_le_bytes());
        assert_eq!(&bytes[40..48], &1.0f64.to_le_bytes());
        let p = LogParticle {
            id: 3,
            material: 1,
            reserved: 0,
            radius: 0.5,
            state: [0.0; 9],
        };
        assert_eq!(
            bincode::serde::encode_to_vec(p, config()).unwrap().len(),
            PARTICLE_BYTES
        );
        let h = CheckpointHeader {
            time: 1.0,
            clock: 0.0,
            step: 4,
        };
        assert_eq!(
            bincode::serde::encode_to_vec(h, config()).unwrap().len(),
            CHECKPOINT_HEADER_BYTES
        );
    }
}
