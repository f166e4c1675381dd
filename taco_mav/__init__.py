"""taco_mav: a GNSS substitute for ground robots (TACO: IMU + cross-view geo-localisation over MAVLink)."""

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
