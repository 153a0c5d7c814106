#!/usr/bin/env python3
"""Minimum fluidization velocity from an `edpm sweep` of the inflow velocity
(python3 >= 3.11, standard library only).

The sweep (results/fluidization/README.md has the exact commands):
1. `edpm run scenarios/fluidized-bed.toml --out FLUIDIZE`: the bed
   fluidized at the scenario's own inflow (about 2 u_mf); its
   final_state.bin is the common start of every point.
2. `edpm sweep scenarios/fluidized-bed.toml --set gas.faces.y_lo.inflow=U1,U2,...
   --set "gas.initial_velocity=[0,{gas.faces.y_lo.inflow},0]"
   --set initial.checkpoint=FLUIDIZE/final_state.bin --t-end T
   --average-after T0 --columns gas_timeseries.csv:pressure_drop_mean_Pa,
   gas_timeseries.csv:pressure_drop_mean_Pa:std,timeseries.csv:ke_translational_J,...`:
   one independent run per velocity from that state (a stepped
   defluidization whose points do not inherit each other's history).

This script reads SWEEP/sweep.csv and each point's final_particles.csv:
- A point is *fixed* when the mean square particle speed 2 KE / M over the
  averaging window is below --packed-v2 (1e-4 m^2/s^2: speeds below 1 cm/s;
  a fluidized bed has 1e-3 to 1e-2, a packed one 1e-8 to 1e-6).
- u_mf is where the fixed-bed branch, fitted as dp = a U + b U^2 through the
  origin (Ergun's form) to the fixed points below 0.95 W/A, reaches the
  buoyant bed weight per area W/A = sum m_p g (1 - rho_g/rho_p) / A.
- eps_mf is the gas fraction of the packed bed, 1 - V_s / (A H), with H
  where the laterally averaged solids fraction (layers of one gas cell)
  falls to half its bulk value, averaged over the fitted points.
- Ergun's u_mf at that eps_mf and Wen-Yu's are the references (the same
  formulas as src/gas/drag.rs).
The measured dp (gas_timeseries.csv pressure_drop_mean_Pa) runs from the
centre of the bottom cell layer to the outlet face; the gas hydrostatic
head rho_g g (H_box - h_y/2) between them is subtracted.

Usage: python3 tools/umf_fit.py SWEEP_DIR [--scenario scenarios/fluidized-bed.toml]
Prints a Markdown report (and writes it with --out FILE).
"""
import argparse
import csv
import math
import os
import sys
import tomllib

G = 9.81
R_GAS = 8.314462618


def umf_wen_yu(d, rho_p, rho_g, mu, g):
    ar = rho_g * (rho_p - rho_g) * g * d ** 3 / mu ** 2
    x = 0.0408 * ar
    re_mf = x / (math.sqrt(33.7 ** 2 + x) + 33.7)
    return re_mf * mu / (rho_g * d)


def umf_ergun(d, rho_p, rho_g, mu, g, eps):
    e3 = eps ** 3
    a = 1.75 * rho_g / (e3 * d)
    b = 150.0 * mu * (1.0 - eps) / (e3 * d * d)
    c = (rho_p - rho_g) * g
    return 2.0 * c / (b + math.sqrt(b * b + 4.0 * a * c))


def scenario_numbers(path):
    with open(path, "rb") as f:
        t = tomllib.load(f)
    gas = t["gas"]
    p = gas.get("pressure", 101325.0)
    if gas.get("model", "ideal-gas") == "ideal-gas":
        rho_g = p * gas.get("molar_mass", 0.02896) / (R_GAS * gas.get("temperature", 293.15))
    else:
        rho_g = gas["density"]
    mats = {m["name"]: m.get("density") for m in t["materials"]}
    pop = t["particles"][0]
    lo, hi = t["domain"]["lo"], t["domain"]["hi"]
    d = pop["diameter"]
    rho_p = mats[pop["material"]]
    n = pop["count"]
    area = (hi[0] - lo[0]) * (hi[2] - lo[2])
    vp = math.pi / 6 * d ** 3
    return dict(
        d=d, rho_p=rho_p, rho_g=rho_g, mu=gas.get("viscosity", 1.8e-5), n=n, area=area,
        height=hi[1] - lo[1], lo_y=lo[1], h_y=(hi[1] - lo[1]) / gas["cells"][1],
        mass=n * vp * rho_p, solids_volume=n * vp,
        weight_per_area=n * vp * rho_p * G * (1 - rho_g / rho_p) / area,
    )


