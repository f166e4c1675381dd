"""The queries to the matcher: at most one in flight, its answer matched back to it, and what became of it.

`QueryDesk` issues the trigger's query, hands it out once, drops it when unanswered for trigger.query_timeout_s,
and takes its answer back; `Answering` is one answer being judged, and builds its `FixOutcome`. Times autopilot
seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from taco_mav.core.frames import FixOutcome, FixReason
from taco_mav.core.run_record import RunRecord
from taco_mav.core.types import FixQuery, MatchResult

__all__ = ["Answering", "QueryDesk"]


@dataclass(frozen=True)
class Answering:
    """The matcher's answer to `query`, arrived at `now` (s), with every crop's weight: the outcomes it can have."""

    query: FixQuery
    now: float
    weights: tuple[float, ...]

    def refused(self, reason: FixReason, **figures: object) -> FixOutcome:
        """Not fused, for `reason`; figures: FixOutcome's optional fields (chosen, xy, yaw_residual, ...)."""
        return FixOutcome(self.query.query_id, False, reason, self.query.capture_t, self.now,
                          weights=self.weights, **figures)  # type: ignore[arg-type]

    def accepted(self, **figures: object) -> FixOutcome:
        """Fused; figures as for `refused`."""
        return FixOutcome(self.query.query_id, True, FixReason.ACCEPTED, self.query.capture_t, self.now,
                          weights=self.weights, **figures)  # type: ignore[arg-type]


class QueryDesk:
    """The query in flight and the time of the last answer (see the module docstring)."""

    def __init__(self, t0: float, timeout_s: float, on_arrival: bool, record: RunRecord | None) -> None:
        """t0: start, s; timeout_s: an unanswered query is dropped after this, s; on_arrival: answers count at
        their arrival rather than their capture (latency.apply_on_arrival)."""
        self.timeout_s, self.on_arrival, self.record = timeout_s, on_arrival, record
        self.answered_t = t0  # capture time of the last answered query (on arrival: its arrival), s
        self._ids = 0
        self._ready: FixQuery | None = None
        self._pending: FixQuery | None = None
        self._issued_t = t0

    def free(self, t: float) -> bool:
        """Whether a new query may be planned at t (s): none waiting to be handed out and none in flight (one
        unanswered for timeout_s is dropped so the pipeline can ask again)."""
        if self._pending is not None:
            if t - self._issued_t < self.timeout_s:
                return False
            self._pending = None
        return self._ready is None

    def issue(self, **fields: object) -> None:
        """The trigger's query, with the next id (fields: FixQuery's, but query_id)."""
        self._ids += 1
        self._ready = FixQuery(self._ids, **fields)  # type: ignore[arg-type]

    def poll(self, t: float) -> FixQuery | None:
        """The query issued, once (None when there is none); it is then in flight."""
        q, self._ready = self._ready, None
        if q is not None:
            self._pending, self._issued_t = q, t
            if self.record is not None:
                self.record.queries.append(q)
        return q

    def adopt(self, q: FixQuery, t: float) -> None:
        """Take another Localiser's query as this one's in flight."""
        self._ready = None
        self._pending, self._issued_t = q, t

    def cancel(self, query_id: int) -> None:
        """Give up on the query in flight (matcher failed); the answer time is not reset."""
        if self._pending is not None and self._pending.query_id == query_id:
            self._pending = None

    @property
    def in_flight(self) -> bool:
        return self._pending is not None

    def take(self, query_id: int, results: Sequence[MatchResult | None], now: float) -> Answering | FixOutcome:
        """The answer to the query in flight, to be judged; or the outcome when `results` answer no query in
        flight or hold nothing."""
        q = self._pending
        if q is None or q.query_id != query_id:
            return FixOutcome(query_id, False, FixReason.UNKNOWN_QUERY, float("nan"), now)
        self._pending = None
        if not any(r is not None for r in results):
            self.answered(q, now)
            return FixOutcome(query_id, False, FixReason.NO_RESULTS, q.capture_t, now)
        return Answering(q, now, tuple(float(r.w) if r is not None else 0.0 for r in results))

    def answered(self, q: FixQuery, now: float) -> None:
        """The query counts as answered (the trigger's time runs from its capture, or from `now` on arrival)."""
        self.answered_t = max(self.answered_t, now if self.on_arrival else q.capture_t)
