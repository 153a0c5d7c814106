#!/usr/bin/env python3
"""Functions in src/ longer than a limit (default 150 lines, signature to
closing brace), for the function-size rule of issue 10.

A long function passes when the comment block right above it (doc comment
or attributes) contains "Long function:" followed by the reason; the
others are listed and the exit status is 1. Unit-test modules are left out.

    python3 tools/function_lengths.py            # check
    python3 tools/function_lengths.py --all 80   # every function over 80 lines

Standard library only.
"""

import argparse
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
FN = re.compile(r"^(\s*)(pub(\([^)]*\))?\s+)?(const\s+)?(unsafe\s+)?fn\s+(\w+)")


def functions(path: pathlib.Path):
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines):
        if line.strip() == "#[cfg(test)]":
            break
        m = FN.match(line)
        if not m:
            continue
        indent = m.group(1)
        # The body ends at the first line that is "}" at the fn's indent;
        # a declaration without body (trait method) ends with ";".
        end = None
        for j in range(i, len(lines)):
            if j == i and lines[j].rstrip().endswith(";"):
                break
            if lines[j] == indent + "}":
                end = j
                break
            if j > i and lines[j].startswith(indent + "fn ") and lines[j - 1].rstrip().endswith(";"):
                break
        if end is None:
            continue
        k = i - 1
        above = []
        while k >= 0 and (lines[k].strip().startswith("//") or lines[k].strip().startswith("#[")):
            above.append(lines[k])
            k -= 1
        yield m.group(6), i + 1, end - i + 1, "\n".join(above)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=150)
    ap.add_argument("--all", type=int, metavar="N",
                    help="list every function over N lines, argued or not")
    args = ap.parse_args()
    unargued = 0
    for path in sorted((ROOT / "src").rglob("*.rs")):
        for name, line, length, above in functions(path):
            rel = path.relative_to(ROOT)
            argued = "Long function:" in above
            if args.all is not None and length > args.all:
                print(f"{length:5} {rel}:{line} {name}{'  (argued)' if argued else ''}")
            elif args.all is None and length > args.limit and not argued:
                print(f"{length:5} {rel}:{line} {name}: over {args.limit} lines, no 'Long function:' comment")
                unargued += 1
    return 1 if unargued else 0


if __name__ == "__main__":
    sys.exit(main())
