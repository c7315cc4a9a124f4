"""PX4's in-flight home moves: real PX4 SIH flights (their own logs) beside the simulator's PX4 flavour, side by side.

    PYTHONPATH=. python bench/home_moves.py [--seeds 200]

Real: every home_position update within 125 s of take-off in the 18 SIH flights of tests/data/real-px4-sih-home.json
that lasted the whole window. Simulator: sim/vehicle/home_drift.py on a demo-like climb to 18 m and hover, one
flight per seed. Prints, per side, the median and range of the number of moves, the lowest and highest home offset
in flight, and the final offset (with its standard deviation).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sim.vehicle.home_drift import hover_flight

REAL = Path(__file__).resolve().parents[1] / "tests/data/real-px4-sih-home.json"
COLUMNS = ("moves", "lowest m", "highest m", "final m")


def summary(rows: np.ndarray) -> list[str]:
    return [f"{np.median(c):.2f} [{c.min():.2f} .. {c.max():.2f}]" for c in rows.T]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=200, help="simulated flights (one per seed)")
    a = p.parse_args(argv)
    flights = [f for f in json.loads(REAL.read_text())["flights"] if f["full_window"]]
    real = np.array([[f["moves"], f["lowest_m"], f["highest_m"], f["final_m"]] for f in flights])
    t0 = time.process_time()
    sim = np.array([hover_flight(seed) for seed in range(a.seeds)])
    cpu = time.process_time() - t0
    print(f"{'':22s}" + "".join(f"{c:>26s}" for c in COLUMNS) + f"{'final std m':>14s}")
    for name, rows in ((f"real PX4 SIH ({len(real)})", real), (f"simulator ({a.seeds} seeds)", sim)):
        print(f"{name:22s}" + "".join(f"{s:>26s}" for s in summary(rows)) + f"{np.std(rows[:, 3]):14.2f}")
    print(f"(median [min .. max]; simulator {cpu:.1f} s CPU)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
