"""Offline evaluation: the same Localiser as the daemon, driven over a dataset deterministically."""
