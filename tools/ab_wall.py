#!/usr/bin/env python3
"""Wall time of two edpm binaries on the same run, side by side.

The development hosts are shared and their speed drifts by tens of per
cent within minutes, so two binaries are compared only by ratios of runs
made next to each other. This tool runs `A run ARGS` and `B run ARGS`
in pairs, in the order A B, B A, A B, ... (so that a steady drift
favours neither), and prints each pair's ratio B/A of summary.json's
`wall_seconds`, their median, and a distribution-free interval for the
median: the k-th smallest and k-th largest ratio, whose coverage of the
true median follows from the binomial distribution alone. With the
overlapped splitting it also prints the medians of the joins' flight
side, gas side and joins (wall_seconds_by_part).

It checks that both binaries wrote the same final_state.bin (the same
bits), which a speed change that claims bit-identical results must show;
`--any-bits` only reports it.

Usage:
    python3 tools/ab_wall.py --a OLD --b NEW [--pairs 8] [--threads 2]
        [--any-bits] -- SCENARIO [edpm run options ...]

Example (the jet bed on two threads, eight pairs):
    python3 tools/ab_wall.py --a old/edpm --b target/release/edpm -- \\
        scenarios/bubbling-bed-jet.toml --set time.dt_flow=1.2e-3 \\
        --set time.splitting=overlapped --t-end 1

Standard library only.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

SIDES = ("flight_side", "gas_side", "joined")


def run(binary, args, out, threads):
    """One `edpm run` into `out`; returns its summary.json."""
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    cmd = [binary, "run", *args, "--quiet", "--force", "--out", str(out)]
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        sys.exit(f"ab_wall: {' '.join(cmd)} failed:\n{done.stderr}")
    return json.loads((out / "summary.json").read_text())


def median_interval(ratios):
    """(low, high, coverage) of the narrowest order-statistic interval
    that covers the median with probability >= 0.9, or the whole range
    with its coverage when too few pairs reach 0.9."""
    r = sorted(ratios)
    n = len(r)

    def coverage(k):
        # P(r_(k) <= median <= r_(n-k+1)) = 1 - 2 P(Binomial(n, 1/2) < k)
        tail = sum(math.comb(n, i) for i in range(k)) / 2 ** n
        return 1.0 - 2.0 * tail

    k = 1
    while k + 1 <= (n + 1) // 2 and coverage(k + 1) >= 0.9:
        k += 1
    return r[k - 1], r[n - k], coverage(k)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--a", required=True, help="the reference binary")
    p.add_argument("--b", required=True, help="the binary compared with it")
    p.add_argument("--pairs", type=int, default=8)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--any-bits", action="store_true",
                   help="report, do not require, identical final states")
    p.add_argument("args", nargs=argparse.REMAINDER,
                   help="after --: the scenario and `edpm run` options")
    a = p.parse_args()
    args = a.args[1:] if a.args[:1] == ["--"] else a.args
    if not args:
        sys.exit("ab_wall: give the scenario and run options after --")
    if a.pairs < 2:
        sys.exit("ab_wall: --pairs must be at least 2")
    if any(x in ("--out", "--force", "--quiet") for x in args):
        sys.exit("ab_wall: the tool sets --out, --force and --quiet itself")
    walls = {"A": [], "B": []}
    sides = {"A": {s: [] for s in SIDES}, "B": {s: [] for s in SIDES}}
    same_bits = True
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k in range(a.pairs):
            order = ("A", "B") if k % 2 == 0 else ("B", "A")
            for who in order:
                binary = a.a if who == "A" else a.b
                s = run(binary, args, tmp / who, a.threads)
                walls[who].append(s["wall_seconds"])
                parts = s.get("wall_seconds_by_part", {})
                for side in SIDES:
                    sides[who][side].append(parts.get(side, 0.0))
            final = [tmp / w / "final_state.bin" for w in "AB"]
            same_bits &= all(f.exists() for f in final) and (
                final[0].read_bytes() == final[1].read_bytes())
    ratios = [b / a_ for a_, b in zip(walls["A"], walls["B"])]
    print(f"edpm run {' '.join(args)}, {a.threads} thread(s), "
          f"{a.pairs} pairs (A: {a.a}, B: {a.b})")
    print()
    print("| pair | A (s) | B (s) | B/A |")
    print("|---|---|---|---|")
    for k, (ta, tb, r) in enumerate(zip(walls["A"], walls["B"], ratios)):
        print(f"| {k + 1} | {ta:.3f} | {tb:.3f} | {r:.3f} |")
    low, high, cover = median_interval(ratios)
    print()
    print(f"median B/A {statistics.median(ratios):.3f}, "
          f"{100 * cover:.0f} % interval {low:.3f}-{high:.3f}")
    if any(v for who in "AB" for v in sides[who]["joined"]):
        for who in "AB":
            m = {s: statistics.median(v) for s, v in sides[who].items()}
            print(f"{who}: medians of the joins' flight side {m['flight_side']:.3f}, "
                  f"gas side {m['gas_side']:.3f}, joins {m['joined']:.3f} s")
    print(f"same final_state.bin: {'yes' if same_bits else 'no'}")
    if not same_bits and not a.any_bits:
        sys.exit("ab_wall: the binaries wrote different final states "
                 "(--any-bits to allow it)")


if __name__ == "__main__":
    main()
