"""taco+'s running tallies shared by its trigger, its fix policy and its aiding: distance driven, when the last
query was planned and the last fix captured (in distance), weak answers deferred in a row, and when the last
answer came. Metres along the track (new frames only), autopilot seconds."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Progress"]


@dataclass
class Progress:
    """odo: distance travelled, m; odo_at_query: odometer when the last query was planned, m; odo_at_fix: ... at the
    capture of the last accepted fix, m; queries: queries planned since the start; deferred: weak answers deferred
    in a row (plus.defer_w); last_answer_t: arrival of the last answer, s."""

    odo: float = 0.0
    odo_at_query: float = 0.0
    odo_at_fix: float = 0.0
    queries: int = 0
    deferred: int = 0
    last_answer_t: float = -math.inf
