"""Flight progress for a person: waypoints of the scan, not raw mission items.

Why: DO items (gimbal, speed) complete instantly, so an item counter jumps (1 -> 5 -> 7) and says nothing about how
much of the scan is flown. And a progress bar redrawn ten times a second into a log file (stderr not a terminal)
is 150 KB of noise per flight: there, one plain line per waypoint reached.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from companion.mission import items as mi
from companion.progress import progress_bar

log = logging.getLogger(__name__)

_NAV_END = 100  # MAV_CMD values below this are NAV commands (positions); DO/CONDITION commands are above


def navigation_seqs(items: Sequence[mi.MissionItem], first_seq: int = 0) -> list[int]:
    """Seqs of the items that move the vehicle (takeoff, waypoints, land, RTL), from ``first_seq`` on."""
    return [it.seq for it in items if it.seq >= first_seq and it.command < _NAV_END]


def waypoints_done(nav_seqs: Sequence[int], current_seq: int, total_items: int) -> int:
    """Waypoints finished when the vehicle works on ``current_seq`` (all of them once the mission is done)."""
    if current_seq >= total_items:
        return len(nav_seqs)
    return sum(1 for s in nav_seqs if s < current_seq)


class WaypointProgress:
    """A tqdm bar of waypoints on a terminal; otherwise one log line each time the count changes (and the final
    count at the end, when that is new): a pilot reading the log sees each waypoint once, not the same line every
    few seconds while a long leg is flown. Disabled: nothing."""

    def __init__(self, items: Sequence[mi.MissionItem], first_seq: int = 0, *, enabled: bool = True,
                 terminal: bool | None = None):
        self.nav = navigation_seqs(items, first_seq)
        self.total_items = len(items)
        self.enabled = enabled
        self.terminal = sys.stderr.isatty() if terminal is None else terminal
        self.done = 0
        self._said: int | None = None  # the count the last log line gave
        self._bar = None
        if enabled and self.terminal:
            self._bar = progress_bar(total=len(self.nav), unit="wp", desc="waypoints", leave=True)

    @property
    def total(self) -> int:
        return len(self.nav)

    def update(self, reached_items: int, detail: str = "") -> int:
        """``reached_items``: mission items completed (the current seq). Returns waypoints done."""
        self.done = waypoints_done(self.nav, reached_items, self.total_items)
        if not self.enabled:
            return self.done
        if self._bar is not None:
            if self._bar.n != self.done:
                self._bar.n = self.done
                self._bar.refresh()
            return self.done
        if self.done != self._said:
            self._said = self.done
            log.info("progress: waypoint %d/%d%s", self.done, self.total, f", {detail}" if detail else "")
        return self.done

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self.enabled and self.done != self._said:
            self._said = self.done
            log.info("progress: waypoint %d/%d", self.done, self.total)
