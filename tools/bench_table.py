#!/usr/bin/env python3
"""The pure event-driven table of issue 13: `edpm bench` against EDMD, side by side.

For every N in {10976, 108000, 1000188} and packing fraction in
{0.1, 0.3, 0.45}, runs `edpm bench --n N --phi PHI --seed S` (default options:
the bench chooses its own search and settings) and each EDMD variant given,
alternating the programs within every repeat, and writes a Markdown table of
the medians of collisions per CPU second, with the ratio edpm / EDMD's best.

EDMD (Smallenburg 2022) is neither built nor shipped here: build it beside the
project as /work/shared/anchors.md describes and pass the binaries, e.g.

    cargo build --release
    python3 tools/bench_table.py --edmd Single=/work/edmd/bench/Single/md \\
        --edmd Multi=/work/edmd/bench/Multi/md --edmd Cell=/work/edmd/bench/Cell/md \\
        --repeats 3 --out results/table.md

or set EDMD_SINGLE, EDMD_MULTI, EDMD_CELL. Each EDMD binary must be called as
`md N PHI EQUILIBRATE MEASURE` (collisions per particle), start from the FCC
lattice, and print one line `RESULT {json}` holding at least
`collisions_per_cpu_second` and `pressure_reduced` (getrusage CPU time over the
measurement only). Without EDMD binaries only edpm's columns are filled.

`--quick` runs N = 10976 only, one repeat, 5 + 10 collisions per particle:
a smoke test of the harness, not a measurement.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

SIZES = (10976, 108000, 1000188)
PHIS = (0.1, 0.3, 0.45)
VARIANT_ENV = {"Single": "EDMD_SINGLE", "Multi": "EDMD_MULTI", "Cell": "EDMD_CELL"}


def carnahan_starling_pressure(phi):
    """beta P sigma^3 = 6 phi Z / pi with Z = (1 + phi + phi^2 - phi^3) / (1 - phi)^3."""
    z = (1 + phi + phi**2 - phi**3) / (1 - phi) ** 3
    return 6 * phi * z / 3.141592653589793


def run_edpm(binary, n, phi, seed, equilibrate, measure):
    args = [binary, "bench", "--n", str(n), "--phi", str(phi), "--seed", str(seed),
            "--equilibrate", str(equilibrate), "--measure", str(measure)]
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def run_edmd(binary, n, phi, equilibrate, measure, workdir):
    args = [binary, str(n), str(phi), str(equilibrate), str(measure)]
    out = subprocess.run(args, check=True, capture_output=True, text=True, cwd=workdir).stdout
    for line in out.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    raise RuntimeError(f"{binary}: no RESULT line in its output:\n{out[-2000:]}")


def load():
    return os.getloadavg()[0]


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--edpm", default="target/release/edpm", help="edpm binary")
    p.add_argument("--edmd", action="append", default=[], metavar="VARIANT=PATH",
                   help="an EDMD binary (repeatable); default from EDMD_SINGLE/MULTI/CELL")
    p.add_argument("--repeats", type=int, default=3, help="runs per program and cell (median)")
    p.add_argument("--n", default=",".join(map(str, SIZES)), help="comma-separated N")
    p.add_argument("--phi", default=",".join(map(str, PHIS)), help="comma-separated phi")
    p.add_argument("--equilibrate", type=float, default=20.0, help="collisions per particle")
    p.add_argument("--measure", type=float, default=50.0, help="collisions per particle")
    p.add_argument("--quick", action="store_true", help="N = 10976, 1 repeat, 5 + 10 collisions")
    p.add_argument("--out", help="also write the Markdown table here")
    p.add_argument("--raw", help="append every run's JSON (one line each) here")
    a = p.parse_args()
    if a.quick:
        a.n, a.repeats, a.equilibrate, a.measure = "10976", 1, 5.0, 10.0
    edmd = {}
    for variant, env in VARIANT_ENV.items():
        if os.environ.get(env):
            edmd[variant] = os.environ[env]
    for item in a.edmd:
        variant, _, path = item.partition("=")
        if not path:
            p.error(f"--edmd wants VARIANT=PATH, got {item!r}")
        edmd[variant] = path
    for variant, path in edmd.items():
        if not os.access(path, os.X_OK):
            p.error(f"EDMD {variant}: {path} is not an executable")
    if not os.access(a.edpm, os.X_OK):
        p.error(f"{a.edpm} is not an executable (cargo build --release)")
    a.sizes = [int(x) for x in a.n.split(",")]
    a.phis = [float(x) for x in a.phi.split(",")]
    a.edmd_bins = edmd
    return a


def main():
    a = parse_args()
    raw = open(a.raw, "a") if a.raw else None
    workdir = tempfile.mkdtemp(prefix="bench_table_")  # EDMD may write files into its cwd
    loads = [load()]
    started = time.strftime("%Y-%m-%d %H:%M")
    rows = []
    for n in a.sizes:
        for phi in a.phis:
            runs = {"edpm": []} | {v: [] for v in a.edmd_bins}
            for rep in range(a.repeats):
                # Alternate the programs within each repeat, so that a change
                # of machine load hits all of them alike.
                r = run_edpm(a.edpm, n, phi, rep + 1, a.equilibrate, a.measure)
                runs["edpm"].append(r)
                print(f"N={n} phi={phi} rep={rep + 1} edpm {r['collisions_per_cpu_second']:.3g} "
                      f"({r['neighbours']}, skin {r['skin']}, start {r['start']}) load {load():.2f}",
                      file=sys.stderr, flush=True)
                for variant, path in a.edmd_bins.items():
                    e = run_edmd(path, n, phi, a.equilibrate, a.measure, workdir)
                    runs[variant].append(e)
                    print(f"N={n} phi={phi} rep={rep + 1} {variant} "
                          f"{e['collisions_per_cpu_second']:.3g} load {load():.2f}",
                          file=sys.stderr, flush=True)
                loads.append(load())
            if raw:
                for prog, rs in runs.items():
                    for r in rs:
                        raw.write(json.dumps({"program": prog, "n": n, "phi": phi} | r) + "\n")
                raw.flush()
            med = {prog: statistics.median(r["collisions_per_cpu_second"] for r in rs)
                   for prog, rs in runs.items()}
            e = runs["edpm"]
            rows.append({
                "n": n, "phi": phi, "med": med,
                "spread": (min(r["collisions_per_cpu_second"] for r in e),
                           max(r["collisions_per_cpu_second"] for r in e)),
                "search": f"{e[0]['neighbours']}" + (f", skin {e[0]['skin']}" if e[0]["neighbours"] == "lists" else ""),
                "pressure": statistics.median(r["pressure_reduced"] for r in e),
                "edmd_pressure": {v: statistics.median(r["pressure_reduced"] for r in runs[v]) for v in a.edmd_bins},
                "rss": statistics.median(r["peak_rss_bytes_per_particle"] or 0 for r in e),
                "estimate": e[0]["bytes_per_particle"],
                "rss_now": statistics.median(r.get("rss_bytes_per_particle") or 0 for r in e),
                "edmd_rss": {v: statistics.median((r.get("max_rss_kib") or r.get("maxrss_kib") or 0) * 1024 / n for r in runs[v])
                             for v in a.edmd_bins},
            })
    variants = list(a.edmd_bins)
    lines = [
        f"Measured {started}, {a.repeats} run(s) per program and cell, alternating; "
        f"{a.equilibrate:g} + {a.measure:g} collisions per particle; "
        f"1-minute load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores.",
        "",
        "Collisions per CPU second (medians):",
        "",
        "| N | phi | edpm (search) | " + " | ".join(f"EDMD {v}" for v in variants)
        + (" | EDMD best | edpm / best" if variants else "") + " |",
        "|---|---|---|" + "---|" * len(variants) + ("---|---|" if variants else ""),
    ]
    for row in rows:
        med = row["med"]
        cells = [f"{row['n']}", f"{row['phi']}", f"{med['edpm']:.3g} ({row['search']})"]
        cells += [f"{med[v]:.3g}" for v in variants]
        if variants:
            best = max(variants, key=lambda v: med[v])
            cells += [f"{med[best]:.3g} ({best})", f"**{med['edpm'] / med[best]:.2f}**"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Pressure (beta P sigma^3, medians) and memory (peak RSS per particle, the OS's figure):",
        "",
        "| N | phi | edpm | " + " | ".join(f"EDMD {v}" for v in variants)
        + " | Carnahan-Starling | edpm peak RSS B/particle (at end; own estimate) | "
        + " | ".join(f"{v} RSS B/particle" for v in variants) + " |",
        "|---|---|---|" + "---|" * len(variants) + "---|---|" + "---|" * len(variants),
    ]
    for row in rows:
        cells = [f"{row['n']}", f"{row['phi']}", f"{row['pressure']:.4f}"]
        cells += [f"{row['edmd_pressure'][v]:.4f}" for v in variants]
        cells += [f"{carnahan_starling_pressure(row['phi']):.4f}",
                  f"{row['rss']:.0f} ({row['rss_now']:.0f}; {row['estimate']})"]
        cells += [f"{row['edmd_rss'][v]:.0f}" for v in variants]
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines) + "\n"
    print(table)
    if a.out:
        tmp = a.out + ".tmp"
        with open(tmp, "w") as f:
            f.write(table)
        os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
