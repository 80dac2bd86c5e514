"""Synthetic sequences (a wing of the core): ray-cast rendering and sequences generated from mocap."""
