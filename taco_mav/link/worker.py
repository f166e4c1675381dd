"""The matcher worker: one thread that answers FixQueries with FixService.answer and posts the results to a
queue. It never touches the Localiser (not thread-safe): the daemon loop hands queries in and takes results out.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable

from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.service import FixService

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WorkResult:
    """query: the query; results: aligned with its crops (None on error); error: text when the matcher failed;
    frame_t: autopilot time of the frame used, s (nan without one); elapsed_s: wall time in the worker, s;
    generation: the daemon's Localiser generation the query belongs to (re-anchoring starts a new one)."""

    query: FixQuery
    results: list[MatchResult | None] | None
    error: str | None
    frame_t: float
    elapsed_s: float
    generation: int = 0


class MatchWorker:
    """A daemon thread around a FixService. extra_latency_s: artificial delay before each answer (tests)."""

    def __init__(self, service: FixService, extra_latency_s: float = 0.0) -> None:
        self.service = service
        self.extra_latency_s = extra_latency_s
        self._in: queue.Queue[tuple[FixQuery, Callable[[], GroundFrame | None], int] | None] = queue.Queue(maxsize=2)
        self.out: queue.Queue[WorkResult] = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="taco-matcher", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def submit(self, query: FixQuery, fetch: Callable[[], GroundFrame | None], generation: int = 0) -> bool:
        """Queue a query; `fetch` (run in the worker) returns its ground frame or None when there is none.
        False when the worker is still busy with earlier ones."""
        try:
            self._in.put_nowait((query, fetch, generation))
        except queue.Full:
            return False
        return True

    def _run(self) -> None:
        while not self._stop.is_set():
            item = self._in.get()
            if item is None:
                break
            query, fetch, generation = item
            t0 = time.perf_counter()
            frame_t = float("nan")
            try:
                frame = fetch()
                if frame is None:
                    results, error = None, "no_frame"
                else:
                    frame_t = frame.t
                    results, error = self.service.answer(query, frame), None
            except Exception as exc:  # noqa: BLE001 - a matcher failure must not kill the daemon
                log.exception("matcher failed on query %d", query.query_id)
                results, error = None, f"{type(exc).__name__}: {exc}"
            if self.extra_latency_s > 0 and self._stop.wait(self.extra_latency_s):
                break
            self.out.put(WorkResult(query, results, error, frame_t, time.perf_counter() - t0, generation))

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        try:
            self._in.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("matcher thread still running after %.1f s (left as a daemon thread)", timeout)
