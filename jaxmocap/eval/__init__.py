"""Evaluation: joint-error metrics, plots and overlays, mode counting with mixtures."""
