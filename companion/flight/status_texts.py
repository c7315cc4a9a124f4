"""The vehicle's own words (STATUSTEXT) around a request it may refuse, for the error that reports the refusal.

A refused mission upload or start comes back as a bare result code (mavsdk: ``TOO_MANY_MISSION_ITEMS``,
``DENIED``); the reason is in a STATUSTEXT that the firmware sends beside it, and often after it: real ArduCopter
acks NO_SPACE and then says "Only 650 items are supported" (or "Only 0 items are supported" while its mission
storage is still initialising); real PX4 says "Geofence violation for waypoint 5" and "Switching to Mission is
currently not available". So the texts are collected while the request runs and for a moment after a refusal.
"""

from __future__ import annotations

import asyncio
import contextlib
import time

from companion.flight.stream_listener import StreamListener

REASON_WAIT_S = 1.5  # after a refusal, how long to wait for the text that explains it (it may trail the ACK)
QUIET_AFTER_TEXT_S = 0.3  # once a text came, how long to wait for the ones that follow it


def clean_text(text: str) -> str:
    """A STATUSTEXT as a person reads it: PX4 ends its texts with a tab (its events marker), which is no part of it."""
    return text.strip()


class StatusTexts(StreamListener):
    """``async with StatusTexts(vehicle.telemetry) as texts: mark = texts.mark(); ...; await texts.reason(mark)``.

    Keeps every STATUSTEXT as ``"SEVERITY: text"`` while the block runs."""

    def __init__(self, telemetry):
        self.telemetry = telemetry
        self.texts: list[tuple[float, str]] = []  # (monotonic time, "SEVERITY: text")
        self._arrived = asyncio.Event()

    async def _listen(self) -> None:
        async for s in self.telemetry.subscribe_status_text():
            self.add(s.type.name, s.text)

    def add(self, severity: str, text: str) -> None:
        self.texts.append((time.monotonic(), f"{severity}: {clean_text(text)}"))
        self._arrived.set()

    def mark(self) -> int:
        """A position to quote from: the texts after it belong to the request that follows."""
        return len(self.texts)

    def since(self, mark: int) -> list[str]:
        return [text for _, text in self.texts[mark:]]

    async def reason(self, mark: int, wait_s: float = REASON_WAIT_S) -> list[str]:
        """The texts since ``mark``, waiting up to ``wait_s`` for the first one and briefly for any that follow."""
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            self._arrived.clear()  # cleared before the check: a text that came in the meantime is counted
            if len(self.texts) > mark:
                break
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), deadline - time.monotonic())
        if len(self.texts) > mark:
            settle = min(QUIET_AFTER_TEXT_S, max(0.0, deadline - time.monotonic()))
            await asyncio.sleep(settle)
        return self.since(mark)


def quote(said: list[str]) -> str:
    """The vehicle's words for an error message."""
    return "it said: " + "; ".join(said) if said else "it gave no reason (no STATUSTEXT)"
