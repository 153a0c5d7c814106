#!/usr/bin/env python3
"""Digest of every shipped scenario's outputs, to show that a change leaves
results bit-identical (refactors, speed work).

Runs each scenario in scenarios/ for a short time (and, where the scenario
allows it, with an event log), then prints one line per output file:
its SHA-256, with summary.json reduced to its non-timing fields first.
Compare the digests of two binaries:

    python3 tools/output_digest.py --edpm old/target/release/edpm > old.txt
    python3 tools/output_digest.py --edpm target/release/edpm > new.txt
    diff old.txt new.txt        # empty: bit-identical

Standard library only.
"""

import argparse
import hashlib
import json
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent

# Simulated time per scenario (s): long enough for collisions, inlet and
# outlet traffic, gas steps and a snapshot or two.
SHORT = {
    "bidisperse-bed": 0.05,
    "box-walls": 0.1,
    "bubbling-bed-ideal": 0.05,
    "bubbling-bed-jet": 0.05,
    "bubbling-bed-nonideal": 0.05,
    "fluidized-bed": 0.05,
    "hcs-3d": 0.16,
    "planar-bed": 0.1,
    "riser-circulating": 0.1,
    "riser-ideal": 0.05,
    "riser-nonideal": 0.05,
}

# Fields of summary.json that measure the machine, not the run.
TIMING = {"cpu_seconds", "wall_seconds", "wall_seconds_by_part", "events_per_cpu_second",
          "gas_cpu_seconds", "solver_cpu_seconds", "log_bytes"}


def strip_timing(value):
    if isinstance(value, dict):
        return {k: strip_timing(v) for k, v in value.items() if k not in TIMING}
    if isinstance(value, list):
        return [strip_timing(v) for v in value]
    return value


def digest(path: pathlib.Path) -> str:
    data = path.read_bytes()
    if path.name == "summary.json":
        data = json.dumps(strip_timing(json.loads(data)), sort_keys=True).encode()
    elif path.name == "run.json":
        # The log's path lies in this run's temporary directory: its name only.
        manifest = json.loads(data)
        if manifest.get("log"):
            manifest["log"] = pathlib.Path(manifest["log"]).name
        data = json.dumps(manifest, sort_keys=True).encode()
    return hashlib.sha256(data).hexdigest()


def run(edpm: str, scenario: pathlib.Path, out: pathlib.Path, log: bool) -> str:
    cmd = [edpm, "run", str(scenario), "--out", str(out), "--quiet",
           "--t-end", str(SHORT.get(scenario.stem, 0.05))]
    if log:
        cmd += ["--log", str(out.parent / f"{scenario.stem}.log")]
    r = subprocess.run(cmd, capture_output=True, text=True)
    return "" if r.returncode == 0 else r.stderr.strip().splitlines()[-1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edpm", default=str(ROOT / "target/release/edpm"))
    ap.add_argument("--only", nargs="*", help="scenario stems (default: all)")
    args = ap.parse_args()
    scenarios = sorted((ROOT / "scenarios").glob("*.toml"))
    if args.only:
        scenarios = [s for s in scenarios if s.stem in args.only]
    with tempfile.TemporaryDirectory() as tmp:
        for scenario in scenarios:
            out = pathlib.Path(tmp) / scenario.stem
            error = run(args.edpm, scenario, out, log=True)
            if error and "--log" in error or "log" in error.lower():
                # Runs the log cannot record yet: without it.
                error = run(args.edpm, scenario, out, log=False)
            if error:
                print(f"{scenario.stem}: ERROR {error}")
                continue
            files = sorted(p for p in out.rglob("*") if p.is_file())
            log = pathlib.Path(tmp) / f"{scenario.stem}.log"
            if log.exists():
                files.append(log)
            for f in files:
                name = f.relative_to(tmp) if f == log else f.relative_to(out.parent)
                print(f"{digest(f)}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
