#!/usr/bin/env python3
"""Runs every benchmark of a Google Benchmark program once (the shortest
run the library allows) and fails if the program fails, reports an error,
runs no benchmark, or, with --counter NAME (repeatable), a benchmark has
none of the counters named with a positive value (a collision scene that no
longer collides measures nothing; nor does a pile of boxes in which the
broad phase finds no pair).

    bench/smoke_test.py PROGRAM [--counter NAME ...]

Registered with CTest (label bench) by bench/CMakeLists.txt: the suite then
catches a benchmark program that crashes or whose scenes went wrong. It
says nothing about speed; see docs/performance.md for that."""
import argparse
import json
import subprocess
import sys


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("program")
    parser.add_argument("--counter", action="append", default=[],
                        help="a counter to check (repeatable): every benchmark must report "
                             "one of the counters named with a value > 0")
    args = parser.parse_args()
    run = subprocess.run([args.program, "--benchmark_min_time=0.000001", "--benchmark_format=json"],
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"error: {args.program} exited with status {run.returncode}:\n{run.stderr}")
    benchmarks = json.loads(run.stdout)["benchmarks"]
    if not benchmarks:
        sys.exit(f"error: {args.program} ran no benchmark")
    failed = []
    for b in benchmarks:
        if b.get("error_occurred"):
            failed.append(f"{b['name']}: {b.get('error_message', 'error')}")
        elif args.counter and not any(b.get(name, 0) > 0 for name in args.counter):
            values = ", ".join(f"{name} = {b.get(name)}" for name in args.counter)
            failed.append(f"{b['name']}: {values}, expected one > 0")
    if failed:
        sys.exit("error: " + "\n  ".join([f"{len(failed)} of {len(benchmarks)} benchmarks:"] + failed))
    print(f"{len(benchmarks)} benchmarks ran")


if __name__ == "__main__":
    main()
