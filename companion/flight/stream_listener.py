"""A stream read in the background for the length of an ``async with`` block.

Why a base class: the companion needs to see what the vehicle sends beside a request that mavsdk handles itself
(the STATUSTEXTs that explain a refusal, the COMMAND_ACK whose result mavsdk reports as UNKNOWN). Each such
listener starts a task on entry that reads one MAVSDK/MAVLink stream into the listener, and cancels it on exit,
whatever way the block is left. The start, the yield that lets the subscription begin before the request it is
meant to explain, and the cancel are the same for every stream; only what is read differs (``_listen``).
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import Self


class StreamListener:
    """``async with Sub(...) as listener:`` runs ``listener._listen()`` as a task until the block ends.

    Subclasses implement ``_listen`` (read the stream, keep what matters) and may override ``_can_listen`` (False:
    no stream to read, e.g. a vehicle without mavlink_direct; the block then runs without a task)."""

    _task: asyncio.Task | None = None

    def _can_listen(self) -> bool:
        return True

    async def _listen(self) -> None:
        raise NotImplementedError

    async def __aenter__(self) -> Self:
        if self._can_listen():
            self._task = asyncio.create_task(self._listen())
            await asyncio.sleep(0)  # let the subscription start before the request it is meant to explain
        return self

    async def __aexit__(self, *exc) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task
