"""A real GNSS receiver in the Localiser (not in the paper): its fusion (`fusion.GnssFusion`, owned by the
Localiser), the guard that decides whether the receiver is honest (guard.py), its dead-reckoning shadow
(shadow.py) and parameters (params.py)."""
