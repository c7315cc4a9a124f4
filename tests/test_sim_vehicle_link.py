"""The fault-injecting UDP link of the simulator, on loopback."""

from __future__ import annotations

import socket
import time

import numpy as np

from sim.vehicle.link import FaultyUdpLink


def _pair(**kw):
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(0.5)
    link = FaultyUdpLink(peer.getsockname(), np.random.default_rng(1), **kw)
    return link, peer


def _drain(peer) -> int:
    n = 0
    peer.settimeout(0.05)
    try:
        while True:
            peer.recv(100)
            n += 1
    except TimeoutError:
        return n


def test_packet_loss_rate_both_directions():
    link, peer = _pair(loss=0.2)
    try:
        sent_through = got = 0
        for batch in range(20):  # in batches: a socket buffer holds only a few hundred datagrams
            for i in range(100):
                link.send((batch * 100 + i).to_bytes(4, "little"))
            sent_through += _drain(peer)
            for i in range(100):
                peer.sendto(i.to_bytes(4, "little"), link.sock.getsockname())
            time.sleep(0.01)
            got += len(link.receive())
        assert 1500 < sent_through < 1700  # ~80 % of 2000
        assert 1500 < got < 1700
    finally:
        link.close()
        peer.close()


def test_latency_delays_and_outage_drops():
    link, peer = _pair(latency_s=0.15)
    try:
        t0 = time.monotonic()
        link.send(b"x")
        assert link.next_due() is not None
        while link.next_due() is not None:
            link.receive()  # pumps the delayed queue
            time.sleep(0.005)
        assert peer.recv(10) == b"x"
        assert time.monotonic() - t0 >= 0.15
        link.down = True
        link.send(b"y")
        link.receive()
        assert _drain(peer) == 0 and link.dropped == 1
    finally:
        link.close()
        peer.close()
