"""The frame-to-frame prediction of the tracking loop (:mod:`jaxmocap.tracking.loop`): the particles of frame ``t``
moved by the damped constant velocity of the estimates ``x̂_{t−1} − x̂_{t−2}`` on the DOFs that
``TrackOptions.velocity_dofs`` names, with full turns of a circular angle (the root's heading) taken out, as one
compiled program that every frame reuses."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap.choices import VELOCITY_DOFS
from jaxmocap.stored_programs import stored_jit
from jaxmocap.tracking.init import root_translation_dofs

__all__ = ["angle_difference", "predict", "unwind", "velocity_dofs"]


def velocity_dofs(model, which: str = "translation") -> np.ndarray:
    """``(D,)`` bool: the DOFs of the constant-velocity prediction (``TrackOptions.velocity_dofs``):
    ``translation`` the root's translation, ``root`` all of the root's DOFs (its heading and tilts too), ``all``
    every DOF."""
    out = np.zeros(model.num_dofs, bool)
    if which == "all":
        out[:] = True
    elif which == "root":
        out[list(model.topology.segment_dofs[0])] = True
    elif which == "translation":
        out[root_translation_dofs(model)] = True
    else:
        raise ValueError(f"unknown velocity_dofs {which!r}; choose one of {', '.join(VELOCITY_DOFS)}")
    return out


def angle_difference(a: np.ndarray, b: np.ndarray, circular: np.ndarray) -> np.ndarray:
    """``a − b`` ``(D,)``, the entries flagged ``circular`` wrapped into ``[−π, π)`` (a heading going from 179° to
    −179° turned by 2°, not by −358°)."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return np.where(circular, np.mod(d + np.pi, 2 * np.pi) - np.pi, d)


@jax.jit
def unwind(particles: jnp.ndarray, circular: jnp.ndarray) -> jnp.ndarray:
    """``particles (N, D)`` with each DOF flagged ``circular`` (``(D,)`` bool; a full-turn angle such as the root's
    heading) moved by the multiple of 2π, ``2π k`` with ``k = round(x̄ / 2π)`` (the same for every particle: the set
    stays in one piece), that brings the particles' mean ``x̄`` into ``[−π, π]``. Such an angle's limits are
    ``±2π`` and the diffusion clips at them: without this a body that keeps turning one way would be held at the
    limit after at most two turns (less, from a start near ±π)."""
    two_pi = jnp.asarray(2 * np.pi, particles.dtype)
    k = jnp.where(circular, jnp.round(jnp.mean(particles, axis=0) / two_pi), 0.0)
    return particles - two_pi * k


@stored_jit
def predict(particles: jnp.ndarray, step: jnp.ndarray, circular: jnp.ndarray) -> jnp.ndarray:
    """The frame's prediction of ``particles (N, D)``: moved by ``step (D,)`` (the damped constant velocity, zero
    where none), then :func:`unwind`; one compiled program, the same on every frame (an eager update would compile
    its operations on the first frame that has a velocity), kept on disk by a run of the command line
    (:func:`jaxmocap.stored_programs.stored_jit`: a warm start reads it back instead of tracing it)."""
    return unwind(particles + step, circular)
