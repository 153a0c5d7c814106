#!/usr/bin/env python3
"""Mutation robustness check of `edpm` (python3 standard library only).

Mutates the shipped scenarios (numbers set to extreme values, keys and
tables removed or duplicated, values of the wrong kind) and the command
line (options at their limits, damaged files for replay and analyse, physics
stress set-ups), runs each case with a timeout and classifies the outcome:

    clear error    non-zero exit with one `edpm: error:` message that names
                   the file, option or particle concerned
    ran sane       exit 0 and the outputs pass the checks below
    panic          a Rust panic, an abort or a signal
    hang           no exit within the timeout
    wrong result   exit 0 but an output fails a check (NaN, a particle
                   outside the domain, the run not ending at t_end, ...)
    unclear error  non-zero exit without such a message

and writes the counts and every case to results/robustness.md.

    cargo build --release
    python3 tools/mutate.py                      # about 400 cases, a few minutes on 2 cores
    python3 tools/mutate.py --limit 50 --jobs 4 --timeout 300

The cases are a deterministic function of --seed and the shipped scenarios.
"""

import argparse
import concurrent.futures
import csv
import json
import math
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time

try:
    import tomllib  # Python 3.11+
except ImportError:  # pragma: no cover - older Pythons skip structure-aware cases
    tomllib = None

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STEPS = 20  # flow steps per run: short runs keep the whole check to minutes

EXTREMES = ["0", "-1", "-0.0", "1e-300", "1e300", "nan", "inf", "-inf", "1e-15", "1e15",
            "4097", "50000001", "0.5"]
OUTCOMES = ["clear error", "ran sane", "panic", "hang", "wrong result", "unclear error"]


class Case:
    def __init__(self, name, args, scenario=None, text=None, t_end=None, cwd_files=None):
        self.name = name          # what was mutated
        self.args = args          # edpm arguments (the scenario path is filled in)
        self.scenario = scenario  # shipped scenario file name, if any
        self.text = text          # replacement scenario text, if any
        self.t_end = t_end        # end time the run must reach (for run cases)
        self.cwd_files = cwd_files or {}


