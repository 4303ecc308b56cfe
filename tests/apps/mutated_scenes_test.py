#!/usr/bin/env python3
"""Runs `tetcosim run` on bundled scenes with one thing changed at random
(seeded): an attribute set to a bad or extreme value, removed, or added, or
an element removed or repeated. Whatever the change, the run must either

  - succeed: exit 0 and a summary.json whose status is "ok" and whose
    numbers are all finite; or
  - fail cleanly: exit 1 with a last line "tetcosim: error: <why>" on
    stderr (a diverged run also writes summary.json, status "diverged");

and never crash (a signal), hang (the timeout), exit with an internal error
(3), or leave a sanitizer report on stderr.

    tests/apps/mutated_scenes_test.py TETCOSIM [--cases N] [--seed S] [--keep DIR]

Registered with CTest (label unit) by tests/CMakeLists.txt, so the
sanitizer build of CI runs it too. Cases that fail are listed with what was
changed; --keep DIR keeps every case's scene there to repeat one."""
import argparse
import json
import math
import os
import random
import shutil
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
# small scenes that load and step quickly, with every kind of <deformable>
# child: tetbody (shapes and mesh files), rigidtet, attach, contact, solver
SCENES = [
    "models/scenes/cube_on_box.xml",
    "models/scenes/block_and_box.xml",
    "models/scenes/paddle.xml",
    "models/scenes/gripper.xml",
    "models/scenes/terrain.xml",
    "models/scenes/strap.xml",
    "models/paper/cubes.xml",
    "models/paper/rigid.xml",
    "models/paper/mixed.xml",
]
VALUES = [
    "nan", "inf", "-inf", "-1", "0", "-0", "1e308", "-1e308", "1e-308", "1e400", "", " ",
    "abc", "1 2", "1 2 3 4 5", "nan nan nan", "1 nan 1", "0 0 0", "1,2,3", "0x10", "1e",
    "99999999999999999999", "2147483648", "-2147483649", "3.5", "100000",
    "missing.msh", "../..", "/",
]
NAMES = [
    "size", "resolution", "split", "young", "poisson", "density", "damping", "pos", "euler",
    "quat", "scale", "vel", "shape", "file", "name", "body", "geom", "tetbody", "vertices", "box",
    "sphere", "stiffness", "method", "friction", "substeps", "tolerance", "maxiter", "rigid",
    "autoproxy", "bogus",
]
STEPS = 30
TIMEOUT_S = 300


def mutate(root, rng):
    """Changes one thing in the scene; returns what, for the report."""
    deformable = root.find("deformable")
    pool = list(deformable.iter()) if rng.random() < 0.85 else list(root.iter())
    element = rng.choice(pool)
    kind = rng.random()
    if kind < 0.55 and element.attrib:
        name, value = rng.choice(sorted(element.attrib)), rng.choice(VALUES)
        element.set(name, value)
        return f"<{element.tag}> {name}={value!r}"
    if kind < 0.7 and element.attrib:
        name = rng.choice(sorted(element.attrib))
        del element.attrib[name]
        return f"<{element.tag}> without {name}"
    if kind < 0.85:
        name, value = rng.choice(NAMES), rng.choice(VALUES)
        element.set(name, value)
        return f"<{element.tag}> added {name}={value!r}"
    children = [c for c in deformable]
    child = rng.choice(children)
    if kind < 0.93:
        deformable.remove(child)
        return f"<{child.tag}> removed"
    deformable.append(ET.fromstring(ET.tostring(child)))
    return f"<{child.tag}> repeated"


def finite_numbers(value):
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(finite_numbers(v) for v in value.values())
    if isinstance(value, list):
        return all(finite_numbers(v) for v in value)
    return value is not None


def reject_constant(name):
    raise ValueError(f"{name} in summary.json")


def check(binary, scene_path, out):
    """Runs one case; returns (what went wrong or None, "ran" or "failed
    cleanly")."""
    try:
        run = subprocess.run([binary, "run", scene_path, "--steps", str(STEPS), "--out", out],
                             capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return f"no answer within {TIMEOUT_S} s", None
    stderr = run.stderr or ""
    if "Sanitizer" in stderr or "runtime error:" in stderr:
        return "sanitizer report:\n" + stderr[-2000:], None
    lines = stderr.strip().splitlines()
    last = lines[-1] if lines else ""
    if run.returncode not in (0, 1):
        return f"exit status {run.returncode}: {last}", None
    summary_path = os.path.join(out, "summary.json")
    if run.returncode == 1:
        if not last.startswith("tetcosim: error: ") or len(last) < len("tetcosim: error: ") + 10:
            return f"exit 1 without a clear error on the last line: {last!r}", None
        return None, "failed cleanly"
    try:
        with open(summary_path) as f:
            summary = json.load(f, parse_constant=reject_constant)
    except (OSError, ValueError) as e:
        return f"exit 0 but no valid summary.json: {e}", None
    if summary.get("status") != "ok":
        return f"exit 0 with status {summary.get('status')!r}", None
    if not finite_numbers(summary):
        return "exit 0 with a number in summary.json that is not finite (or null)", None
    return None, "ran"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("binary")
    parser.add_argument("--cases", type=int, default=40)
    parser.add_argument("--seed", type=int, default=2004)
    parser.add_argument("--keep", help="a folder to keep every case's scene in")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    failures = []
    outcomes = {"ran": 0, "failed cleanly": 0}
    with tempfile.TemporaryDirectory(prefix="tetcosim-mutated-") as tmp:
        cases_dir = args.keep or tmp
        os.makedirs(cases_dir, exist_ok=True)
        for case in range(args.cases):
            scene = SCENES[case % len(SCENES)]
            source = os.path.join(ROOT, scene)
            tree = ET.parse(source)
            change = mutate(tree.getroot(), rng)
            # the case sits in another folder: mesh files stay where they were
            for element in tree.getroot().iter():
                file = element.get("file")
                if file and file not in VALUES and not os.path.isabs(file):
                    element.set("file", os.path.join(os.path.dirname(source), file))
            path = os.path.join(cases_dir, f"case{case:03d}.xml")
            tree.write(path)
            out = os.path.join(tmp, "out")
            shutil.rmtree(out, ignore_errors=True)
            problem, outcome = check(args.binary, path, out)
            if problem:
                failures.append(f"case {case} ({scene}, {change}): {problem}")
            else:
                outcomes[outcome] += 1
    if failures:
        sys.exit(f"error: {len(failures)} of {args.cases} changed scenes misbehaved:\n  " +
                 "\n  ".join(failures))
    print(f"{args.cases} changed scenes: {outcomes['ran']} ran, "
          f"{outcomes['failed cleanly']} failed with a clear error")


if __name__ == "__main__":
    main()
