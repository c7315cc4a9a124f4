"""Time tests in two or more checkouts side by side, in one run: wall seconds per test and CPU seconds per checkout.

    python bench/test_time.py --checkout before=/tmp/ts/main --checkout after=. --repeat 2 \\
        tests/test_onboard_crash.py tests/test_onboard_sitl.py

Each repeat runs pytest on the same tests in every checkout in turn (alternating, so a change in the machine's load
hits both), with that checkout first on PYTHONPATH and this interpreter. Wall time per test comes from pytest's
JUnit report (call + setup + teardown); CPU is user + system time of pytest and every process it started and waited
for (the simulator, the camera, the companion CLI), which a busy shared machine disturbs far less than wall time.
The load average is printed beside each run: SITL tests fly in simulated time, so their wall time on a loaded machine
is set by the speed-up and by how long process start-ups take there.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"


def run_once(checkout: Path, tests: list[str], report: Path) -> tuple[float, float, int, dict[str, float]]:
    """(wall s, CPU s, pytest's exit code, wall s per test id) of one pytest run in ``checkout``."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [sys.executable, "-m", "pytest", *tests, "-q", "-p", "no:cacheprovider", f"--junitxml={report}"]
    cpu0, t0 = _children_cpu_s(), time.monotonic()
    rc = subprocess.run(cmd, cwd=checkout, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    wall, cpu = time.monotonic() - t0, _children_cpu_s() - cpu0
    per_test = {}
    for case in ET.parse(report).iter("testcase"):
        name = f"{case.get('classname', '').rsplit('.', 1)[-1]}::{case.get('name')}"
        failed = case.find("failure") is not None or case.find("error") is not None
        per_test[name + (" (FAILED)" if failed else "")] = float(case.get("time", "nan"))
    return wall, cpu, rc, per_test


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tests", nargs="+", help="pytest node ids or files, relative to each checkout")
    ap.add_argument("--checkout", action="append", required=True, metavar="NAME=DIR",
                    help="a checkout to time (give two or more)")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    checkouts = [(name, Path(path).resolve()) for name, path in (c.split("=", 1) for c in args.checkout)]
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; tests: {' '.join(args.tests)}")
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for name, path in checkouts:
                load_before = _load()
                wall, cpu, rc, per_test = run_once(path, args.tests, Path(tmp) / f"{name}-{k}.xml")
                print(f"\nrun {k + 1} {name} ({path}): wall {wall:.1f} s, CPU {cpu:.1f} s, pytest exit {rc}, "
                      f"load {load_before} -> {_load()}")
                for test, seconds in per_test.items():
                    print(f"  {seconds:7.1f} s  {test}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
