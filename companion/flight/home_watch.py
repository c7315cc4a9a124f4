"""Watch the autopilot's home altitude during a flight: mission altitudes are relative to home, so when the autopilot
moves home, every later mission altitude moves with it.

Real PX4 does this on its own: for 120 s after take-off (commander ``HomePosition.cpp``, COM_HOME_EN 1, the default)
it shifts home's altitude by the barometer-vs-GPS difference whenever that exceeds 1 m. Over 11 PX4 SIH flights home
ended -1.51 .. +1.50 m off the true ground, and with home 1.51 m low the demo's strip bottoms (planned 1.55 m above
home) were 0.04 m above the ground: the drone flew into it (docs/FLIGHT.md). A real vehicle's home can move the same
way when its GPS and barometer disagree.

The reference is home's altitude at arming (the last HOME_POSITION before the vehicle was seen in the air): the
ground the vehicle took off from. Each move of more than ``HOME_MOVE_REPORT_M`` is said once; a move that brings the
lowest waypoint still ahead closer than ``MIN_GROUND_CLEARANCE_M`` to that ground ends the scan. Moves inside the
autopilot's correction window are expected (PX4 SIH makes 30+ of them while the plan holds), so each is said at DEBUG
(``-v``) and the window's net move once, as a warning, when it closes; a move outside the window is always a warning.

Flying while home may still move: the PX4 plan flies only waypoints at least home's largest move + 1 m above home in
the correction window (``planner.window_floor_m``: the strips' upper parts) and the part below after it, holding at
the last waypoint above when that part would come sooner (``planner.plan_scan``). While the autopilot may still move
home and the vehicle has not gone past that waypoint (``settling``), a move ends the scan only when it brings one of
the waypoints still ahead up to it under the minimum clearance (``check``); the part below is judged with home's
last position, the one it will be flown from. Once the window is over:

* when asked (``restore``: a SITL profile's ``restore_home``, ``sitl_profile.py``, e.g. PX4's SIH simulator) home
  is put back where it was at arming (``restore_step``): SIH's GPS altitude is the truth plus 0.5 m of white noise
  per sample (``sensor_gps_sim``) and PX4's correction takes one raw sample, so there the move is noise, not drift
  (the estimator averages the samples; the re-fly with home 1.51 m low flew its strip bottom 0.04 m above SIH's
  true ground). Never decided from what the vehicle looks like: on a real vehicle the correction follows the
  receiver's real, slowly varying altitude error, which the estimator follows too, so home is never moved back;
* otherwise, a move that leaves a waypoint ahead too near the ground ends the flight there, at the hold, high
  above the ground.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from companion.mission import items as mi
from companion.mission.planner import MIN_GROUND_CLEARANCE_M

log = logging.getLogger(__name__)

# A move smaller than this is within what the autopilot's own altitude estimate wanders; larger ones are said.
HOME_MOVE_REPORT_M = 0.3
# The lowest a waypoint still ahead may come to the take-off ground after home moved (``MIN_GROUND_CLEARANCE_M``,
# 1 m, shared with the planner). The demo's strip bottoms are planned 1.55 m above home; PX4 SIH's home ended up to
# 1.51 m low (ground contact at 0.04 m).
__all__ = ["MIN_GROUND_CLEARANCE_M", "HomeTooLow", "HomeWatch", "settle_item_seq"]
# PX4 stamps its take-off when its land detector sees it (about as mavsdk's in-air flag does); a home update
# streams at 0.5 Hz: the window counts as over this long after it should be.
SETTLE_SLACK_S = 3.0
# Smaller moves are not worth a command (the autopilot's own altitude estimate wanders more).
RESTORE_MIN_M = 0.05
# Putting home back is confirmed by HOME_POSITION, not by the command's ACK: sent without waiting for one (mavsdk
# 4.1 aborted the whole process, "std::future_error: Promise already satisfied", after an ACK it had given up on,
# on a loaded machine with real PX4 SIH), and sent again every RESTORE_WAIT_S of autopilot time, RESTORE_TRIES times.
RESTORE_MATCH_M = 0.05
RESTORE_WAIT_S = 5.0
RESTORE_TRIES = 3
# ... and never sooner than this many wall seconds after the last try: a simulator at speed-up 20 runs 5 s of autopilot
# time in 0.25 s of wall time, and on a loaded machine the HOME_POSITION that confirms the put-back can reach the
# companion later than that (one slow poll is 2 s of autopilot time). On a real vehicle autopilot and wall time run
# together, so this changes nothing there.
RESTORE_WAIT_WALL_S = 3.0
# Items whose altitude is above home and that the vehicle flies to (take-off, land and return are not scan heights).
_RELATIVE_FRAMES = {mi.MAV_FRAME_GLOBAL_RELATIVE_ALT, mi.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
_FLOWN_TO = {mi.MAV_CMD_NAV_WAYPOINT}


_NAV_ITEMS = {mi.MAV_CMD_NAV_TAKEOFF, mi.MAV_CMD_NAV_WAYPOINT, mi.MAV_CMD_NAV_LAND, mi.MAV_CMD_NAV_RETURN_TO_LAUNCH}


def settle_item_seq(items: Sequence[mi.MissionItem], waypoint_index: int) -> int:
    """The seq of the plan's waypoint ``waypoint_index`` among the items (one NAV item per waypoint, from the
    take-off; ArduPilot's home placeholder at seq 0 is not a waypoint); -1 when there is no such item."""
    nav = [it for it in items if it.command in _NAV_ITEMS
           and not (it.seq == 0 and it.frame == mi.MAV_FRAME_GLOBAL and it.command == mi.MAV_CMD_NAV_WAYPOINT)]
    return int(nav[waypoint_index].seq) if 0 <= waypoint_index < len(nav) else -1


