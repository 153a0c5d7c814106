//! Result files: atomic writes, CSV tables and checkpoints.

use std::io::Write;
use std::path::Path;

use anyhow::Context;

use crate::io::container::{self, Kind};
use crate::particles::NewParticle;

/// Writes `bytes` to `path` atomically: to a temporary file in the same
/// directory, flushed to disk, then renamed over `path`. A crash leaves
/// either the old file or the new one, never a partial file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let name = path.file_name().context("output path has no file name")?;
    let tmp = dir.join(format!(".{}.tmp", name.to_string_lossy()));
    let mut f =
        std::fs::File::create(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    f.write_all(bytes)
        .with_context(|| format!("writing {}", tmp.display()))?;
    f.sync_all()
        .with_context(|| format!("flushing {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
    Ok(())
}

/// Files written on a thread of their own (each with [`write_atomic`] or
/// its like), so that a run does not wait for encoding and the disk:
/// jobs run one at a time in the order given. At most
/// [`BackgroundWriter::PENDING`] wait; [`BackgroundWriter::submit`] blocks
/// beyond. The first failure stops the writer and is returned by the next
/// `submit` or by [`BackgroundWriter::finish`]. Dropped unfinished, it
/// still completes the jobs given (errors then go unreported).
pub struct BackgroundWriter {
    /// The thread's name, for messages.
    name: String,
    jobs: Option<std::sync::mpsc::SyncSender<WriteJob>>,
    thread: Option<std::thread::JoinHandle<anyhow::Result<()>>>,
}

type WriteJob = Box<dyn FnOnce() -> anyhow::Result<()> + Send>;

impl BackgroundWriter {
    /// Jobs that may wait while one is written.
    pub const PENDING: usize = 2;

    /// A writer on a new thread named `name`.
    pub fn new(name: &str) -> anyhow::Result<Self> {
        let (jobs, queue) = std::sync::mpsc::sync_channel::<WriteJob>(Self::PENDING);
        let thread = std::thread::Builder::new()
            .name(name.to_string())
            .spawn(move || queue.into_iter().try_for_each(|job| job()))
            .with_context(|| format!("starting the {name} thread"))?;
        Ok(BackgroundWriter {
            name: name.to_string(),
            jobs: Some(jobs),
            thread: Some(thread),
        })
    }

    /// Queues `job`; an earlier job's failure instead, if there was one.
    pub fn submit(
        &mut self,
        job: impl FnOnce() -> anyhow::Result<()> + Send + 'static,
    ) -> anyhow::Result<()> {
        let sent = self.jobs.as_ref().map(|q| q.send(Box::new(job)));
        match sent {
            Some(Ok(())) => Ok(()),
            // The thread stopped at a failure (or finish was called).
            _ => {
                self.finish()?;
                anyhow::bail!("the {} was finished before this file", self.name)
            }
        }
    }

    /// Waits for every job given; the first failure, if any.
    pub fn finish(&mut self) -> anyhow::Result<()> {
        self.jobs = None;
        match self.thread.take().map(std::thread::JoinHandle::join) {
            None => Ok(()),
            Some(Ok(written)) => written,
            Some(Err(_)) => anyhow::bail!("the {} thread panicked", self.name),
        }
    }
}

impl Drop for BackgroundWriter {
    fn drop(&mut self) {
        // Errors were someone else's to collect: finish was not called.
        let _ = self.finish();
    }
}

/// Columns that hold counts or indices, in every CSV edpm writes: their
/// values are written as integers (`500`, not `500.0`).
pub const INTEGER_COLUMNS: &[&str] = &[
    "id",
    "material",
    "point",
    "particles",
    "voids",
    "pair_collisions",
    "wall_collisions",
    "collapse_reports",
    "collisions",
    "altered_collisions",
    "cell",
    "i",
    "j",
    "k",
    "cells",
    "cells_used",
    "cells_skipped",
    "cell_samples_used",
    "cell_samples_skipped",
    "particles_used",
    "samples",
    "snapshots_used",
];

/// One CSV cell: integers (by column) without a fraction, other numbers
/// with full round-trip precision, and an empty cell where a value is
/// undefined (not finite: a ratio over no samples), as `null` in JSON;
/// spreadsheets, pandas and [`CsvColumns::read`] read it as missing.
pub fn csv_number(v: f64, integer: bool) -> String {
    if !v.is_finite() {
        String::new()
    } else if integer && v.fract() == 0.0 && v.abs() < 9.007e15 {
        format!("{}", v as i64)
    } else {
        format!("{v:?}")
    }
}

/// A CSV table built in memory and written atomically.
#[derive(Clone, Debug, Default)]
pub struct CsvTable {
    text: String,
    /// Whether each column is one of [`INTEGER_COLUMNS`].
    integer: Vec<bool>,
}

impl CsvTable {
    pub fn new(header: &[&str]) -> Self {
        CsvTable {
            text: header.join(",") + "\n",
            integer: header.iter().map(|h| INTEGER_COLUMNS.contains(h)).collect(),
        }
    }

    /// Appends one row; floats are written with full round-trip precision,
    /// counts as integers.
    pub fn row(&mut self, values: &[f64]) {
        self.push_cells(values, 0);
    }

    /// Appends one row whose first column is the text `label` (commas,
    /// quotes and line breaks in it become `_`), then `values`.
    pub fn labelled_row(&mut self, label: &str, values: &[f64]) {
        self.text.push_str(&label.replace([',', '"', '\n'], "_"));
        self.text.push(',');
        self.push_cells(values, 1);
    }

    /// Appends `values` as the columns from `first` on, and ends the row.
    fn push_cells(&mut self, values: &[f64], first: usize) {
        self.text
            .push_str(&csv_cells(values, self.integer.get(first..).unwrap_or(&[])));
    }

    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        write_atomic(path, self.text.as_bytes())
    }
}

/// `values` as CSV cells ([`csv_number`]; `integer[c]` for column `c`),
/// ending the line.
fn csv_cells(values: &[f64], integer: &[bool]) -> String {
    let cells: Vec<String> = values
        .iter()
        .enumerate()
        .map(|(c, &v)| csv_number(v, integer.get(c) == Some(&true)))
        .collect();
    cells.join(",") + "\n"
}

/// A CSV file written row by row as a run goes: each line goes to the
/// file in one `write` call, so a killed run leaves whole lines only (up
/// to the last row written).
pub struct CsvStream {
    path: std::path::PathBuf,
    file: std::fs::File,
    /// Whether each column is one of [`INTEGER_COLUMNS`].
    integer: Vec<bool>,
}

impl CsvStream {
    /// Creates (or truncates) `path` and writes the header line.
    pub fn create(path: &Path, header: &[&str]) -> anyhow::Result<CsvStream> {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut s = CsvStream {
            path: path.to_path_buf(),
            file,
            integer: header.iter().map(|h| INTEGER_COLUMNS.contains(h)).collect(),
        };
        s.write_line(&(header.join(",") + "\n"))?;
        Ok(s)
    }

    /// Appends one row, formatted as [`CsvTable::row`] does.
    pub fn row(&mut self, values: &[f64]) -> anyhow::Result<()> {
        let line = csv_cells(values, &self.integer);
        self.write_line(&line)
    }

    fn write_line(&mut self, line: &str) -> anyhow::Result<()> {
        self.file
            .write_all(line.as_bytes())
            .with_context(|| format!("writing {}", self.path.display()))
    }

    /// Flushes the file to disk (at the end of a run).
    pub fn sync(&mut self) -> anyhow::Result<()> {
        self.file
            .sync_all()
            .with_context(|| format!("flushing {}", self.path.display()))
    }
}

/// A numeric CSV file read back: its header and rows (cells that are not
/// numbers read as NaN).
#[derive(Clone, Debug, Default)]
pub struct CsvColumns {
    pub header: Vec<String>,
    pub rows: Vec<Vec<f64>>,
}

impl CsvColumns {
    pub fn read(path: &Path) -> anyhow::Result<CsvColumns> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut lines = text.lines();
        let header = lines
            .next()
            .unwrap_or_default()
            .split(',')
            .map(str::to_string)
            .collect();
        let rows = lines
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                l.split(',')
                    .map(|x| x.parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        Ok(CsvColumns { header, rows })
    }

    /// Index of the column named `name`.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }
}

/// Version of the checkpoint format: 2 put it in the checksummed
/// container (magic `EDPMCKPT`, docs/data-files.md).
pub const CHECKPOINT_VERSION: u32 = 2;

/// The container kind of checkpoints.
pub const CHECKPOINT_KIND: Kind = Kind {
    magic: *b"EDPMCKPT",
    what: "checkpoint",
    version: CHECKPOINT_VERSION,
    legacy_up_to: 1,
};

/// A full particle state, loadable with `[initial] checkpoint = ...`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Checkpoint {
    /// In the container header, not the payload: 0 for the checkpoints
    /// edpm writes (a state is the same whichever run reached it).
    #[serde(skip)]
    pub run_id: u64,
    pub version: u32,
    /// Simulation time of the state (s).
    pub time: f64,
    pub particles: Vec<NewParticle>,
}

