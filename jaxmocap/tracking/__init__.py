"""Tracking: options, setup, initialisation, the run folder and the frame loop, sweeps."""
