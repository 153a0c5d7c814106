#!/usr/bin/env python3
"""Runs `edpm bench` over the EDMD comparison grid and prints a Markdown table.

Each cell is the median of REPEATS runs (collisions per CPU second). Usage:
    cargo build --release && python3 tools/bench_table.py [REPEATS]
"""
import json
import statistics
import subprocess
import sys

BIN = sys.argv[2] if len(sys.argv) > 2 else "target/release/edpm"
REPEATS = int(sys.argv[1]) if len(sys.argv) > 1 else 3
# Settings per packing fraction: the neighbour search and skin that measured
# fastest (see results/benchmarks.md).
SETTINGS = {0.10: ["--neighbours", "cells"], 0.30: ["--skin", "0.3"], 0.45: ["--skin", "0.3"]}
EDMD = {(10976, 0.10): 8.9e5, (10976, 0.30): 7.2e5, (10976, 0.45): 1.1e6,
        (108000, 0.10): 4.2e5, (108000, 0.30): 4.1e5, (108000, 0.45): 6.7e5}


def bench(args):
    out = subprocess.run([BIN, "bench", *args], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main():
    rows = []
    for n in (10976, 108000):
        for phi, extra in SETTINGS.items():
            runs = [bench(["--n", str(n), "--phi", str(phi), "--seed", str(s), *extra]) for s in range(1, REPEATS + 1)]
            rate = statistics.median(r["collisions_per_cpu_second"] for r in runs)
            p = statistics.median(r["pressure_reduced"] for r in runs)
            cs = runs[0]["pressure_carnahan_starling"]
            rows.append((n, phi, " ".join(extra), rate, EDMD[(n, phi)], p, cs, runs[0]["bytes_per_particle"]))
    print("| N | phi | settings | collisions / CPU s (median of %d) | EDMD | ratio | beta P sigma^3 | Carnahan-Starling | bytes / particle |" % REPEATS)
    print("|---|---|---|---|---|---|---|---|---|")
    for n, phi, extra, rate, edmd, p, cs, b in rows:
        print(f"| {n} | {phi} | {extra} | {rate:.3g} | {edmd:.2g} | {rate / edmd:.2f} | {p:.4f} | {cs:.4f} | {b} |")


if __name__ == "__main__":
    main()
