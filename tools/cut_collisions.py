"""Pair collisions across a cut plane, per flow step, from an edpm event log.

How often would two halves of a domain, each simulated on its own core for
a flow step, have to agree on a collision between them (docs/scaling.md,
section 2.3)? The cut is placed at the median coordinate of the colliding
particles, so that the halves hold equal collision work. A collision counts
as crossing when its two particles are on opposite sides of the cut at
contact; particles that crossed the cut earlier in the step are not
counted, so the figures are lower bounds.

    python3 tools/cut_collisions.py run.log AXIS T_FROM

AXIS: 0, 1 or 2 (x, y, z); T_FROM: first time taken (s), to skip the start.
Needs numpy (optional for the other tools).
"""

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import edpm_log  # noqa: E402


def cut_collisions(log, axis, t_from):
    """Per-step counts: a dict with the cut (m), the steps, and the mean
    collisions per step, crossing the cut and in all."""
    r = log["records"]
    dt = log["dt_flow"]
    pair = (r["kind"] == edpm_log.PAIR) & (r["time"] >= t_from)
    a = r["state_a"][pair][:, axis]
    b = r["state_b"][pair][:, axis]
    if len(a) == 0:
        raise ValueError(f"no pair collisions after t = {t_from} s")
    cut = float(np.median(np.concatenate([a, b])))
    crossing = (a - cut) * (b - cut) < 0
    steps = np.floor((r["time"][pair] - t_from) / dt).astype(int)
    n = int(steps.max()) + 1
    across = np.bincount(steps[crossing], minlength=n)
    every = np.bincount(steps, minlength=n)
    return {
        "axis": axis,
        "cut_m": cut,
        "flow_steps": n,
        "dt_flow_s": dt,
        "collisions_per_step": float(every.mean()),
        "crossing_per_step_mean": float(across.mean()),
        "crossing_per_step_median": float(np.median(across)),
        "steps_without_crossing": float(np.mean(across == 0)),
    }


def main(argv):
    if len(argv) != 4 or argv[2] not in ("0", "1", "2"):
        print(__doc__, file=sys.stderr)
        return 2
    log = edpm_log.read_log(argv[1], use_numpy=True)
    print(json.dumps(cut_collisions(log, int(argv[2]), float(argv[3]))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
