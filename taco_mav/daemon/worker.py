"""The matcher worker: one thread that answers FixQueries with FixService.answer and posts the results to a
queue. It never touches the Localiser (not thread-safe): the daemon loop hands queries in and takes results out.

Faults stay inside the worker: a frame the camera guard rejects (`FrameRejected`) comes back as its reason, a
matcher exception as "matcher_error" (logged with its traceback). A matcher that hangs is seen from outside by
`running()` (the job and how long it has run); the owner then `abandon()`s the worker and starts another on the
same output queue: the stuck thread is a daemon thread that drops its late answer and ends when it returns.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable

from taco_mav.camera.sources import FrameRejected
from taco_mav.core.types import FixQuery, MatchResult
from taco_mav.cvgl.base import GroundFrame
from taco_mav.cvgl.service import FixService

log = logging.getLogger(__name__)

FetchFn = Callable[[], GroundFrame]
"""Runs in the worker: the query's ground frame, or FrameRejected(reason)."""


@dataclass(frozen=True)
class WorkResult:
    """query: the query; results: aligned with its crops (None on error); error: why there are none (a
    FrameRejected reason or "matcher_error"); detail: the error's text; frame_t: autopilot time of the frame
    used, s (nan without one); elapsed_s: wall time in the worker, s; generation: the daemon's Localiser
    generation the query belongs to (re-anchoring starts a new one)."""

    query: FixQuery
    results: list[MatchResult | None] | None
    error: str | None
    frame_t: float
    elapsed_s: float
    generation: int = 0
    detail: str = ""


@dataclass(frozen=True)
class Job:
    """The job a worker is running: its query, generation and start time (time.monotonic s)."""

    query: FixQuery
    generation: int
    started: float


class MatchWorker:
    """A daemon thread around a FixService. out: the results queue (shared by a replacement worker; a new one by
    default). At most one query waits while one runs."""

    def __init__(self, service: FixService, out: queue.Queue[WorkResult] | None = None) -> None:
        self.service = service
        self._in: queue.Queue[tuple[FixQuery, FetchFn, int] | None] = queue.Queue(maxsize=1)
        self.out: queue.Queue[WorkResult] = out if out is not None else queue.Queue()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._job: Job | None = None
        self._thread = threading.Thread(target=self._run, name="taco-matcher", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def submit(self, query: FixQuery, fetch: FetchFn, generation: int = 0) -> bool:
        """Queue a query; `fetch` (run in the worker) returns its ground frame. False when the worker is
        still busy with earlier ones."""
        try:
            self._in.put_nowait((query, fetch, generation))
        except queue.Full:
            return False
        return True

    def running(self) -> Job | None:
        """The job in progress (None when idle)."""
        with self._lock:
            return self._job

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            item = self._in.get()
            if item is None or self._stop.is_set():
                break
            query, fetch, generation = item
            t0 = time.perf_counter()
            with self._lock:
                self._job = Job(query, generation, time.monotonic())
            frame_t = float("nan")
            results, error, detail = None, None, ""
            try:
                frame = fetch()
                frame_t = frame.t
                results = self.service.answer(query, frame)
            except FrameRejected as exc:
                error, detail = exc.reason, exc.detail
                log.debug("query %d: frame rejected: %s", query.query_id, exc)
            except Exception as exc:  # noqa: BLE001 - a matcher failure must not kill the daemon
                log.exception("matcher failed on query %d", query.query_id)
                error, detail = "matcher_error", f"{type(exc).__name__}: {exc}"
            with self._lock:
                self._job = None
            if self._stop.is_set():  # abandoned while the matcher ran: the answer is nobody's now
                break
            self.out.put(WorkResult(query, results, error, frame_t, time.perf_counter() - t0, generation, detail))

    def drop_waiting(self) -> list[tuple[FixQuery, int]]:
        """Take the queued (not started) queries out: (query, generation) each."""
        taken = []
        while True:
            try:
                item = self._in.get_nowait()
            except queue.Empty:
                return taken
            if item is not None:
                taken.append((item[0], item[2]))

    def abandon(self) -> None:
        """Stop without waiting (the matcher hangs): the thread ends when the matcher returns, dropping its
        answer."""
        self._stop.set()

    def stop(self, timeout: float = 1.0) -> None:
        """Stop and wait up to `timeout` s; a thread stuck in the matcher is left behind (a daemon thread)."""
        self._stop.set()
        try:
            self._in.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("matcher thread still running after %.1f s (left as a daemon thread)", timeout)
