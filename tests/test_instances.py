"""SITL instance reservation (closedloop/instances.py): missions started together take different instances, in
one process or in several, and a mission that ends or dies frees its instance."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import uuid
from collections.abc import Iterator

import pytest

from taco_mav.closedloop.instances import lock_path, reserved_instance


def _hold(kind: str, ready: mp.Event) -> None:  # type: ignore[valid-type]
    with reserved_instance(kind, range(5), lambda i: True):
        ready.set()  # type: ignore[attr-defined]
        signal.pause()


@pytest.fixture
def kind() -> Iterator[str]:
    k = f"test-{uuid.uuid4().hex[:8]}"
    yield k
    for i in range(5):
        lock_path(k, i).unlink(missing_ok=True)


def test_two_missions_in_one_process_take_different_instances_and_an_ended_one_frees_its_own(kind: str) -> None:
    with reserved_instance(kind, range(5), lambda i: True) as a:
        with reserved_instance(kind, range(5), lambda i: True) as b:
            assert (a, b) == (0, 1)
        with reserved_instance(kind, range(5), lambda i: True) as c:
            assert c == 1  # b's ended
    with reserved_instance(kind, range(5), lambda i: True) as d:
        assert d == 0


def test_an_instance_whose_ports_are_taken_is_skipped_and_none_left_names_the_kind(kind: str) -> None:
    with reserved_instance(kind, range(5), lambda i: i >= 3) as a:
        assert a == 3
        with reserved_instance(kind, range(5), lambda i: i != 4) as b:
            assert b == 0
        with pytest.raises(RuntimeError, match=f"no free {kind} SITL instance"):
            with reserved_instance(kind, [3], lambda i: True):
                pass


def test_another_process_holding_an_instance_is_respected_until_it_is_killed(kind: str) -> None:
    ctx = mp.get_context("spawn")
    ready = ctx.Event()
    holder = ctx.Process(target=_hold, args=(kind, ready))
    holder.start()
    try:
        assert ready.wait(60.0), "the holding process did not reserve an instance"
        with reserved_instance(kind, range(5), lambda i: True) as mine:
            assert mine == 1  # 0 is the other process's
        os.kill(holder.pid, signal.SIGKILL)  # a worker killed mid-mission: the kernel drops its lock
        holder.join(10.0)
        with reserved_instance(kind, range(5), lambda i: True) as after:
            assert after == 0
    finally:
        if holder.is_alive():
            holder.kill()
            holder.join(10.0)
