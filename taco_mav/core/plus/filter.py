"""taco+'s filter: the states (x, y, theta, dv, b[, beta][, the map's offset]), their prior, the predict with
taco+'s process noise (noise.py) and the smoother's odometry noise.

World frame ENU metres, headings ENU radians; dv the speed error m/s, b the forward accelerometer bias m/s^2,
beta the compass bias rad.
"""

from __future__ import annotations

import math

import numpy as np

from taco_mav.core.error_model import ErrorTerms
from taco_mav.core.frames import Tick
from taco_mav.core.params import LocaliserParams
from taco_mav.core.plus.noise import bias_decay, n_states, process_noise_plus
from taco_mav.core.plus.params import PlusParams
from taco_mav.core.ukf import PlanarUkf

__all__ = ["PlusFilter"]


class PlusFilter:
    """taco+'s filter for the Localiser's parameters `params` and taco+'s `q` (params.plus)."""

    def __init__(self, params: LocaliserParams, q: PlusParams) -> None:
        self.p, self.q = params, q

    def make_ukf(self, x: float, y: float, heading: float) -> PlanarUkf:
        """(x, y, theta, dv, b[, beta][, the map's offset]) with taco+'s initial sigmas; map.georef_sigma_m > 0
        adds the map's georeferencing offset as two more states (ukf.py)."""
        p, q = self.p, self.q
        s_xy, s_th = p.ukf.initial_sigma_xy_m, p.ukf.initial_sigma_theta_rad
        var = [s_xy**2, s_xy**2, s_th**2, q.initial_speed_sigma_mps**2, q.initial_bias_sigma_mps2**2,
               q.compass_bias_sigma_rad**2][:n_states(q)]
        g = p.map_georef_sigma_m
        if g > 0.0:
            if len(var) != 6:
                raise ValueError("map.georef_sigma_m > 0 needs the compass-bias state "
                                 "(plus.compass_bias_sigma_rad > 0)")
            var += [g * g, g * g]
        return PlanarUkf(np.array([x, y, heading] + [0.0] * (len(var) - 3)), np.diag(var), p.ukf.alpha, p.ukf.beta,
                         p.ukf.kappa)

    def predict(self, ukf: PlanarUkf, tick: Tick, terms: ErrorTerms) -> None:
        """UKF predict over one frame with taco+'s process noise (noise.py), the compass bias decaying."""
        inc = tick.inc
        dt = max(inc.dt, 1e-6)
        Q = process_noise_plus(float(ukf.x[2]), dt, inc.distance, self.q, n=len(ukf.x))
        ukf.predict(inc.d_fwd, inc.d_left, inc.d_theta, Q, dt=inc.dt, bias_decay=bias_decay(dt, self.q))

    def odometry_sigma(self, tick: Tick) -> float:
        """The smoother's odometry sigma for this frame, metres: taco+'s own position process noise plus what
        the speed-error uncertainty moves the frame by (sigma_dv dt), instead of the paper's >= 1 m."""
        inc = tick.inc
        Q = process_noise_plus(float(tick.x[2]), max(inc.dt, 1e-6), inc.distance, self.q)
        return max(math.sqrt(0.5 * float(np.trace(Q[:2, :2]))) + math.sqrt(max(float(tick.P[3, 3]), 0.0)) * inc.dt,
                   1e-3)
