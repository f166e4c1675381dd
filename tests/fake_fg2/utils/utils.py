"""Fake FG2 checkout (tests only): the one helper the fake model imports from FG2's `utils.utils`."""

import torch
from torch.nn import functional as F


def desc_l2norm(desc: torch.Tensor) -> torch.Tensor:
    """L2-normalise descriptors along dim 1."""
    return F.normalize(desc, p=2, dim=1, eps=1e-10)
