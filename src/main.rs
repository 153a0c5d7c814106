//! The `edpm` command line.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use edpm::bench::{self, BenchOptions};
use edpm::engine::{NeighbourSearch, Prefetch};
use edpm::queue::QueueKind;

#[derive(Parser)]
#[command(
    name = "edpm",
    version,
    about = "Event-driven hard-sphere discrete particle model"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scenario and write a summary and time series.
    Run {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// Output directory (default: out/<scenario name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// End time in seconds, overriding time.t_end.
        #[arg(long)]
        t_end: Option<f64>,
        /// Override any scenario key, e.g. --set collisions.default.e_n=0.8
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// No progress reports.
        #[arg(long)]
        quiet: bool,
        /// Wall time between progress lines when stderr is not a terminal
        /// (s, default 5); on a terminal a progress bar is shown instead.
        #[arg(long, value_name = "SECONDS")]
        progress_interval: Option<f64>,
        /// Write a binary event log of every collision (docs/event-log.md).
        #[arg(long, value_name = "FILE")]
        log: Option<PathBuf>,
        /// Full-state checkpoints in the log every this many flow steps
        /// (default: 10 per run).
        #[arg(long, value_name = "STEPS")]
        log_checkpoint_steps: Option<u64>,
        /// Continue from a restart file (restart.bin of an earlier run of
        /// the same scenario, [output] restart_interval) to t_end, bit for
        /// bit as the uninterrupted run (docs/data-files.md).
        #[arg(long, value_name = "FILE")]
        restart: Option<PathBuf>,
        /// Run into an output directory that holds an earlier run's
        /// outputs: edpm's own files there (summary, time series,
        /// snapshots, VTK, final state, analysis) are deleted first.
        /// Without it such a directory is refused.
        #[arg(long)]
        force: bool,
    },
    /// Validate a scenario: print it resolved (every default filled in,
    /// with units) on stdout, and particles, gas cells, flow steps, the
    /// memory estimate and the warnings on stderr.
    Check {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// End time in seconds, overriding time.t_end.
        #[arg(long)]
        t_end: Option<f64>,
        /// Override any scenario key, e.g. --set collisions.default.e_n=0.8
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
    },
    /// Run a scenario over a grid of --set values (KEY=V1,V2,...), one
    /// run per point in OUT/point-NNN, and tabulate each point's results
    /// in OUT/sweep.csv and OUT/sweep.md.
    Sweep {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// KEY=V1,V2,... sweeps KEY over the values (commas inside [...],
        /// {...} or quotes do not split); KEY=V fixes it for every point;
        /// {KEY2} in a value stands for the point's value of KEY2.
        #[arg(long = "set", value_name = "KEY=VALUES", required = true)]
        sets: Vec<String>,
        /// Output directory of the sweep.
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
        /// End time of every run (s), overriding time.t_end.
        #[arg(long)]
        t_end: Option<f64>,
        /// Runs at once (default: the number of cores).
        #[arg(long)]
        jobs: Option<usize>,
        /// Table columns: dotted paths into summary.json
        /// (counters.pair_collisions), FILE.csv:COLUMN for the time
        /// average of a column of the run's FILE.csv, FILE.csv:COLUMN:std
        /// for its standard deviation (default: particles,
        /// collisions, kinetic energy, CPU time, and the pressure drop of
        /// gas runs).
        #[arg(long, value_delimiter = ',')]
        columns: Vec<String>,
        /// Time averages of FILE.csv:COLUMN columns start here (s).
        #[arg(long, default_value_t = 0.0)]
        average_after: f64,
        /// Re-run points whose directories hold an earlier sweep's outputs.
        #[arg(long)]
        force: bool,
    },
    /// Rebuild a run from its event log alone.
    Replay {
        /// Event log written by `edpm run --log`.
        log: PathBuf,
        /// Write the state at this time (s) as CSV and VTK.
        #[arg(long, value_name = "SECONDS")]
        at: Option<f64>,
        /// Compare the replay with every checkpoint in the log, bit for bit.
        #[arg(long)]
        verify: bool,
        /// Collision statistics (frequency, impact angles and velocities,
        /// dissipation), printed and written as JSON and CSV.
        #[arg(long)]
        stats: bool,
        /// Output directory (default: the log's directory).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Statistics of a run's snapshots (velocity distributions, granular
    /// temperatures, profiles, heterogeneity, energy budget, KTGF test,
    /// segregation), written as CSV and JSON into RUN_DIR/analysis/.
    Analyse {
        /// Run directories written by `edpm run` with [output]
        /// snapshot_interval; with two or more, also a side-by-side
        /// comparison.
        #[arg(required = true)]
        run_dirs: Vec<PathBuf>,
        /// Directory of the comparison of several runs (default:
        /// `comparison/` beside the first run directory).
        #[arg(long, value_name = "DIR")]
        compare_out: Option<PathBuf>,
        /// Use only snapshots at t >= this time (s).
        #[arg(
            long,
            value_name = "SECONDS",
            default_value_t = 0.0,
            allow_negative_numbers = true
        )]
        t_start: f64,
        /// Analysis cell size (m); repeat or give a list (0.01,0.02) to show
        /// the cell-size dependence; the first is the primary grid
        /// (default: the run's tally or gas grid, else 5 diameters).
        #[arg(
            long = "cell-size",
            value_name = "METRES",
            value_delimiter = ',',
            allow_negative_numbers = true
        )]
        cell_size: Vec<f64>,
        /// Cells with fewer particles are skipped in the velocity statistics
        /// and the KTGF test.
        #[arg(long, value_name = "N", default_value_t = 10)]
        min_per_cell: usize,
        /// Tally cells with fewer pair collisions in an interval are skipped
        /// in the KTGF test.
        #[arg(long, value_name = "N", default_value_t = 10)]
        min_collisions: u64,
        /// Histogram bins.
        #[arg(long, value_name = "N", default_value_t = 50)]
        bins: usize,
        /// Heights (m above the box bottom) of the lateral profiles
        /// (default: 5 evenly spaced).
        #[arg(
            long,
            value_name = "METRES",
            value_delimiter = ',',
            allow_negative_numbers = true
        )]
        heights: Vec<f64>,
    },
    /// Redraw every figure of an analysis directory from its CSV files
    /// (docs/figures.md).
    Figures {
        /// RUN_DIR/analysis, or any directory holding its CSV files.
        dir: PathBuf,
        /// Title prefix (default: the run directory's name).
        #[arg(long)]
        title: Option<String>,
    },
    /// Fit the minimum fluidization velocity to an `edpm sweep` of the
    /// inflow velocity (results/fluidization/README.md) and compare it
    /// with Ergun and Wen–Yu; prints a Markdown report.
    Umf {
        /// The sweep's out directory (sweep.csv and one directory per point).
        sweep: PathBuf,
        /// The swept scenario (its gas, box and particle material).
        #[arg(long, default_value = "scenarios/fluidized-bed.toml")]
        scenario: PathBuf,
        /// Also write the report to this file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Run the validation catalogue (docs/validation.md): each case
    /// against its reference; writes report.md, report.json and figures,
    /// and fails if a case fails.
    Validate(ValidateArgs),
    /// Elastic smooth spheres in a periodic cube; prints one JSON line.
    Bench {
        /// Particle count (rounded to 4 k³ for the FCC start).
        #[arg(long, default_value_t = 10976)]
        n: usize,
        /// Packing fraction.
        #[arg(long, default_value_t = 0.3)]
        phi: f64,
        /// Collisions per particle to equilibrate.
        #[arg(long, default_value_t = 20.0)]
        equilibrate: f64,
        /// Collisions per particle to measure.
        #[arg(long, default_value_t = 50.0)]
        measure: f64,
        /// Flow step (in mean free times) at which every particle is
        /// synchronised and re-predicted, as in a coupled run.
        #[arg(long)]
        flow_step: Option<f64>,
        /// The kicks at each flow step (zero velocity changes): one for
        /// all, whose kept pairs survive, or one per particle, as the gas
        /// coupling gives, after which every pair is tested again up to
        /// the next flow step.
        #[arg(long, value_enum, default_value = "uniform")]
        kicks: KicksArg,
        /// Neighbour-shell thickness in diameters (lists only).
        #[arg(long, default_value_t = bench::DEFAULT_SKIN)]
        skin: f64,
        #[arg(long, value_enum, default_value = "calendar")]
        queue: QueueArg,
        /// Neighbour search: per-particle lists, cells, or `auto`, the rule
        /// of `edpm run` (cells below a packing fraction of 0.325).
        #[arg(long, value_enum, default_value = "auto")]
        neighbours: NeighbourArg,
        /// Whether partner searches batch their candidates and prefetch
        /// their records: `auto` where the particles' kinematics (64 bytes
        /// each) outgrow the L2 cache; results are the
        /// same bit for bit either way.
        #[arg(long, value_enum, default_value = "auto")]
        prefetch: PrefetchArg,
        /// Initial state: an FCC lattice, a fluid melted at phi = 0.45 and
        /// compressed, or `auto` (the lattice below phi = 0.46, where it
        /// melts during equilibration; compressed above).
        #[arg(long, value_enum, default_value = "auto")]
        start: StartArg,
        /// Renumber particles in cell order every this many collisions per
        /// particle, for memory locality (0: never).
        #[arg(long, default_value_t = 20.0)]
        reorder_every: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum NeighbourArg {
    Auto,
    Lists,
    Cells,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum KicksArg {
    Uniform,
    PerParticle,
}

impl From<KicksArg> for bench::FlowKicks {
    fn from(k: KicksArg) -> Self {
        match k {
            KicksArg::Uniform => bench::FlowKicks::Uniform,
            KicksArg::PerParticle => bench::FlowKicks::PerParticle,
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum StartArg {
    Auto,
    Lattice,
    Compressed,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum PrefetchArg {
    Auto,
    Always,
    Never,
}

impl From<PrefetchArg> for Prefetch {
    fn from(p: PrefetchArg) -> Self {
        match p {
            PrefetchArg::Auto => Prefetch::Auto,
            PrefetchArg::Always => Prefetch::Always,
            PrefetchArg::Never => Prefetch::Never,
        }
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum QueueArg {
    IndexedHeap,
    Calendar,
    Reference,
}

impl From<QueueArg> for QueueKind {
    fn from(q: QueueArg) -> Self {
        match q {
            QueueArg::IndexedHeap => QueueKind::IndexedHeap,
            QueueArg::Calendar => QueueKind::Calendar,
            QueueArg::Reference => QueueKind::Reference,
        }
    }
}

impl NeighbourArg {
    /// The neighbour search asked for; `None`: the rule of `edpm run`.
    fn search(self) -> Option<NeighbourSearch> {
        match self {
            NeighbourArg::Auto => None,
            NeighbourArg::Lists => Some(NeighbourSearch::Lists),
            NeighbourArg::Cells => Some(NeighbourSearch::Cells),
        }
    }
}

impl From<StartArg> for bench::Start {
    fn from(s: StartArg) -> Self {
        match s {
            StartArg::Auto => bench::Start::Auto,
            StartArg::Lattice => bench::Start::Lattice,
            StartArg::Compressed => bench::Start::Compressed,
        }
    }
}

/// `edpm sweep` without --jobs: one run per core.
fn default_jobs() -> usize {
    std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
}

/// `edpm validate --quick` or the full catalogue.
fn validate_mode(quick: bool) -> edpm::validate::Mode {
    if quick {
        edpm::validate::Mode::Quick
    } else {
        edpm::validate::Mode::Full
    }
}

/// `edpm bench`: checks the options, runs the benchmark and prints its
/// result as one JSON line (with a warning when the fluid crystallised).
fn bench_cli(opts: &BenchOptions) -> anyhow::Result<()> {
    bench::check_options(opts).map_err(|msg| anyhow::anyhow!("{msg}"))?;
    let r = bench::run(opts)
        .map_err(|e| anyhow::anyhow!("bench: the engine refused the start: {e}"))?;
    if r.peak_rss_bytes.is_none() {
        eprintln!("edpm: peak resident set size: not available (no /proc/self/status)");
    }
    if r.solid_fraction > bench::CRYSTAL_WARNING_FRACTION {
        eprintln!(
            "edpm: warning: {:.0} % of the particles are solid-like at the end: \
             the pressure is not the fluid's (try --start compressed)",
            100.0 * r.solid_fraction
        );
    }
    println!(
        "{}",
        serde_json::to_string(&r).expect("bench result serialises")
    );
    Ok(())
}

/// Arguments of `edpm validate`.
#[derive(clap::Args)]
struct ValidateArgs {
    /// Cases to run, by name (default: all; --list shows them).
    cases: Vec<String>,
    /// Reduced version of every case (a few minutes of CPU).
    #[arg(long)]
    quick: bool,
    /// Report directory.
    #[arg(long, default_value = "out/validate")]
    out: PathBuf,
    /// List the cases and exit.
    #[arg(long)]
    list: bool,
    /// Multiply every tolerance (for testing the exit status).
    #[arg(long, default_value_t = 1.0, hide = true)]
    tolerance_scale: f64,
    /// Instead of the catalogue: run time against error for one
    /// numerical knob (or `all`), tables and charts into --out
    /// (results/accuracy/README.md).
    #[arg(long, value_name = "KNOB", conflicts_with = "stress")]
    accuracy: Option<String>,
    /// Instead of the catalogue: the stability suite (CASES: setups
    /// to run; --quick leaves out the run of 1e8 events); stress.md
    /// and stress.json into --out.
    #[arg(long)]
    stress: bool,
}

/// `edpm validate`: the catalogue, or `--accuracy KNOB`, or `--stress`.
fn validate_command(a: ValidateArgs) -> anyhow::Result<()> {
    let mode = validate_mode(a.quick);
    if let Some(knob) = a.accuracy {
        return edpm::validate::accuracy::accuracy_cli(&knob, &a.out);
    }
    if a.stress {
        return edpm::validate::stress::stress_cli(&a.cases, mode, &a.out);
    }
    edpm::validate::validate_cli(&edpm::validate::ValidateOptions {
        cases: a.cases,
        mode,
        out: a.out,
        list: a.list,
        tolerance_scale: a.tolerance_scale,
    })
}

/// Stack of each worker thread, bytes: the main thread's usual 8 MiB, since
/// the whole command runs on a worker.
const WORKER_STACK_BYTES: usize = 8 << 20;

/// Runs `work` on a worker of a rayon pool (`RAYON_NUM_THREADS` threads), so
/// that the parallel loops of every flow step start on a thread that is
/// already awake. Called from the main thread, each loop would hand its work
/// to the pool and sleep until it is done: on one thread that round trip
/// through the kernel took about a tenth of the jet bed's time
/// (results/benchmarks.md, "fourth session").
fn on_worker_thread<T: Send>(work: impl FnOnce() -> T + Send) -> anyhow::Result<T> {
    // Parsed as rayon parses it (no trimming); empty counts as unset.
    if let Ok(text) = std::env::var("RAYON_NUM_THREADS")
        && !text.is_empty()
    {
        let cpus = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
        let most = (MAX_THREADS_PER_CPU * cpus).max(MAX_THREADS_ANY_MACHINE);
        match text.parse::<usize>() {
            Ok(n) if n <= most => {}
            _ => anyhow::bail!(
                "RAYON_NUM_THREADS={text:?}: must be a thread count in 0..={most} on this machine (0 means one per CPU)"
            ),
        }
    }
    Ok(
        match rayon::ThreadPoolBuilder::new()
            .stack_size(WORKER_STACK_BYTES)
            .build()
        {
            Ok(pool) => pool.install(work),
            Err(_) => work(),
        },
    )
}

/// Most threads `RAYON_NUM_THREADS` may ask for: 16 per CPU, and 256 on
/// any machine (to test thread-count independence on a small one). More
/// only adds threads that wait: 100000 of them took minutes to start a
/// 5 ms run.
const MAX_THREADS_PER_CPU: usize = 16;
const MAX_THREADS_ANY_MACHINE: usize = 256;

/// Parses the command line and runs the subcommand on a worker thread.
fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = on_worker_thread(|| dispatch(cli.command)).and_then(|r| r);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("edpm: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Turns each subcommand's arguments into the library's options and runs it.
fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Run {
            scenario,
            out,
            t_end,
            overrides,
            quiet,
            progress_interval,
            log,
            log_checkpoint_steps,
            restart,
            force,
        } => {
            let opts = edpm::run::RunOptions {
                progress: !quiet,
                progress_interval,
                log,
                log_checkpoint_steps,
                restart,
                force,
            };
            edpm::run::run_cli(&scenario, out.as_deref(), t_end, &overrides, &opts)
        }
        Command::Check {
            scenario,
            t_end,
            overrides,
        } => edpm::check::check_cli(&scenario, t_end, &overrides),
        Command::Sweep {
            scenario,
            sets,
            out,
            t_end,
            jobs,
            columns,
            average_after,
            force,
        } => edpm::sweep::sweep_cli(
            &scenario,
            &edpm::sweep::SweepOptions {
                sets,
                out,
                t_end,
                jobs: jobs.unwrap_or_else(default_jobs),
                columns,
                average_after,
                force,
            },
        ),
        Command::Replay {
            log,
            at,
            verify,
            stats,
            out,
        } => edpm::replay::replay_cli(
            &log,
            &edpm::replay::ReplayOptions {
                at,
                verify,
                stats,
                out,
            },
        ),
        Command::Analyse {
            run_dirs,
            compare_out,
            t_start,
            cell_size,
            min_per_cell,
            min_collisions,
            bins,
            heights,
        } => edpm::analysis::analyse_cli(
            &run_dirs,
            &edpm::analysis::AnalyseOptions {
                t_start,
                cell_sizes: cell_size,
                min_per_cell,
                bins,
                heights,
                min_collisions,
            },
            compare_out.as_deref(),
        ),
        Command::Validate(args) => validate_command(args),
        Command::Umf {
            sweep,
            scenario,
            out,
        } => edpm::analysis::fluidization::umf_cli(&sweep, &scenario, out.as_deref()),
        Command::Figures { dir, title } => edpm::analysis::figures_cli(&dir, title.as_deref()),
        Command::Bench {
            n,
            phi,
            equilibrate,
            measure,
            flow_step,
            kicks,
            skin,
            queue,
            neighbours,
            prefetch,
            start,
            reorder_every,
            seed,
        } => bench_cli(&BenchOptions {
            n,
            phi,
            equilibrate,
            measure,
            flow_step,
            kicks: kicks.into(),
            skin,
            queue: queue.into(),
            neighbours: neighbours.search(),
            prefetch: prefetch.into(),
            start: start.into(),
            reorder_every,
            seed,
        }),
    }
}