@dataclass(frozen=True)
class HomeTooLow:
    """Home moved so far that a waypoint still ahead is too close to the take-off ground."""

    offset_m: float  # home now minus home at arming (up positive)
    seq: int  # the lowest waypoint still ahead
    planned_m: float  # its altitude above home as planned
    clearance_m: float  # where it now is above the take-off ground

    def problem(self, min_clearance_m: float) -> str:
        return (f"the autopilot moved home's altitude by {self.offset_m:+.2f} m during the flight, so waypoint "
                f"{self.seq} (planned {self.planned_m:.2f} m above home) would be flown {self.clearance_m:.2f} m "
                f"above the take-off ground, under the {min_clearance_m:g} m minimum: the scan ends here and the "
                f"vehicle returns to launch. Fix: raise the strip bottoms (the mission's scan margin) or let the "
                f"autopilot's home settle before the scan (PX4 corrects it for 120 s after take-off)")


class HomeWatch:
    """Fed HOME_POSITION altitudes and the flight state; says each move once and checks the waypoints ahead."""

    def __init__(self, items: Sequence[mi.MissionItem], *, report_m: float = HOME_MOVE_REPORT_M,
                 min_clearance_m: float = MIN_GROUND_CLEARANCE_M, window_s: float = 0.0, settle_seq: int = -1,
                 restore: bool = False, restore_wait_wall_s: float = RESTORE_WAIT_WALL_S,
                 wall_clock: Callable[[], float] = time.monotonic):
        """``window_s``: how long after take-off the autopilot may move home (PX4 120 s, ArduPilot 0);
        ``settle_seq``: the item the plan holds at until then (-1: none); ``restore``: put home back once the window
        is over (a SITL profile's ``restore_home``); ``restore_wait_wall_s``: the least wall time between two tries
        of it."""
        self.items = list(items)
        self.report_m = report_m
        self.min_clearance_m = min_clearance_m
        self.window_s = window_s
        self.settle_seq = settle_seq
        self.restore = restore
        self.restore_target_m: float | None = None  # where home is being put back (once the window is over)
        self.restore_sends = 0
        self._restore_sent_s: float | None = None
        self.restore_wait_wall_s = restore_wait_wall_s
        self._wall_clock = wall_clock
        self._restore_sent_wall: float | None = None
        self._moved_by_m = 0.0  # the move that was put back
        self.put_back = False  # the autopilot's home is where it was at arming again (confirmed by HOME_POSITION)
        self.restore_done = False  # put back, or given up after RESTORE_TRIES
        self.home_at_arming_m: float | None = None
        self.home_now_m: float | None = None
        self.airborne = False
        self._reported_offset_m = 0.0
        self.moves: list[float] = []  # every offset said, in order
        self.window_moves = 0  # moves said inside the correction window
        self.window_summarised = False

    def on_home(self, alt_amsl_m: float, *, in_window: bool = False) -> None:
        """A HOME_POSITION altitude. Before the vehicle is in the air it is the reference (home at arming).
        ``in_window``: the autopilot's correction window is open, so a move is expected and said at DEBUG."""
        if not math.isfinite(alt_amsl_m):
            return
        self.home_now_m = alt_amsl_m
        if not self.airborne:
            self.home_at_arming_m = alt_amsl_m
            return
        offset = self.offset_m
        target = self.restore_target_m
        if target is not None and abs(alt_amsl_m - target) < RESTORE_MATCH_M:
            return  # the put-back, said by restore_step
        if offset is not None and abs(offset - self._reported_offset_m) > self.report_m:
            self._reported_offset_m = offset
            self.moves.append(offset)
            if in_window:
                self.window_moves += 1
            log.log(logging.DEBUG if in_window else logging.WARNING,
                    "the autopilot moved home's altitude by %+.2f m during the flight (now %.2f m AMSL, %.2f m "
                    "at arming): every later mission altitude moved with it", offset, alt_amsl_m,
                    self.home_at_arming_m)

    def summarise_window(self, since_takeoff_s: float | None) -> None:
        """Once the correction window is over: its net move, said once as a warning (each move inside it was said at
        DEBUG)."""
        if (self.window_summarised or self.window_s <= 0 or not self.airborne or since_takeoff_s is None
                or self.window_open(since_takeoff_s)):
            return
        self.window_summarised = True
        offset = self.offset_m or 0.0
        if self.window_moves == 0 and abs(offset) <= self.report_m:
            return
        log.warning("the autopilot's %g s home correction window is over: home moved %d time%s in it (each at debug "
                    "level, -v) and is now %+.2f m from where it was at arming%s", self.window_s, self.window_moves,
                    "" if self.window_moves == 1 else "s", offset,
                    " (to be put back: the SITL profile's restore_home)"
                    if self.restore and abs(offset) >= RESTORE_MIN_M else
                    ": every later mission altitude moved with it")

    def on_airborne(self) -> None:
        self.airborne = True

    @property
    def offset_m(self) -> float | None:
        if self.home_at_arming_m is None or self.home_now_m is None:
            return None
        return self.home_now_m - self.home_at_arming_m

    def window_open(self, since_takeoff_s: float | None) -> bool:
        """Whether the autopilot may still move home (None: take-off time not known yet)."""
        if self.window_s <= 0:
            return False
        return since_takeoff_s is None or since_takeoff_s < self.window_s + SETTLE_SLACK_S

    def settling(self, current_seq: int, since_takeoff_s: float | None) -> bool:
        """Nothing ends yet: home may still move and the vehicle has not left the hold before the scan, or (asked for
        by a SITL profile) home is being put back. A put-back pending counts even after the vehicle left the hold:
        the companion sees the window's end one poll late, and at a simulator speed-up of 20 on a loaded machine one
        poll was enough for the vehicle to leave the 5 s slack of its hold and the flight ended with a put-back
        already on its way.
        The put-back is confirmed or given up within RESTORE_TRIES x RESTORE_WAIT_S (15 s) of autopilot time, less
        than the descent from the hold to the first strip bottom takes (18 m at the 0.72 m/s the flight sets); in a
        simulator at a speed-up, within RESTORE_TRIES x RESTORE_WAIT_WALL_S of wall time (the simulator takes the
        put-back at once: only its confirmation can be late)."""
        if self.restore_target_m is not None and not self.restore_done:
            return True
        return self.window_open(since_takeoff_s) and 0 <= current_seq <= self.settle_seq

    def restore_step(self, since_takeoff_s: float | None) -> float | None:
        """Asked for (``restore``), after the window: the altitude to send home to now (home at arming), or None
        (not due, sent recently, confirmed, or given up). Confirmation and giving up are said here."""
        if not self.restore or self.restore_done or not self.airborne or since_takeoff_s is None:
            return None
        offset = self.offset_m
        if self.restore_target_m is None:
            if offset is None or self.window_open(since_takeoff_s) or abs(offset) < RESTORE_MIN_M:
                return None
            self.restore_target_m = self.home_at_arming_m
            self._moved_by_m = offset
        target = self.restore_target_m
        if self.home_now_m is not None and abs(self.home_now_m - target) < RESTORE_MATCH_M:
            self.restore_done = self.put_back = True
            self._reported_offset_m = self.offset_m or 0.0
            log.warning("SITL profile: home is back at %.2f m AMSL, where it was at arming (the autopilot had moved "
                        "it by %+.2f m in its %g s correction window; put back as the profile's restore_home asks)",
                        target, self._moved_by_m, self.window_s)
            return None
        waited = self._restore_sent_s is None or (
            since_takeoff_s - self._restore_sent_s >= RESTORE_WAIT_S
            and self._wall_clock() - self._restore_sent_wall >= self.restore_wait_wall_s)
        if not waited:
            return None
        if self.restore_sends >= RESTORE_TRIES:
            self.restore_done = True
            log.error("the vehicle did not put home back at %.2f m AMSL (asked %d times; home is %+.2f m off): the "
                      "home watch decides with the moved home", target, self.restore_sends, offset or 0.0)
            return None
        self.restore_sends += 1
        self._restore_sent_s = since_takeoff_s
        self._restore_sent_wall = self._wall_clock()
        return target

    def check(self, current_seq: int, since_takeoff_s: float | None) -> HomeTooLow | None:
        """What ends the scan now, if anything: while ``settling``, a waypoint up to the settle item (those flown
        while home may still move) under the minimum clearance; after it, any waypoint still ahead."""
        if self.settling(current_seq, since_takeoff_s):
            return self.too_low(current_seq, until_seq=self.settle_seq)
        return self.too_low(current_seq)

    def too_low(self, current_seq: int, until_seq: int | None = None) -> HomeTooLow | None:
        """The lowest waypoint from ``current_seq`` on (up to ``until_seq``), when home's move puts it under the
        minimum clearance."""
        offset = self.offset_m
        if offset is None or not self.airborne:
            return None
        last = len(self.items) if until_seq is None else until_seq + 1
        ahead = [it for it in self.items[max(0, current_seq):last]
                 if it.command in _FLOWN_TO and it.frame in _RELATIVE_FRAMES]
        if not ahead:
            return None
        lowest = min(ahead, key=lambda it: it.z)
        clearance = lowest.z + offset
        # only the move's doing: a plan that itself flies lower than the minimum is the planner's decision
        if clearance >= self.min_clearance_m or clearance > lowest.z - self.report_m:
            return None
        return HomeTooLow(offset, int(lowest.seq), float(lowest.z), clearance)
