#!/usr/bin/env python3
"""Vertical force balance of a gas-fluidized bed over a time window.

Takes two runs of the same scenario and seed that differ only in t_end
(runs are deterministic, so the shorter one is the longer one's start):
EARLY ends at the window's start, LATE at its end. From the counters and
the time series it prints, each divided by the bed weight W = sum m_i |g|:

- the static pressure drop (gas_timeseries.csv pressure_drop_mean_Pa)
  and the gas support (gas_support_mean_Pa: the static drop plus the net
  gas momentum flux into the column, e.g. a jet's), both times the
  cross-section, with the standard error of 10 block means;
- the force of the gas on the particles (summary gas.exchange_impulse),
  of the bottom plate and of the other walls (counters.wall_impulse), and
  the particles' momentum change (timeseries.csv momentum);
- the closure (gas + plate + walls - dP/dt) / W, which must be 1 up to
  the gas buoyancy rho_g/rho_p (it checks the bookkeeping).

Gravity along -y; the cross-section is the domain's x extent times its z
extent (the bed depth in planar mode, docs/gas.md "Pressure drop").

Usage: python3 tools/bed_balance.py EARLY LATE
"""

import csv
import json
import math
import statistics
import sys
import tomllib


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def main(early, late):
    s0 = json.load(open(f"{early}/summary.json"))
    s1 = json.load(open(f"{late}/summary.json"))
    t0, t1 = s0["t_end"], s1["t_end"]
    span = t1 - t0
    particles = rows(f"{late}/final_particles.csv")
    with open(f"{late}/resolved.toml", "rb") as f:
        resolved = tomllib.load(f)
    density = [m.get("density") for m in resolved["materials"]]
    lo, hi = resolved["domain"]["lo"], resolved["domain"]["hi"]
    g = abs(resolved["domain"]["gravity"][1])
    area = (hi[0] - lo[0]) * (hi[2] - lo[2])
    if s1["particles_final"] != s0["particles_final"] or s1["counters"]["removed"]:
        sys.exit("bed_balance.py: the bed must keep its particles (no inlet or outlet)")
    weight = sum(
        density[int(p["material"])] * 4.0 / 3.0 * math.pi * float(p["radius_m"]) ** 3 * g
        for p in particles
    )
    c0, c1 = s0["counters"], s1["counters"]

    def wall(k):
        return -(c1["wall_impulse"][k][1] - c0["wall_impulse"][k][1]) / span

    plate = wall(2)
    walls = wall(0) + wall(1) + wall(3)
    gas = (
        s1["gas"]["exchange_impulse_particles"][1] - s0["gas"]["exchange_impulse_particles"][1]
    ) / span
    series = rows(f"{late}/timeseries.csv")
    start = min(series, key=lambda r: abs(float(r["time_s"]) - t0))
    dmom = (float(series[-1]["momentum_y_kg_m_s"]) - float(start["momentum_y_kg_m_s"])) / span
    gas_rows = [r for r in rows(f"{late}/gas_timeseries.csv") if float(r["time_s"]) > t0 + 1e-9]

    def mean_and_error(column):
        x = [float(r[column]) * area / weight for r in gas_rows]
        blocks = 10
        n = len(x) // blocks
        means = [sum(x[i * n:(i + 1) * n]) / n for i in range(blocks)]
        return statistics.mean(x), statistics.stdev(means) / math.sqrt(blocks)

    dp, dp_err = mean_and_error("pressure_drop_mean_Pa")
    support, support_err = mean_and_error("gas_support_mean_Pa")
    inflow = statistics.mean(float(r["momentum_inflow_Pa"]) for r in gas_rows) * area / weight
    print(f"window {t0:g}-{t1:g} s, W = {weight:.5g} N, A = {area:.5g} m^2, W/A = {weight / area:.5g} Pa")
    print("| measure | / W |")
    print("|---|---|")
    print(f"| static pressure drop x A | {dp:.4f} +- {dp_err:.4f} |")
    print(f"| net gas momentum inflow x A | {inflow:.4f} |")
    print(f"| gas support (static + momentum) x A | {support:.4f} +- {support_err:.4f} |")
    print(f"| gas force on the particles | {gas / weight:.4f} |")
    print(f"| bottom plate | {plate / weight:.4f} |")
    print(f"| side walls | {walls / weight:.4f} |")
    print(f"| particles' momentum change per time | {dmom / weight:.4f} |")
    print(f"| closure (gas + plate + walls - dP/dt) | {(gas + plate + walls - dmom) / weight:.4f} |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
