#!/usr/bin/env python3
"""Run time against accuracy for the gas-coupled speed anchor.

Runs scenarios/bubbling-bed-jet.toml (or another scenario) at several flow
steps, each REPEATS times, and prints a markdown table: median wall and CPU
seconds per simulated second, the time-averaged pressure drop, bed height
(twice the solids centroid) and number of particles held (a riser's
hold-up) after the start-up (with their change against the smallest flow
step), the largest Courant number and the collisions.

Repeats of one seed are bit-identical, so they measure timing noise only.
`--seeds 7,11,13,17` runs each flow step once per seed instead (the
scenario's `seed` set with `--set seed=S`): the averages are then means over
independent realisations of the bed, given with their standard error, and
the change against the smallest flow step with the combined standard error.
This is what a flow-step comparison of a bubbling bed's height needs, since
one realisation's 5 s average scatters by several per cent. `--jobs 2` runs
two at a time (use it for accuracy only: the times then share the machine).

Usage: python3 tools/bench_gas.py [--repeats 3 | --seeds 7,11] [--jobs 1]
       [--t-end 2.0] [--skip 0.5] [--dt 5e-5,1e-4,2e-4]
       [--bin target/release/edpm] [SCENARIO]

A flow step may name a splitting after `@` (`--dt 5e-5,1.2e-3@overlapped`:
`--set time.splitting=overlapped` for that row only).
"""

import argparse
import concurrent.futures
import csv
import math
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run(binary, scenario, step, t_end, out, seed=None):
    seed_args = ["--set", f"seed={seed}"] if seed is not None else []
    dt, _, splitting = step.partition("@")
    splitting_args = ["--set", f"time.splitting={splitting}"] if splitting else []
    subprocess.run(
        [binary, "run", scenario, "--out", str(out), "--t-end", str(t_end),
         "--set", f"time.dt_flow={dt}", "--quiet"] + seed_args + splitting_args,
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    summary = json.loads((out / "summary.json").read_text())
    with open(out / "gas_timeseries.csv") as f:
        gas = list(csv.DictReader(f))
    with open(out / "timeseries.csv") as f:
        series = list(csv.DictReader(f))
    return summary, gas, series


def late_mean(rows, key, skip):
    values = [float(r[key]) for r in rows if float(r["time_s"]) >= skip]
    return statistics.mean(values) if values else float("nan")


def mean_and_error(values):
    """Mean and its standard error (0 for a single value)."""
    m = statistics.mean(values)
    if len(values) < 2:
        return m, 0.0
    return m, statistics.stdev(values) / math.sqrt(len(values))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenario", nargs="?", default="scenarios/bubbling-bed-jet.toml")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seeds", help="comma-separated seeds, one run each (replaces --repeats)")
    p.add_argument("--jobs", type=int, default=1, help="runs at a time")
    p.add_argument("--t-end", type=float, default=2.0)
    p.add_argument("--skip", type=float, default=0.5, help="start-up excluded from averages (s)")
    p.add_argument("--dt", default="5e-5,1e-4,2e-4",
                   help="flow steps (s), each optionally DT@SPLITTING")
    p.add_argument("--bin", default="target/release/edpm")
    a = p.parse_args()
    seeds = [int(x) for x in a.seeds.split(",")] if a.seeds else [None] * a.repeats
    dts = a.dt.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as tmp, \
            concurrent.futures.ThreadPoolExecutor(max_workers=a.jobs) as pool:
        jobs = {(dt, r): pool.submit(run, a.bin, a.scenario, dt, a.t_end,
                                     Path(tmp) / f"dt{dt.replace('@', '-')}-{r}", seed)
                for dt in dts for r, seed in enumerate(seeds)}
        for dt in dts:
            walls, cpus, drops, heights, courant, coll, held = [], [], [], [], [], [], []
            for r in range(len(seeds)):
                s, gas, series = jobs[(dt, r)].result()
                walls.append(s["wall_seconds"] / s["t_end"])
                cpus.append(s["cpu_seconds"] / s["t_end"])
                drops.append(late_mean(gas, "pressure_drop_mean_Pa", a.skip))
                heights.append(2.0 * late_mean(series, "centre_of_mass_y_m", a.skip))
                held.append(late_mean(series, "particles", a.skip))
                courant.append(s["gas"]["max_courant"])
                coll.append(s["counters"]["pair_collisions"] + s["counters"]["wall_collisions"])
                print(f"dt={dt} run {r}: {walls[-1]:.2f} s/s wall, dp {drops[-1]:.1f} Pa, "
                      f"height {heights[-1]:.4f} m", file=sys.stderr)
            rows.append((dt, statistics.median(walls), statistics.median(cpus),
                         mean_and_error(drops), mean_and_error(heights),
                         max(courant), statistics.median(coll) / a.t_end,
                         mean_and_error(held)))
    ref = rows[0]
    runs = f"seeds {a.seeds}, one run each" if a.seeds else f"{a.repeats} runs per flow step"
    print(f"Scenario `{a.scenario}`, {a.t_end} s simulated, averages over "
          f"t >= {a.skip} s, {runs} (medians of time, means of averages "
          "± standard error over the runs), bed height = 2 × solids centroid.\n")
    print("| flow step (s) | wall s per simulated s | CPU s per simulated s | "
          "mean Δp (Pa) | Δp vs finest | bed height (m) | height vs finest | "
          "max Courant | collisions per simulated s | particles held | held vs finest |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dt, wall, cpu, (dp, dp_err), (h, h_err), cour, coll, (n, n_err) in rows:
        dp_diff = (dp - ref[3][0]) / ref[3][0]
        dp_diff_err = math.hypot(dp_err, ref[3][1]) / ref[3][0]
        h_diff = (h - ref[4][0]) / ref[4][0]
        h_diff_err = math.hypot(h_err, ref[4][1]) / ref[4][0]
        print(f"| {dt} | {wall:.2f} | {cpu:.2f} | {dp:.0f} ± {dp_err:.0f} | "
              f"{dp_diff:+.1%} ± {dp_diff_err:.1%} | {h:.4f} ± {h_err:.4f} | "
              f"{h_diff:+.1%} ± {h_diff_err:.1%} | {cour:.2f} | {coll:.3g} | "
              f"{n:.0f} ± {n_err:.0f} | {(n - ref[7][0]) / ref[7][0]:+.1%} ± "
              f"{math.hypot(n_err, ref[7][1]) / ref[7][0]:.1%} |")


if __name__ == "__main__":
    main()
