"""The throughput benchmark of this tree beside another checkout's (a ``git worktree`` of
earlier code), in one run, alternating so that both see the same machine.

    git worktree add /tmp/before <rev>
    python -m benchmarks.compare /tmp/before [--rounds 2] [throughput args, e.g.
        --sizes 1024 4096 16384 --paths step step_and_maybe_reset]

Each round runs ``python -m benchmarks.throughput`` (each tree's own copy, from its own
directory, so each measures its own code) first in the other tree, then in this one. It
prints both tables of the paths' env-steps/s and, per N and path, the best over the rounds
and the ratio this tree / the other.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
# A row of throughput's paths table: "| N | mode | rate [low] | rate [low] (ratio) | ..."
ROW = re.compile(r"^\| ([\d,]+) \| (\w+) \| (.+) \|$")


def run(tree: Path, args: list[str]) -> str:
    """Throughput's printed output for ``tree`` (its own benchmarks, from its directory)."""
    done = subprocess.run([sys.executable, "-m", "benchmarks.throughput", *args], cwd=tree,
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"benchmarks.throughput failed in {tree}:\n{done.stderr[-2000:]}")
    return done.stdout


def rates(output: str, header: str) -> dict[tuple[int, str, str], float]:
    """{(N, mode, path): env-steps/s} from the paths table of throughput's ``output``; the
    paths' names from its ``header`` row."""
    lines = output.splitlines()
    start = lines.index(header)
    names = [c.strip().split(" env-steps/s")[0] for c in header.strip("|").split("|")[2:]]
    found = {}
    for line in lines[start + 2:]:
        match = ROW.match(line)
        if not match:
            break
        n, mode = int(match[1].replace(",", "")), match[2]
        for name, value in zip(names, match[3].split(" | "), strict=False):
            figure = value.split(" ")[0].replace(",", "")
            if figure.replace(".", "").isdigit():
                found[(n, mode, name)] = float(figure)
    return found


def paths_header(output: str) -> str:
    """The paths table's header row (the resets table's starts "| N | mode | step ms")."""
    return next(line for line in output.splitlines()
                if line.startswith("| N | mode | ") and not line.startswith("| N | mode | step ms"))


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.compare",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("other", type=Path, help="a checkout of the code to compare with")
    parser.add_argument("--rounds", type=int, default=2, help="runs of each tree, alternating")
    args, rest = parser.parse_known_args()
    if not (args.other / "benchmarks" / "throughput.py").is_file():
        parser.error(f"{args.other} holds no benchmarks/throughput.py (a torchpark checkout)")
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    best: dict[str, dict] = {"other": {}, "this": {}}
    for round_ in range(args.rounds):
        for name, tree in (("other", args.other), ("this", HERE)):
            output = run(tree, rest)
            print(f"## round {round_ + 1}, {name}: {tree}\n\n{output}", flush=True)
            for key, rate in rates(output, paths_header(output)).items():
                best[name][key] = max(rate, best[name].get(key, 0.0))
    print(f"## best of {args.rounds} rounds, env-steps/s (collector: frames/s)\n")
    print(f"| N | mode | path | {args.other} | this tree | this / other |")
    print("|---:|---|---|---:|---:|---:|")
    for key in sorted(best["this"]):
        if key in best["other"]:
            n, mode, path = key
            other, this = best["other"][key], best["this"][key]
            print(f"| {n:,} | {mode} | {path} | {other:,.0f} | {this:,.0f} | "
                  f"{this / other:.2f} |")


if __name__ == "__main__":
    main()
