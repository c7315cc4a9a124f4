"""The background listener under StatusTexts and the start's COMMAND_ACK reader: a task for the block's length."""

import asyncio

from companion.flight.start import _CommandAcks
from companion.flight.stream_listener import StreamListener


class _Endless(StreamListener):
    def __init__(self):
        self.seen: list[int] = []
        self.cancelled = False

    async def _listen(self) -> None:
        try:
            while True:
                self.seen.append(len(self.seen))
                await asyncio.sleep(0.01)
        except asyncio.CancelledError:
            self.cancelled = True
            raise


def test_the_stream_is_read_from_entry_and_cancelled_on_exit_however_the_block_ends():
    async def run(fail: bool):
        listener = _Endless()
        try:
            async with listener as entered:
                assert entered is listener and listener.seen == [0]  # started before the block's first line
                await asyncio.sleep(0.05)
                if fail:
                    raise RuntimeError("the request failed")
        except RuntimeError:
            pass
        count = len(listener.seen)
        await asyncio.sleep(0.05)
        return listener, count

    for fail in (False, True):
        listener, count = asyncio.run(run(fail))
        assert listener.cancelled and listener._task.done()
        assert len(listener.seen) == count >= 3  # nothing read after the block


def test_a_listener_without_a_stream_runs_the_block_without_a_task():
    class NoDirect:  # a vehicle object without mavlink_direct
        pass

    async def run():
        async with _CommandAcks(NoDirect()) as acks:
            return acks

    acks = asyncio.run(run())
    assert acks.direct is None and acks._task is None and acks.results == []


def test_command_acks_keeps_the_results_of_mode_switches_and_starts_only():
    class Message:
        def __init__(self, command, result):
            self.fields_json = f'{{"command": {command}, "result": {result}}}'

    class Direct:
        async def subscribe_message(self, name):
            assert name == "COMMAND_ACK"
            for command, result in ((176, 4), (400, 0), (300, 2), (176, 0)):
                yield Message(command, result)
            await asyncio.sleep(10)

    class Vehicle:
        direct = Direct()

    async def run():
        async with _CommandAcks(Vehicle()) as acks:
            await asyncio.sleep(0.01)
        return acks

    assert asyncio.run(run()).results == ["DO_SET_MODE FAILED", "MISSION_START DENIED", "DO_SET_MODE ACCEPTED"]
