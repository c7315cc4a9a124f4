"""Review plot of a plan: front view on the facade plane and top view, as PNG bytes."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from companion.mission.geometry import footprint_enu  # noqa: E402
from companion.mission.planner import ScanPlan  # noqa: E402


def plot_png(plan: ScanPlan, dpi: int = 110) -> bytes:
    m = plan.mission
    fp = plan.footprint
    wps = plan.waypoints
    fig, (front, top) = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [1.6, 1]})

    # Front view: the wall as the camera sees it, path projected on the facade plane.
    front.add_patch(Rectangle((0, 0), plan.frame.length_m, m.facade.height_m, color="0.85", label="wall"))
    along = np.array([w.along_m for w in wps])
    up = np.array([w.up_m for w in wps])
    near = np.array([abs(w.out_m - m.standoff_m) < 0.06 for w in wps])
    front.plot(along[near], up[near], "-", color="tab:red", lw=1.2, label="path at standoff")
    for i, j in plan.scan_legs[:1]:
        n = max(2, plan.estimates.expected_keyframes // max(len(plan.scan_legs), 1))
        for t in np.linspace(0, 1, n):
            a = along[i] + t * (along[j] - along[i])
            z = up[i] + t * (up[j] - up[i])
            front.add_patch(
                Rectangle(
                    (a - fp.width_m / 2, z - fp.height_m / 2),
                    fp.width_m,
                    fp.height_m,
                    fill=False,
                    ec="tab:blue",
                    lw=0.5,
                    alpha=0.6,
                )
            )
    front.plot([], [], color="tab:blue", lw=0.5, label="keyframe footprints (strip 1)")
    front.plot(along[1], up[1], "k^", label="entrance")
    front.set_xlabel("along wall from start (m)")
    front.set_ylabel("height above wall base (m)")
    front.set_title(f"{m.name}: front view ({m.pattern} strips, {plan.estimates.strips} strips)")
    front.set_aspect("equal")
    front.legend(loc="upper right", fontsize=7)
    front.grid(alpha=0.3)

    # Top view: ENU around the wall start.
    e, n, _ = plan.frame.facade_to_enu(along, np.array([w.out_m for w in wps]), up)
    we, wn, _ = plan.frame.facade_to_enu(np.array([0.0, plan.frame.length_m]), 0.0, 0.0)
    poly = footprint_enu(m, plan.frame.origin)
    if poly is not None:
        ring = np.vstack([poly, poly[:1]])
        top.fill(ring[:, 0], ring[:, 1], color="0.85", label="building")
    top.plot(we, wn, "k-", lw=3, label="wall")
    top.plot(e, n, "-", color="tab:red", lw=1, label="path")
    top.plot(e[0], n[0], "g^", label="takeoff")
    oe, on = plan.frame.out_enu
    mid = np.array([we.mean(), wn.mean()])
    top.annotate("", xy=mid + 3 * np.array([oe, on]), xytext=mid, arrowprops={"arrowstyle": "->"})
    top.text(*(mid + 3.5 * np.array([oe, on])), "drone side", fontsize=7)
    top.set_xlabel("east (m)")
    top.set_ylabel("north (m)")
    top.set_title("top view")
    top.set_aspect("equal")
    top.legend(loc="best", fontsize=7)
    top.grid(alpha=0.3)

    est = plan.estimates
    fig.suptitle(
        f"path {est.path_length_m:.0f} m, ~{est.flight_time_s / 60:.1f} min, scan {est.scan_speed_m_s:.2f} m/s, "
        f"GSD {est.gsd_mm_per_px:.2f} mm/px, ~{est.expected_keyframes} keyframes at {m.overlap:.0%} overlap",
        fontsize=9,
    )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
