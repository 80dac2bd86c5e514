"""Synthetic sequences (a wing of the core): camera rigs and backgrounds (stage), and multi-view sequences of mocap
rendered with :mod:`jaxmocap.geometry.render` (generate)."""
