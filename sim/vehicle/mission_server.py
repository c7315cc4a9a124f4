"""Vehicle side of the MAVLink mission protocol (upload, download, clear) with MISSION_ITEM_INT.

It survives a lossy link the way PX4's does: it re-requests an item when none arrives in time, answers
duplicates, re-sends the final ACK if the GCS repeats the last item, and aborts after a few silent retries.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # common + ArduPilot messages

from companion.mission.items import MissionItem

log = logging.getLogger(__name__)

RETRY_S = 0.25  # wall seconds without the requested item before asking again
MAX_RETRIES = 10


@dataclass
class _Upload:
    partner: tuple[int, int]
    count: int
    mission_type: int
    items: list[MissionItem] = field(default_factory=list)
    last_request: float = 0.0
    retries: int = 0


def item_from_msg(msg) -> MissionItem:
    return MissionItem(seq=msg.seq, frame=msg.frame, command=msg.command, current=msg.current,
                       autocontinue=msg.autocontinue, param1=msg.param1, param2=msg.param2, param3=msg.param3,
                       param4=msg.param4, x=msg.x, y=msg.y, z=msg.z, mission_type=msg.mission_type)


def _current_is_first(items: list[MissionItem]) -> list[MissionItem]:
    return [MissionItem(it.seq, it.frame, it.command, 1 if k == 0 else 0, it.autocontinue, it.param1, it.param2,
                        it.param3, it.param4, it.x, it.y, it.z, it.mission_type) for k, it in enumerate(items)]


class MissionServer:
    """Holds the vehicle's mission, geofence and rally lists and serves the transfer protocol.

    ``validate(item, index)`` returns None or a MAV_MISSION_RESULT error code; ``on_new_mission(items)`` is
    called when an upload of the mission list completes (also for a clear, with an empty list).
    ``transform_upload`` turns the uploaded list into what the firmware stores (and flies);
    ``transform_download`` into what it hands back, ``current`` flags included.
    """

    def __init__(self, mav: mavlink.MAVLink, send: Callable[[object], None],
                 validate: Callable[[MissionItem, int], int | None], on_new_mission: Callable[[list], None],
                 max_items: int = 500, transform_upload: Callable[[list], list] | None = None,
                 transform_download: Callable[[list], list] | None = None,
                 on_too_many: Callable[[int], None] | None = None,
                 on_invalid_item: Callable[[int], None] | None = None):
        self.mav = mav
        self.on_too_many = on_too_many  # told the limit after a too-large MISSION_COUNT was refused
        self.on_invalid_item = on_invalid_item  # told the result code before an item is refused
        self.send = send
        self.validate = validate
        self.on_new_mission = on_new_mission
        self.max_items = max_items
        self.transform_upload = transform_upload or (lambda items: items)
        self.transform_download = transform_download or _current_is_first
        self.lists: dict[int, list[MissionItem]] = {0: [], 1: [], 2: []}
        self._upload: _Upload | None = None
        self._completed: tuple[tuple[int, int], int, int] | None = None  # partner, count, type of last upload

    # --- incoming messages -------------------------------------------------------------------------
    def handle(self, msg) -> bool:
        """Process one message; returns True if it was a mission-protocol message."""
        t = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if t == "MISSION_COUNT":
            self._on_count(src, msg)
        elif t == "MISSION_ITEM_INT":
            self._on_item(src, msg)
        elif t == "MISSION_ITEM":
            # Float lat/lon items lose precision; PX4 accepts them, we insist on the INT protocol.
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, msg.mission_type)
        elif t == "MISSION_REQUEST_LIST":
            items = self.transform_download(list(self.lists.get(msg.mission_type, [])))
            self.send(self.mav.mission_count_encode(src[0], src[1], len(items), msg.mission_type))
        elif t in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._on_request(src, msg)
        elif t == "MISSION_CLEAR_ALL":
            self.lists[msg.mission_type] = []
            self._upload = None
            if msg.mission_type == 0:
                self.on_new_mission([])
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, msg.mission_type)
        elif t == "MISSION_ACK":
            pass  # end of a download: nothing to do
        else:
            return False
        return True

    def _ack(self, dst, result: int, mission_type: int) -> None:
        self.send(self.mav.mission_ack_encode(dst[0], dst[1], result, mission_type))

    def _on_count(self, src, msg) -> None:
        if msg.mission_type not in self.lists:
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, msg.mission_type)
            return
        if msg.count > self.max_items:
            log.info("mission upload refused: %d items > %d", msg.count, self.max_items)
            self._ack(src, mavlink.MAV_MISSION_NO_SPACE, msg.mission_type)
            if self.on_too_many is not None:
                self.on_too_many(self.max_items)
            return
        if msg.count == 0:
            self.lists[msg.mission_type] = []
            if msg.mission_type == 0:
                self.on_new_mission([])
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, msg.mission_type)
            return
        self._upload = _Upload(partner=src, count=msg.count, mission_type=msg.mission_type)
        self._completed = None
        self._request(0)

    def _request(self, seq: int) -> None:
        up = self._upload
        assert up is not None
        up.last_request = time.monotonic()
        self.send(self.mav.mission_request_int_encode(up.partner[0], up.partner[1], seq, up.mission_type))

    def _on_item(self, src, msg) -> None:
        up = self._upload
        if up is None or up.partner != src or msg.mission_type != up.mission_type:
            done = self._completed
            if done and done[0] == src and msg.seq == done[1] - 1 and msg.mission_type == done[2]:
                self._ack(src, mavlink.MAV_MISSION_ACCEPTED, msg.mission_type)  # our ACK was lost
            return
        expected = len(up.items)
        if msg.seq != expected:
            self._request(expected)  # duplicate or out of order: ask again for the one we need
            return
        item = item_from_msg(msg)
        error = self.validate(item, expected) if up.mission_type == 0 else None
        if error is not None:
            log.info("mission upload refused at item %d (command %d): result %d", msg.seq, msg.command, error)
            self._upload = None
            if self.on_invalid_item is not None:
                self.on_invalid_item(error)
            self._ack(src, error, up.mission_type)
            return
        up.items.append(item)
        up.retries = 0
        if len(up.items) < up.count:
            self._request(len(up.items))
            return
        items = self.transform_upload(up.items) if up.mission_type == 0 else up.items
        self.lists[up.mission_type] = items
        self._upload = None
        self._completed = (src, up.count, up.mission_type)
        if up.mission_type == 0:
            self.on_new_mission(items)
        self._ack(src, mavlink.MAV_MISSION_ACCEPTED, up.mission_type)

    def _on_request(self, src, msg) -> None:
        items = self.transform_download(list(self.lists.get(msg.mission_type, [])))
        if not 0 <= msg.seq < len(items):
            self._ack(src, mavlink.MAV_MISSION_INVALID_SEQUENCE, msg.mission_type)
            return
        it = items[msg.seq]
        self.send(self.mav.mission_item_int_encode(
            src[0], src[1], msg.seq, it.frame, it.command, it.current, it.autocontinue,
            it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z, msg.mission_type))

    # --- timers ------------------------------------------------------------------------------------
    def poll(self) -> None:
        """Re-request a lost item; give up on a partner that went silent."""
        up = self._upload
        if up is None or time.monotonic() - up.last_request < RETRY_S:
            return
        up.retries += 1
        if up.retries > MAX_RETRIES:
            log.info("mission upload timed out at item %d of %d", len(up.items), up.count)
            self._upload = None
            self._ack(up.partner, mavlink.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            return
        self._request(len(up.items))
