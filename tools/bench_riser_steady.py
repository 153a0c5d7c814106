#!/usr/bin/env python3
"""Wall time per simulated second of a riser at steady state, one thread
against two.

A riser starts empty and fills over its first simulated second, so timing
from t = 0 measures a riser with about half its steady hold-up. This tool
fills the riser once per splitting to `--start` (default 1.5 s; the
scenarios reach steady state at about 1.2 s), writing a restart file there,
then times `--restart` runs over `--span` simulated seconds: second-order
splitting on one thread and overlapped splitting on two, alternating,
`--repeats` times. Restarts continue bit for bit, so the repeats of one
setting run the same trajectory and differ by timing noise only.

Prints a markdown table: each run's wall seconds per simulated second, the
medians, and their ratio (results/benchmarks.md, seventeenth session), and
for the two-thread runs the two sides of the overlapped steps' joins (the
flight and the gas step): the longer one bounds the speedup.

The two settings follow different trajectories (a riser is chaotic), so a
short span also compares two flows. `--same-trajectory` adds overlapped
splitting on one thread, which gives the same bits as on two: its ratio
is the speedup of the threads alone on the very same work
(results/benchmarks.md, twenty-sixth session).

Usage: python3 tools/bench_riser_steady.py [--repeats 3] [--start 1.5]
       [--span 1.0] [--dt 1e-3] [--bin target/release/edpm]
       [--set KEY=VALUE ...] [--same-trajectory]
       [SCENARIO (default scenarios/riser-ideal.toml)]

`--set` overrides go to every run (fills included), for instance
`--set 'engine.cell_shape="square"'` against the default adaptive cells
(results/benchmarks.md, eighteenth session).
"""

import argparse
import json
import os
import statistics
import subprocess
import tempfile
from pathlib import Path

SETTINGS = [("second-order", 1), ("overlapped", 2)]
SAME_TRAJECTORY = ("overlapped", 1)


def edpm(binary, scenario, splitting, threads, out, args):
    """Runs `edpm run` quietly into `out`; returns its summary.json."""
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    cmd = [binary, "run", scenario, "--quiet", "--force", "--out", str(out),
           "--set", f"time.splitting={splitting}"] + args
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return json.loads((out / "summary.json").read_text())


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenario", nargs="?", default="scenarios/riser-ideal.toml")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--start", type=float, default=1.5)
    p.add_argument("--span", type=float, default=1.0)
    p.add_argument("--dt", type=float, default=1e-3)
    p.add_argument("--bin", default="target/release/edpm")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--same-trajectory", action="store_true",
                   help="also time overlapped splitting on one thread")
    a = p.parse_args()
    settings = SETTINGS + ([SAME_TRAJECTORY] if a.same_trajectory else [])
    step = ["--set", f"time.dt_flow={a.dt}",
            "--set", f"output.restart_interval={a.start}"]
    for override in a.set:
        step += ["--set", override]
    walls = {s: [] for s in settings}
    # Two-thread runs: per simulated second, the joins' flight side, gas
    # side and the joins (summary.json's wall_seconds_by_part).
    sides = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        restarts = {}
        for splitting, _ in SETTINGS:
            # The restart is written at the end of the step reaching
            # `start`, never at a run's last step: run one step beyond.
            out = tmp / f"fill-{splitting}"
            edpm(a.bin, a.scenario, splitting, 2, out,
                 step + ["--t-end", repr(a.start + a.dt)])
            restarts[splitting] = out / "restart.bin"
        for _ in range(a.repeats):
            for splitting, threads in settings:
                s = edpm(a.bin, a.scenario, splitting, threads, tmp / "run",
                         step + ["--t-end", repr(a.start + a.span),
                                 "--restart", str(restarts[splitting])])
                walls[(splitting, threads)].append(s["wall_seconds"] / a.span)
                if (splitting, threads) == SETTINGS[1]:
                    p = s["wall_seconds_by_part"]
                    sides.append(tuple(p[k] / a.span for k in
                                       ("flight_side", "gas_side", "joined")))
    print(f"{a.scenario}, {a.start} -> {a.start + a.span} s, "
          f"dt_flow {a.dt} s: wall seconds per simulated second\n")
    print("| splitting | threads | runs | median |")
    print("|---|---|---|---|")
    for (splitting, threads), w in walls.items():
        runs = ", ".join(f"{x:.2f}" for x in w)
        print(f"| {splitting} | {threads} | {runs} | {statistics.median(w):.2f} |")
    one, two = (statistics.median(walls[s]) for s in SETTINGS)
    print(f"\ntwo threads against one: {one / two:.2f}x")
    ratios = [x / y for x, y in zip(walls[SETTINGS[0]], walls[SETTINGS[1]])]
    print("  each repeat: " + ", ".join(f"{r:.2f}x" for r in ratios))
    flight, gas, joined = (statistics.median(x) for x in zip(*sides))
    bound = "the flight" if flight >= gas else "the gas step"
    print(f"two threads, wall s per simulated second in the joins (medians): "
          f"flight side {flight:.2f}, gas side {gas:.2f}, joins {joined:.2f}: "
          f"{bound} bounds the step")
    if a.same_trajectory:
        same = statistics.median(walls[SAME_TRAJECTORY])
        print(f"two threads against one on the same trajectory (overlapped): {same / two:.2f}x")
        ratios = [x / y for x, y in zip(walls[SAME_TRAJECTORY], walls[SETTINGS[1]])]
        print("  each repeat: " + ", ".join(f"{r:.2f}x" for r in ratios))


if __name__ == "__main__":
    main()