def leaves(node, path=""):
    """(--set path, value) of every numeric leaf of a parsed TOML document."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from leaves(v, f"{path}.{k}" if path else k)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from leaves(v, f"{path}.{i}")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path, node


def fmt(v):
    return repr(float(v)) if isinstance(v, float) else str(v)


def scenario_cases(rng, name, text):
    """Mutations of one shipped scenario."""
    cases = []
    data = tomllib.loads(text) if tomllib else {}
    t_end = data.get("time", {}).get("t_end", 1.0)
    dt = data.get("time", {}).get("dt_flow", 1e-4)
    short = min(t_end, STEPS * dt)
    run = ["--t-end", repr(short)]

    # Numbers set to extreme or scaled values.
    numeric = [(p, v) for p, v in leaves(data) if not p.startswith("seed")]
    for path, value in rng.sample(numeric, min(len(numeric), 20)):
        if path == "time.t_end":
            # Only values that end the run quickly or are refused: a longer
            # valid t_end is a long run, not a robustness case.
            new = rng.choice(["0", "-1", "-0.0", "1e-300", "1e300", "nan", "inf", "-inf",
                              "1e-15", "50000001", "x1e-3"])
        else:
            new = rng.choice(EXTREMES + ["x1e3", "x1e-3", "x1e6"])
        if new.startswith("x"):
            new = fmt(value * float(new[1:]))
        timed = path.startswith("time.")
        args = ["--set", f"{path}={new}"] + ([] if timed else run)
        cases.append(Case(f"{name}: {path} = {new}", args, name,
                          t_end=None if timed else short))

    # Structure: a line deleted, a table duplicated, a value of the wrong kind,
    # an unknown key, a typo in a name, the file cut in half.
    lines = text.splitlines()
    assignments = [i for i, l in enumerate(lines) if "=" in l and not l.lstrip().startswith("#")]
    headers = [i for i, l in enumerate(lines) if l.lstrip().startswith("[")]
    for i in rng.sample(assignments, min(3, len(assignments))):
        edited = "\n".join(lines[:i] + lines[i + 1:]) + "\n"
        cases.append(Case(f"{name}: line {i + 1} deleted ({lines[i].strip()[:40]})", run, name,
                          text=edited, t_end=short))
    if headers:
        i = rng.choice(headers)
        j = next((k for k in headers if k > i), len(lines))
        edited = "\n".join(lines + lines[i:j]) + "\n"
        cases.append(Case(f"{name}: table at line {i + 1} duplicated", run, name,
                          text=edited, t_end=short))
    i = rng.choice(assignments)
    key = lines[i].split("=", 1)[0]
    edited = "\n".join(lines[:i] + [f'{key}= "text"'] + lines[i + 1:]) + "\n"
    cases.append(Case(f"{name}: {key.strip()} given as a string", run, name, text=edited, t_end=short))
    cases.append(Case(f"{name}: unknown key", run, name,
                      text=text.replace("[time]", "[time]\ncolour = 3", 1), t_end=short))
    cases.append(Case(f"{name}: material name typo", run, name,
                      text=re.sub(r'material = "(\w+)"', r'material = "\1x"', text, count=1),
                      t_end=short))
    cases.append(Case(f"{name}: file cut in half", run, name, text=text[: len(text) // 2],
                      t_end=short))
    return cases


def command_line_cases():
    """Options at their limits, damaged inputs of replay and analyse, and
    physics stress set-ups."""
    box = "box-walls.toml"
    jet = "bubbling-bed-jet.toml"
    bed = "bidisperse-bed.toml"
    cases = []
    for t in ["0", "-1", "nan", "inf", "1e300", "1e-300", "abc"]:
        cases.append(Case(f"--t-end {t}", ["--t-end", t], box))
    cases += [
        Case("--log-checkpoint-steps 0", ["--t-end", "0.01", "--log", "{tmp}/run.log",
                                          "--log-checkpoint-steps", "0"], box),
        Case("--log-checkpoint-steps 1", ["--t-end", "0.005", "--log", "{tmp}/run.log",
                                          "--log-checkpoint-steps", "1"], box, t_end=0.005),
        Case("--log with gas", ["--t-end", "0.001", "--log", "{tmp}/run.log"], jet),
        Case("--set without =", ["--t-end", "0.01", "--set", "novalue"], box),
        Case("--set index out of range", ["--t-end", "0.01", "--set", "particles.9.count=1"], box),
        Case("--set empty segment", ["--t-end", "0.01", "--set", "a..b=1"], box),
        Case("--out is a file", ["--t-end", "0.01", "--out", "{tmp}/file"], box,
             cwd_files={"file": b"x"}),
        Case("missing scenario", ["--t-end", "0.01"], "no-such-scenario.toml"),
        # Stress: each must run sanely or stop with a clear error.
        Case("dense inelastic box without TC (stall)",
             ["--t-end", "0.005", "--set", "particles.0.count=2500",
              "--set", "collisions.default.e_n=0.3", "--set", "collisions.tc=0"], box),
        Case("gravity 1e300", ["--t-end", "0.01", "--set", "domain.gravity=[0, -1e300, 0]"], box),
        Case("gravity 1e4", ["--t-end", "0.01", "--set", "domain.gravity=[0, -1e4, 0]"], box,
             t_end=0.01),
        Case("temperature 1e300", ["--t-end", "0.01", "--set", "particles.0.temperature=1e300"], box),
        Case("temperature 1e4", ["--t-end", "0.005", "--set", "particles.0.temperature=1e4"], box,
             t_end=0.005),
        Case("mean velocity 1e100",
             ["--t-end", "0.01", "--set", "particles.0.velocity=[1e100, 0, 0]"], box),
        Case("density 1e-300", ["--t-end", "0.01", "--set", "materials.0.density=1e-300"], box),
        Case("density 0.1", ["--t-end", "0.01", "--set", "materials.0.density=0.1"], box,
             t_end=0.01),
        Case("diameter 1e-15", ["--t-end", "0.01", "--set", "particles.0.diameter=1e-15"], box),
        Case("domain +-1e300", ["--t-end", "0.01", "--set", "domain.lo=[-1e300, -1e300, -1e300]",
                                "--set", "domain.hi=[1e300, 1e300, 1e300]"], box),
        Case("tally cells 4096^3", ["--t-end", "0.01", "--set", "output.tally_cells=[4096, 4096, 4096]",
                                    "--set", "output.snapshot_interval=0.005"], box),
        Case("sample interval 1e-15", ["--t-end", "0.01", "--set", "output.sample_interval=1e-15"], box),
        Case("snapshot interval 1e-300", ["--t-end", "0.01", "--set", "output.snapshot_interval=1e-300"], box),
        Case("dt_flow 1e-300", ["--t-end", "0.01", "--set", "time.dt_flow=1e-300"], box),
        Case("t_end not a multiple of dt_flow", ["--t-end", "0.01234"], box, t_end=0.01234),
        Case("one flow step", ["--set", "time.t_end=0.003", "--set", "time.dt_flow=0.003"], box,
             t_end=0.003),
        Case("jet 1000 m/s with dt_flow 1e-2",
             ["--t-end", "0.1", "--set", "gas.jets.0.velocity=1000", "--set", "time.dt_flow=1e-2"], jet),
        Case("jet 1000 m/s at Courant 1",
             ["--t-end", "0.004", "--set", "gas.jets.0.velocity=1000", "--set", "time.dt_flow=2e-5"], jet),
        Case("gas cells smaller than particles",
             ["--t-end", "0.001", "--set", "gas.cells=[1000, 45, 1]"], jet),
        Case("gas bed with 1e-20 m particles",
             ["--t-end", "0.001", "--set", "particles.1.diameter=1e-20"], bed),
        Case("gas bed with 1 micron fines",
             ["--t-end", "0.002", "--set", "particles.1.diameter=1e-6",
              "--set", "particles.1.count=200"], bed, t_end=0.002),
        Case("gas pressure solve forced direct on a big grid",
             ["--t-end", "0.001", "--set", "gas.cells=[20, 60, 12]",
              "--set", "gas.pressure_solver=direct", "--set", "particles.0.diameter=0.0015"], bed),
    ]
    return cases


def other_command_cases():
    """Replay, analyse and bench with bad arguments or damaged inputs."""
    return [
        Case("replay a file that is not a log", ["replay", "{tmp}/junk.log"], None,
             cwd_files={"junk.log": b"EDPMLOG\0" + bytes(range(200))}),
        Case("replay --at -1 of a missing log", ["replay", "{tmp}/none.log", "--at", "-1"], None),
        Case("analyse a directory without snapshots", ["analyse", "{tmp}"], None),
        Case("analyse --bins 0", ["analyse", "{tmp}", "--bins", "0"], None),
        Case("analyse --cell-size 0", ["analyse", "{tmp}", "--cell-size", "0"], None),
        Case("bench --n 0", ["bench", "--n", "0"], None),
        Case("bench --phi 1", ["bench", "--phi", "1"], None),
        Case("bench --skin -1", ["bench", "--skin", "-1"], None),
    ]


def finite_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    for row in rows[1:]:
        for cell in row:
            try:
                v = float(cell)
            except ValueError:
                return f"{os.path.basename(path)}: non-numeric cell {cell!r}"
            if not math.isfinite(v):
                return f"{os.path.basename(path)}: non-finite value {cell}"
    return None


def check_outputs(out, t_end):
    """None when the outputs of a finished run are sane, else what is wrong."""
    try:
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
    except (OSError, ValueError) as e:
        return f"summary.json unreadable: {e}"
    if summary.get("status", "completed") != "completed":
        return f"exit 0 with status {summary.get('status')}"
    for key in ["kinetic_energy_translational", "kinetic_energy_rotational"]:
        v = summary.get(key)
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"summary.json: {key} = {v}"
    if t_end is not None and abs(summary["t_end"] - t_end) > 1e-9 * max(t_end, 1e-300):
        return f"ended at t = {summary['t_end']} s, not at t_end = {t_end} s"
    for name in ["timeseries.csv", "gas_timeseries.csv"]:
        path = os.path.join(out, name)
        if os.path.exists(path):
            problem = finite_csv(path)
            if problem:
                return problem
    if tomllib is None:
        return None
    with open(os.path.join(out, "scenario.toml"), "rb") as f:
        s = tomllib.load(f)
    lo, hi = s["domain"]["lo"], s["domain"]["hi"]
    planar = s["domain"].get("planar", False)
    bounds = s.get("boundaries", {})
    outlet = bounds.get("outlet", {}).get("axis")
    with open(os.path.join(out, "final_particles.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        r = float(row["radius_m"])
        for a, axis in enumerate("xyz"):
            x = float(row[f"{axis}_m"])
            if not math.isfinite(x) or not math.isfinite(float(row[f"v{axis}_m_s"])):
                return f"particle {row['id']}: non-finite state"
            tol = 1e-9 * max(abs(lo[a]), abs(hi[a]), r)
            if planar and axis == "z":
                continue
            if bounds.get(axis, "walls") == "periodic":
                ok = lo[a] - tol <= x <= hi[a] + tol
            else:
                upper = hi[a] + tol if outlet == axis else hi[a] - r * (1 - 1e-6) + tol
                ok = lo[a] + r * (1 - 1e-6) - tol <= x <= upper
            if not ok:
                return f"particle {row['id']} outside the domain along {axis}: {x}"
    return None


def classify(case, proc, out):
    err = proc.stderr
    if proc.returncode < 0 or "panicked at" in err or proc.returncode == 101 or \
            "memory allocation of" in err:
        line = next((l for l in err.splitlines() if "panicked" in l or "memory" in l), err[:200])
        return "panic", line.strip()
    lines = [l for l in err.splitlines() if l.startswith("edpm: error:")]
    if proc.returncode != 0:
        # Exit code 2: the argument parser's message, which names the option.
        if len(lines) == 1 or (proc.returncode == 2 and err.startswith("error:")):
            message = lines[0] if lines else err.strip().splitlines()[0]
            # It names what to change: the scenario file (with a field), an
            # option, a particle, or the file or directory given.
            tokens = [".toml", "--", "particle", ".log", "edpm-mutate-"]
            if proc.returncode == 2 or any(t in message for t in tokens):
                return "clear error", message
        return "unclear error", err.strip().replace("\n", " | ")[:300]
    if case.args and case.args[0] in ("replay", "analyse", "bench"):
        return "ran sane", proc.stdout.strip()[:120]
    problem = check_outputs(out, case.t_end)
    if problem:
        return "wrong result", problem
    return "ran sane", ""


def run_case(edpm, case, timeout):
    tmp = tempfile.mkdtemp(prefix="edpm-mutate-")
    try:
        for name, data in case.cwd_files.items():
            with open(os.path.join(tmp, name), "wb") as f:
                f.write(data)
        args = [a.replace("{tmp}", tmp) for a in case.args]
        out = os.path.join(tmp, "out")
        if args and args[0] in ("replay", "analyse", "bench"):
            cmd = [edpm] + args
        else:
            if case.text is not None:
                scenario = os.path.join(tmp, case.scenario)
                with open(scenario, "w") as f:
                    f.write(case.text)
            else:
                scenario = os.path.join(ROOT, "scenarios", case.scenario)
            cmd = [edpm, "run", scenario, "--quiet"]
            if "--out" not in args:
                cmd += ["--out", out]
            cmd += args
        start = time.monotonic()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                                  env={**os.environ, "RUST_BACKTRACE": "0"})
        except subprocess.TimeoutExpired:
            return "hang", f"no exit within {timeout} s", timeout
        outcome, detail = classify(case, proc, out)
        return outcome, detail.replace(tmp, "TMP"), time.monotonic() - start
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--edpm", default=os.path.join(ROOT, "target", "release", "edpm"))
    p.add_argument("--out", default=os.path.join(ROOT, "results", "robustness.md"))
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per case")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--seed", type=int, default=14)
    p.add_argument("--limit", type=int, default=None, help="run only the first N cases")
    opts = p.parse_args(argv[1:])
    if not os.path.exists(opts.edpm):
        print(f"{opts.edpm} not found: run `cargo build --release` first", file=sys.stderr)
        return 2

    rng = random.Random(opts.seed)
    cases = []
    for name in sorted(os.listdir(os.path.join(ROOT, "scenarios"))):
        if name.endswith(".toml"):
            with open(os.path.join(ROOT, "scenarios", name)) as f:
                cases += scenario_cases(rng, name, f.read())
    cases += command_line_cases() + other_command_cases()
    if opts.limit is not None:
        cases = cases[:opts.limit]

    start = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(max_workers=opts.jobs) as pool:
        results = list(pool.map(lambda c: run_case(opts.edpm, c, opts.timeout), cases))
    elapsed = time.monotonic() - start

    counts = {k: 0 for k in OUTCOMES}
    for outcome, _, _ in results:
        counts[outcome] += 1
    command = "python3 tools/mutate.py" + "".join(
        f" {a}" for a in argv[1:])
    lines = [
        "# Robustness: mutated scenarios and command lines",
        "",
        f"Produced by `{command}` (tools/mutate.py; seed {opts.seed}, "
        f"timeout {opts.timeout:g} s per case, {opts.jobs} jobs, {elapsed:.0f} s in total).",
        "Each case runs `edpm` on a mutated shipped scenario or command line for at most",
        f"{STEPS} flow steps; the categories are defined in the script's docstring.",
        "",
        "| tried | clear error | ran sane | panic | hang | wrong result | unclear error |",
        "|---:|---:|---:|---:|---:|---:|---:|",
        f"| {len(cases)} | " + " | ".join(str(counts[k]) for k in OUTCOMES) + " |",
        "",
        "## Cases",
        "",
        "| # | case | outcome | s | message or finding |",
        "|---:|---|---|---:|---|",
    ]
    for k, (case, (outcome, detail, seconds)) in enumerate(zip(cases, results)):
        detail = detail.replace("|", "\\|").replace("\n", " ")
        if len(detail) > 240:
            detail = detail[:237] + "..."
        lines.append(f"| {k + 1} | {case.name.replace('|', '/')} | {outcome} | {seconds:.1f} | {detail} |")
    os.makedirs(os.path.dirname(opts.out), exist_ok=True)
    tmp = opts.out + ".tmp"
    with open(tmp, "w") as f:
        f.write("\n".join(lines) + "\n")
    os.replace(tmp, opts.out)
    print(f"{len(cases)} cases: " + ", ".join(f"{counts[k]} {k}" for k in OUTCOMES) +
          f" ({elapsed:.0f} s); written to {opts.out}")
    bad = counts["panic"] + counts["hang"] + counts["wrong result"] + counts["unclear error"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