impl Checkpoint {
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        write_atomic(
            path,
            &container::encode(&CHECKPOINT_KIND, self.run_id, self)?,
        )
    }

    pub fn read(path: &Path) -> anyhow::Result<Checkpoint> {
        let bytes = std::fs::read(path)
            .with_context(|| format!("reading checkpoint {}", path.display()))?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    /// Decodes a checkpoint file's bytes; `name` is used in messages. The
    /// particles are not checked here (the engine checks each one).
    pub fn from_bytes(bytes: &[u8], name: &str) -> anyhow::Result<Checkpoint> {
        let (header, mut cp): (_, Checkpoint) = container::decode(&CHECKPOINT_KIND, name, bytes)?;
        if cp.version != CHECKPOINT_VERSION {
            anyhow::bail!(
                "{name}: the payload says checkpoint version {}, the header {CHECKPOINT_VERSION}: the checkpoint is damaged",
                cp.version
            );
        }
        cp.run_id = header.run_id;
        Ok(cp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// The jobs run in the order given, all of them by `finish`, although
    /// the first ones are slow and the queue is full meanwhile.
    #[test]
    fn background_jobs_run_in_order_and_finish_waits() {
        let done = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let mut w = BackgroundWriter::new("test writer").unwrap();
        for i in 0..(3 * BackgroundWriter::PENDING) {
            let done = done.clone();
            w.submit(move || {
                if i < 2 {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                done.lock().unwrap().push(i);
                Ok(())
            })
            .unwrap();
        }
        w.finish().unwrap();
        let want: Vec<usize> = (0..3 * BackgroundWriter::PENDING).collect();
        assert_eq!(*done.lock().unwrap(), want);
    }

    /// A failed job stops the writer: its error comes back (from a later
    /// `submit` or from `finish`), and no later job runs.
    #[test]
    fn a_background_failure_is_reported_and_stops_the_writer() {
        let ran = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let mut w = BackgroundWriter::new("test writer").unwrap();
        w.submit(|| anyhow::bail!("disk full")).unwrap();
        let mut reported = None;
        for _ in 0..200 {
            let ran = ran.clone();
            let job = move || {
                ran.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                Ok(())
            };
            if let Err(e) = w.submit(job) {
                reported = Some(e);
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let e = reported.unwrap_or_else(|| w.finish().unwrap_err());
        assert!(e.to_string().contains("disk full"), "{e}");
        assert_eq!(ran.load(std::sync::atomic::Ordering::SeqCst), 0);
        // Finished: later files are refused, not lost in silence.
        assert!(w.submit(|| Ok(())).is_err());
    }

    #[test]
    fn counts_are_integers_and_other_numbers_round_trip() {
        let mut t = CsvTable::new(&["run", "time_s", "particles", "pair_collisions"]);
        t.labelled_row("ideal, 2D", &[0.1, 500.0, 3.0]);
        t.row(&[7.0, 1.0 / 3.0, 1e20, f64::NAN]);
        assert_eq!(
            t.text,
            "run,time_s,particles,pair_collisions\n\
             ideal_ 2D,0.1,500,3\n\
             7.0,0.3333333333333333,1e20,\n"
        );
    }

    #[test]
    fn checkpoint_round_trips_bit_for_bit_and_rejects_other_versions() {
        let dir = std::env::temp_dir().join(format!("edpm-cp-{}", std::process::id()));
        let path = dir.join("state.bin");
        let p = NewParticle {
            pos: DVec3::new(0.1, 1.0 / 3.0, -2.5e-7),
            vel: DVec3::new(f64::MIN_POSITIVE, 1e300, -0.0),
            omega: DVec3::splat(std::f64::consts::PI),
            radius: 1e-3,
            material: 3,
        };
        let cp = Checkpoint {
            run_id: 7,
            version: CHECKPOINT_VERSION,
            time: 0.25,
            particles: vec![p; 3],
        };
        cp.write(&path).unwrap();
        assert_eq!(Checkpoint::read(&path).unwrap(), cp);
        Checkpoint { version: 99, ..cp }.write(&path).unwrap();
        let err = Checkpoint::read(&path).unwrap_err().to_string();
        assert!(err.contains("payload says checkpoint version 99"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
