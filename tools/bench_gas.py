#!/usr/bin/env python3
"""Run time against accuracy for the gas-coupled speed anchor.

Runs scenarios/bubbling-bed-jet.toml (or another scenario) at several flow
steps, each REPEATS times, and prints a markdown table: median wall and CPU
seconds per simulated second, the time-averaged pressure drop and bed
centre-of-mass height after the start-up (with their change against the
smallest flow step), the largest Courant number and the collisions.

Usage: python3 tools/bench_gas.py [--repeats 3] [--t-end 2.0] [--skip 0.5]
       [--dt 5e-5,1e-4,2e-4] [--bin target/release/edpm] [SCENARIO]
"""

import argparse
import csv
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def run(binary, scenario, dt, t_end, out):
    subprocess.run(
        [binary, "run", scenario, "--out", str(out), "--t-end", str(t_end),
         "--set", f"time.dt_flow={dt}", "--quiet"],
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


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenario", nargs="?", default="scenarios/bubbling-bed-jet.toml")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--t-end", type=float, default=2.0)
    p.add_argument("--skip", type=float, default=0.5, help="start-up excluded from averages (s)")
    p.add_argument("--dt", default="5e-5,1e-4,2e-4")
    p.add_argument("--bin", default="target/release/edpm")
    a = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for dt in a.dt.split(","):
            walls, cpus, drops, heights, courant, coll = [], [], [], [], [], []
            for r in range(a.repeats):
                out = Path(tmp) / f"dt{dt}-{r}"
                s, gas, series = run(a.bin, a.scenario, dt, a.t_end, out)
                walls.append(s["wall_seconds"] / s["t_end"])
                cpus.append(s["cpu_seconds"] / s["t_end"])
                drops.append(late_mean(gas, "pressure_drop_mean_Pa", a.skip))
                heights.append(late_mean(series, "centre_of_mass_y_m", a.skip))
                courant.append(s["gas"]["max_courant"])
                coll.append(s["counters"]["pair_collisions"] + s["counters"]["wall_collisions"])
                print(f"dt={dt} run {r}: {walls[-1]:.2f} s/s wall", file=sys.stderr)
            rows.append((float(dt), statistics.median(walls), statistics.median(cpus),
                         statistics.mean(drops), statistics.mean(heights),
                         max(courant), statistics.median(coll) / a.t_end))
    ref = rows[0]
    print(f"Scenario `{a.scenario}`, {a.t_end} s simulated, averages over "
          f"t >= {a.skip} s, {a.repeats} runs per flow step (medians of time, "
          "means of averages).\n")
    print("| flow step (s) | wall s per simulated s | CPU s per simulated s | "
          "mean Δp (Pa) | Δp vs finest | bed height (m) | height vs finest | "
          "max Courant | collisions per simulated s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for dt, wall, cpu, dp, h, cour, coll in rows:
        print(f"| {dt:g} | {wall:.2f} | {cpu:.2f} | {dp:.0f} | "
              f"{(dp - ref[3]) / ref[3]:+.1%} | {h:.4f} | {(h - ref[4]) / ref[4]:+.1%} | "
              f"{cour:.2f} | {coll:.3g} |")


if __name__ == "__main__":
    main()