def bed_gas_fraction(particles_csv, sc):
    """1 - V_s/(A H), H where the layer solids fraction falls to half its
    bulk value (layers of one gas cell; particle volume split by height)."""
    h = sc["h_y"]
    layers = [0.0] * int(round(sc["height"] / h))
    with open(particles_csv) as f:
        for row in csv.DictReader(f):
            r, y = float(row["radius_m"]), float(row["y_m"]) - sc["lo_y"]
            # Spherical cap volumes per layer, by 16-point midpoint slices.
            for k in range(16):
                z = y - r + (k + 0.5) * 2 * r / 16
                layer = min(max(int(z / h), 0), len(layers) - 1)
                layers[layer] += math.pi * (r * r - (z - y) ** 2) * 2 * r / 16
    frac = [v / (sc["area"] * h) for v in layers]
    bulk = sorted(frac[1:8])[3]
    for k in range(1, len(frac)):
        if frac[k] < bulk / 2:
            # Linear interpolation between the centres of layers k-1 and k.
            f0, f1 = frac[k - 1], frac[k]
            t = (f0 - bulk / 2) / (f0 - f1)
            height = (k - 0.5 + t) * h
            return 1 - sc["solids_volume"] / (sc["area"] * height), height
    return float("nan"), float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweep")
    ap.add_argument("--scenario", default="scenarios/fluidized-bed.toml")
    ap.add_argument("--packed-v2", type=float, default=1e-4)
    ap.add_argument("--out")
    a = ap.parse_args()
    sc = scenario_numbers(a.scenario)
    w = sc["weight_per_area"]
    head = sc["rho_g"] * G * (sc["height"] - sc["h_y"] / 2)
    key = "gas.faces.y_lo.inflow"
    points = []
    with open(os.path.join(a.sweep, "sweep.csv")) as f:
        for row in csv.DictReader(f):
            if row["status"] != "completed":
                sys.exit(f"{row['point']} failed: re-run it before fitting")
            u = float(row[key])
            dp = float(row["gas_timeseries.csv:pressure_drop_mean_Pa"]) - head
            v2 = 2 * float(row["timeseries.csv:ke_translational_J"]) / sc["mass"]
            eps, height = bed_gas_fraction(os.path.join(a.sweep, row["point"], "final_particles.csv"), sc)
            points.append(dict(row=row, U=u, dp=dp, v2=v2, eps=eps, height=height,
                               fixed=v2 < a.packed_v2,
                               std=float(row["gas_timeseries.csv:pressure_drop_mean_Pa:std"])))
    fit = [p for p in points if p["fixed"] and p["dp"] < 0.95 * w]
    if len(fit) < 2:
        sys.exit("fewer than two fixed-bed points below 0.95 W/A: sweep lower velocities")
    # Least squares dp = a U + b U^2 (normal equations, 2x2).
    s2 = sum(p["U"] ** 2 for p in fit)
    s3 = sum(p["U"] ** 3 for p in fit)
    s4 = sum(p["U"] ** 4 for p in fit)
    r1 = sum(p["U"] * p["dp"] for p in fit)
    r2 = sum(p["U"] ** 2 * p["dp"] for p in fit)
    det = s2 * s4 - s3 * s3
    ca, cb = (r1 * s4 - r2 * s3) / det, (s2 * r2 - s3 * r1) / det
    umf = (-ca + math.sqrt(ca * ca + 4 * cb * w)) / (2 * cb) if cb != 0 else w / ca
    eps_mf = sum(p["eps"] for p in fit) / len(fit)
    fluid = [p for p in points if not p["fixed"] and p["U"] >= 1.15 * umf]
    plateau = sum(p["dp"] for p in fluid) / len(fluid) if fluid else float("nan")
    args = (sc["d"], sc["rho_p"], sc["rho_g"], sc["mu"], G)
    ergun = umf_ergun(*args, eps_mf)
    wen_yu = umf_wen_yu(*args)

    out = [f"Sweep `{a.sweep}` of `{a.scenario}`: W/A = {w:.2f} Pa, gas head subtracted {head:.3f} Pa.", "",
           "| U (m/s) | state | dp (Pa) | dp std (Pa) | dp / (W/A) | mean square speed (m²/s²) | eps (bed height) | CPU (s) |",
           "|---|---|---|---|---|---|---|---|"]
    for p in sorted(points, key=lambda p: -p["U"]):
        eps = f"{p['eps']:.4f}" if p["fixed"] else "—"
        out.append(f"| {p['U']:.3f} | {'fixed' if p['fixed'] else 'fluidized'} | {p['dp']:.2f} | {p['std']:.2f} | "
                   f"{p['dp'] / w:.3f} | {p['v2']:.1e} | {eps} | {float(p['row']['cpu_seconds']):.0f} |")
    out += ["",
            f"Fixed-bed fit dp = a U + b U² over {len(fit)} points: a = {ca:.2f} Pa s/m, b = {cb:.2f} Pa s²/m²; "
            f"**u_mf = {umf:.4f} m/s**. eps_mf = {eps_mf:.4f} (bed height). "
            f"Fluidized plateau (U >= 1.15 u_mf, {len(fluid)} points): {plateau:.2f} Pa = {plateau / w:.3f} W/A.", "",
            "| reference | u_mf (m/s) | measured / reference - 1 |", "|---|---|---|",
            f"| Ergun at eps_mf = {eps_mf:.4f} | {ergun:.4f} | {100 * (umf / ergun - 1):+.1f} % |",
            f"| Wen–Yu | {wen_yu:.4f} | {100 * (umf / wen_yu - 1):+.1f} % |"]
    text = "\n".join(out) + "\n"
    print(text, end="")
    if a.out:
        with open(a.out + ".tmp", "w") as f:
            f.write(text)
        os.replace(a.out + ".tmp", a.out)


if __name__ == "__main__":
    main()
