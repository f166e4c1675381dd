"""Reliability tooling: the soak run (`soak.soak`)."""
