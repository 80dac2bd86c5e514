"""PARSEC bodytrack's image likelihood (``jaxmocap/parsec/FORMAT.md`` §6.4) as a pure JAX function of one
particle, and its fast batched form.

For a state ``x`` the 10 cylinders (:func:`jaxmocap.parsec.cylinders.cylinder_poses`) are projected into every camera
(:func:`jaxmocap.parsec.cylinders.cylinder_corners`, corners P0..P3) and sampled in two images per camera:

* **edge term** on the edge map ``E`` (:func:`jaxmocap.parsec.images.edge_map`): along the two long sides P0→P1 and
  P2→P3, each with ``n = max(int(|side|/5 + 0.5), 4)`` and ``n + 1`` samples at ``t = 0, d, 2d, …`` (``d = 1/n``,
  ``t`` accumulated in float32 as bodytrack does), each sample adds ``(255 − E(x, y))²``;
  ``ErrEdge = Σ (255 − E)² / 255² / (number of edge samples inside the images)``;
* **inside term** on the binary foreground map ``FG``: ``n1 + 1`` rows ``e1 = P0 + t1 (P1 − P0)``, ``e2 = P3 +
  t1 (P2 − P3)`` with ``n1 = max(int(|P1 − P0|/10 + 0.5), 4)``, and on each row ``n2`` samples ``e1 + t2 (e2 −
  e1)``, ``t2 = 0 … (n2 − 1)/n2`` (the e2 end excluded), ``n2 = max(int(|mid(P0P1) − mid(P3P2)|/10 + 0.5), 4)``;
  ``ErrInside = #(FG = 0) / (number of inside samples inside the images)``;
* ``log L = −(ErrEdge + ErrInside)``, equal weights, summed over all cameras and parts before the divisions.

A sample at ``(xf, yf)`` reads pixel ``(int(xf + 0.5), int(yf + 0.5))`` with C's truncation toward zero (so
``xf`` in (−1.5, −0.5) reads column 0) and counts only inside the image. The sample positions are computed in
float32 in bodytrack's operation order whatever the dtype of the state, so that pixel lookups match the C++.
A state whose cylinders intersect (bodytrack's sphere test on the part pairs (6, 0), (8, 0), (2, 4),
:func:`geometry_valid`) gets ``−1e10`` and ``valid = False``; so does a state with no sample inside any image
(bodytrack divides by zero there).

**Static shapes.** The number of samples of a cylinder depends on its projected size, so it varies from particle
to particle. Each group of parts is sampled by a ``lax.while_loop`` that takes a fixed number of samples per
lane (camera × part × side) and iteration, with masks for the samples past a lane's count; the loop runs as long
as the largest lane of the batch needs, so every shape is static and nothing is padded to a worst case. The
counts are bounded by the image size, so the loop length is too: a side is sampled with at most ``n = int(D/5 +
0.5)`` (D the image diagonal; 160 for 640×480), the inside grid with at most ``int(D/10 + 0.5)`` rows and
columns (80). A cylinder whose projected side is longer than the image diagonal cannot lie in the image; only for
such a cylinder (an implausible particle) is the sampling sparser than bodytrack's.

**Speed.** :func:`log_likelihood_batch` evaluates particles ``(N, 31)`` with the particle axis last in every
intermediate array, where XLA on CPU vectorises the per-sample arithmetic (with ``vmap``'s leading batch axis it
does not: several times slower). Inside a loop iteration every sample is a separate elementwise step accumulating
into one packed integer counter per lane (no reduction ops, which XLA on CPU materialises); the lanes' counters are
summed into four integers per particle carried by the scan over part groups (no per-part array is stacked: 1.05×,
and the edge sum is exact before its one rounding to float32). The pixel index is computed exactly in float32
without a conversion (:func:`_index`), and the pixel reads promise in-bounds indices (a masked sample reads pixel
0); XLA compiles a loop iteration into one fused kernel (on x86 CPUs without AVX-512 the positions apart from the
reads and sums, :func:`_gather`, each sample's mask in the top bit of its index and its contribution to the sums
looked up by the byte read, :func:`_lookup`). The loop lengths are reduced once before each loop, and
the sphere test uses its static sphere counts (:func:`_static_sphere_counts`, NumPy only, so that they stay
concrete inside ``jit``) and is compiled as a computation of its own (:func:`_on_its_own`). The programs that
evaluate it (:func:`jit_loglik_batch`, the PARSEC tracker's step) are compiled with
:func:`jaxmocap.host.particle_options`: copy insertion with region analysis (fewer copies of the loops' carried
arrays); XLA's fusion emitters (its default) since the reads run apart, faster there than the loop emitter.
See ``benchmarks/perf/bench_parsec.py`` and ``benchmarks/perf/instructions.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxmocap import host
from jaxmocap.filters.sharding import chunked
from jaxmocap.parsec import cylinders
from jaxmocap.parsec.cameras import Cameras, _trail
from jaxmocap.parsec.files import NUM_DOFS, NUM_PARTS, BodyShape
from jaxmocap.parsec.model import _CYLINDER_LENGTH, cylinder_lengths

__all__ = [
    "Config",
    "Observation",
    "Terms",
    "observation",
    "geometry_valid",
    "corners",
    "terms_from_corners",
    "likelihood_terms",
    "log_likelihood",
    "log_likelihood_batch",
    "make_loglik_batch",
    "jit_loglik_batch",
    "INVALID",
]

#: Log-likelihood of an invalid state (bodytrack's value).
INVALID = -1e10

#: Part pairs tested for intersection (left forearm / torso, right forearm / torso, left shin / right shin).
INTERSECTION_PAIRS: tuple[tuple[int, int], ...] = ((6, 0), (8, 0), (2, 4))


@dataclasses.dataclass(frozen=True)
class Config:
    """Static settings of the likelihood (hashable).

    Attributes:
      image_size: ``(W, H)`` of every camera image.
      edge_step, inside_hstep, inside_vstep: sampling steps in pixels (bodytrack: 5, 10, 10).
      chunk: edge samples per lane taken by one iteration of the edge loop; one number, or one per group. The loop
        runs until the longest side of the batch is done, so a group whose sides have at most ``k`` samples
        wastes least with ``k`` a multiple of its chunk. The default fits sequenceB_2 (at most 24, 12, 16, 16, 9
        and 12 samples a side around the initial pose: 1184 edge slots per particle, 1344 with 8 for all); the
        values do not depend on it.
      groups: parts sampled together by one loop (similar projected sizes keep the masked work small).
      inside_cols: per group, the samples of a row taken as one block (a row of ``n2`` samples takes
        ``ceil(n2 / inside_cols)`` blocks; bodytrack's rows have at least 4, the torso's about 6 here).
      inside_rows: blocks per lane taken by one iteration of the inside loop.
      max_batch: particles evaluated together at most: :func:`log_likelihood_batch` maps over equal chunks of a
        larger batch (:func:`jaxmocap.filters.sharding.chunked`). A batch's intermediate arrays grow with
        it; past the CPU's caches every pass over them waits on memory: 16000 particles at once took 4.6 µs per
        particle, in four chunks of 4000 3.1 µs (AMD EPYC with 32 MB of L3, one thread, bit-identical values;
        8000 at once 3.0 µs).
      gathers_apart: whether a loop iteration's pixel reads are one gather of their own, apart from the sample
        positions before them and the sums after them (:func:`_gather`); None (the default): where
        :func:`jaxmocap.host.gathers_apart` says so. The values do not depend on it but for float rounding at a
        pixel border (:func:`_gather`).

    Groups of the same size, ``chunk`` and ``inside_cols`` share one compiled loop, scanned over them.
    """

    image_size: tuple[int, int] = (640, 480)
    edge_step: float = 5.0
    inside_hstep: float = 10.0
    inside_vstep: float = 10.0
    chunk: int | tuple[int, ...] = (12, 12, 8, 8, 6, 6)
    groups: tuple[tuple[int, ...], ...] = ((0,), (9,), (1, 3), (2, 4), (5, 7), (6, 8))
    inside_cols: tuple[int, ...] = (6, 6, 4, 4, 4, 4)
    inside_rows: int = 2
    max_batch: int = 4096
    gathers_apart: bool | None = None

    @property
    def apart(self) -> bool:
        """Whether the pixel reads run as gathers of their own (:func:`_gather`): ``gathers_apart``, or where it is
        None :func:`jaxmocap.host.gathers_apart` (this machine's choice)."""
        return host.gathers_apart() if self.gathers_apart is None else bool(self.gathers_apart)

    def __post_init__(self):
        parts = sorted(p for g in self.groups for p in g)
        if parts != list(range(NUM_PARTS)):
            raise ValueError("groups must list every part 0..9 exactly once")
        if len(self.inside_cols) != len(self.groups):
            raise ValueError("inside_cols needs one entry per group")
        if len(self.chunks) != len(self.groups):
            raise ValueError("chunk needs one entry per group (or one number)")
        if min(*self.chunks, self.inside_rows, *self.inside_cols, self.max_batch) < 1:
            raise ValueError("chunk sizes and max_batch must be positive")
        if (self.max_rows_n + 1) * self.max_cols_n >= 65536:
            raise ValueError("image too large for the inside sample counters; use larger inside steps")

    @property
    def chunks(self) -> tuple[int, ...]:
        """The edge chunk of every group."""
        return (self.chunk,) * len(self.groups) if isinstance(self.chunk, int) else tuple(self.chunk)

    @property
    def diagonal(self) -> float:
        return math.hypot(*self.image_size)

    @property
    def max_edge_n(self) -> int:
        """Largest ``n`` of a side (``n + 1`` samples): a side as long as the image diagonal."""
        return int(self.diagonal / self.edge_step + 0.5)

    @property
    def max_rows_n(self) -> int:
        return int(self.diagonal / self.inside_vstep + 0.5)

    @property
    def max_cols_n(self) -> int:
        return int(self.diagonal / self.inside_hstep + 0.5)


class Observation(NamedTuple):
    """One frame: ``edge (V, H, W)`` edge maps (0..255; other dtypes than uint8 are truncated to uint8 per call)
    and ``fg (V, H, W)`` foreground maps (non-zero = foreground). A pytree; a new frame with the same shapes does
    not recompile."""

    edge: jnp.ndarray
    fg: jnp.ndarray


def observation(edge_maps, fg_maps) -> Observation:
    """Stack per-camera maps into an :class:`Observation` of uint8 device arrays."""
    e = np.asarray(edge_maps)
    f = np.asarray(fg_maps)
    if e.shape != f.shape or e.ndim != 3:
        raise ValueError(f"edge and foreground maps must both be (V, H, W), got {e.shape} and {f.shape}")
    # a transfer each (jnp.asarray of a numpy array would run a compiled copy program)
    return Observation(jax.device_put(e.astype(np.uint8)), jax.device_put((f != 0).astype(np.uint8)))


class Terms(NamedTuple):
    """Per-particle result: ``loglik``, ``edge_error``, ``inside_error``, ``valid`` and the in-image sample
    counts ``edge_samples``, ``inside_samples``."""

    loglik: jnp.ndarray
    edge_error: jnp.ndarray
    inside_error: jnp.ndarray
    valid: jnp.ndarray
    edge_samples: jnp.ndarray
    inside_samples: jnp.ndarray


# ---------------------------------------------------------------------------------------------------------------
# Geometry


def _sphere_count(length, radius_max):
    return jnp.minimum(jnp.floor(jnp.abs(length / radius_max / 2.0) + 0.5), 20.0)


def _static_sphere_counts(shape: BodyShape) -> dict[int, int] | None:
    """Sphere counts of the tested parts when the shape is concrete (not traced), else ``None``."""
    try:  # NumPy only: inside a trace a jnp operation on constants gives a tracer, not a value
        limbs = np.asarray(shape.limbs, dtype=np.float64)
        lengths = np.asarray(shape.lengths, dtype=np.float64)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):
        return None
    length = np.asarray([s * lengths[k] for k, s in _CYLINDER_LENGTH])
    parts = {p for pair in INTERSECTION_PAIRS for p in pair}
    out = {}
    for i in parts:
        out[i] = int(min(math.floor(abs(length[i] / max(limbs[i, 0], limbs[i, 1]) / 2.0) + 0.5), 20))
    return out


def _valid_from_frames(shape: BodyShape, A, t) -> jnp.ndarray:
    """:func:`geometry_valid` from scaled frames (``A[i][j]``, ``t[i]`` of shape ``(10, *B)``) → ``B`` bools."""
    dt = t[0].dtype
    nb = t[0].ndim - 1
    limbs = jnp.asarray(shape.limbs, dt)
    bottom, top = limbs[:, 0], limbs[:, 1]
    length = cylinder_lengths(shape).astype(dt)
    static = _static_sphere_counts(shape)

    def spheres(i):
        """Centres (3 arrays ``(K, *B)``), radii and mask ``(K, *1)`` of the spheres of part ``i`` (traced
        shape: 21 spheres, masked)."""
        k = _sphere_count(length[i], jnp.maximum(bottom[i], top[i]))
        idx = jnp.arange(21, dtype=dt)
        alpha = _trail(idx * (1.0 / jnp.maximum(k, 1.0)), nb)
        mask = _trail((idx <= k) & (k > 0), nb)
        c = [t[j][i][None] + alpha * (A[j][2][i] * length[i])[None] for j in range(3)]
        dr = top[i] - bottom[i]
        return c, (bottom[i] + alpha * dr) / jnp.sqrt(1.0 + (dr / length[i]) ** 2), mask

    def static_spheres(i, k):
        """Per sphere: centre (3 ``B``-shaped arrays) and radius, for the static count ``k``."""
        dr = top[i] - bottom[i]
        scaling = jnp.sqrt(1.0 + (dr / length[i]) ** 2)
        axis = [A[j][2][i] * length[i] for j in range(3)]
        delta = 1.0 / jnp.asarray(k, dt)
        out = []
        for q in range(k + 1):
            alpha = q * delta
            out.append(([t[j][i] + alpha * axis[j] for j in range(3)], (bottom[i] + alpha * dr) / scaling))
        return out

    ok = jnp.ones(t[0].shape[1:], bool)
    for a, b in INTERSECTION_PAIRS:
        if static is not None:
            if static[a] == 0 or static[b] == 0:  # bodytrack's 0·∞ makes NaN centres: never intersecting
                continue
            for ca, ra in static_spheres(a, static[a]):
                for cb, rb in static_spheres(b, static[b]):
                    d = [ca[q] - cb[q] for q in range(3)]
                    rab = ra + rb
                    ok = ok & ~(rab * rab > d[0] * d[0] + d[1] * d[1] + d[2] * d[2])  # NaN: no hit
        else:
            (ca, ra, ma), (cb, rb, mb) = spheres(a), spheres(b)
            d = [ca[q][:, None] - cb[q][None, :] for q in range(3)]
            nrm = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            rab = ra[:, None] + rb[None, :]
            hit = (rab * rab > nrm) & ma[:, None] & mb[None, :]
            ok = ok & ~jnp.any(hit, axis=(0, 1))
    return ok


def geometry_valid(shape: BodyShape, poses: jnp.ndarray) -> jnp.ndarray:
    """bodytrack's ``BodyGeometry::Valid`` (§6.2) for cylinder poses ``(10, 3, 4)``: scalar bool.

    Each cylinder of a tested pair is approximated by ``k + 1`` spheres, ``k = min(int(|len/max(b, t)|/2 +
    0.5), 20)``, centred at ``o0 + α (o1 − o0)`` (``α = i/k``, ``o0, o1`` the axis ends) with radius ``(b + α (t −
    b)) / sqrt(1 + ((t − b)/len)²)``; the pair intersects if two spheres overlap, ``(r_a + r_b)² > |c_a − c_b|²``.
    A cylinder with ``k = 0`` never intersects (bodytrack's 0·∞ gives NaN centres there).
    """
    A = [[poses[:, i, j] for j in range(3)] for i in range(3)]
    t = [poses[:, i, 3] for i in range(3)]
    return _valid_from_frames(shape, A, t)


def corners(shape: BodyShape, cams: Cameras, x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Cylinder poses ``(10, 3, 4)`` and projected corners ``(V, 10, 4, 2)`` of one state ``x (31,)`` (dtype of
    ``x``)."""
    x = jnp.asarray(x)
    A, t = cylinders._cylinder_frames(shape, x)
    rows = [jnp.stack([A[i][0], A[i][1], A[i][2], t[i]], -1) for i in range(3)]
    return jnp.stack(rows, 1), cylinders._corners(shape, cams, A, t)


# ---------------------------------------------------------------------------------------------------------------
# Sampling
#
# Written for XLA on CPU: inside a loop iteration every sample is a separate elementwise step (explicit adds
# into the per-lane accumulators, no reduction ops, which XLA would materialise), gathers promise in-bounds
# indices (:func:`_index` masks every sample outside the images to pixel 0, so XLA's bounds test and fill are
# not needed: 1.11-1.13x on AMD EPYC family 25 model 1 with either fusion emitter; ``mode="fill"`` had been
# measured 2-3x faster than the clamping modes, and ``promise_in_bounds`` 0.95x of it on 2026-11-25, an earlier
# version of this code on another CPU), and the running parameters ``t`` are accumulated in float32 exactly as
# bodytrack does.

#: 2**23. A float32 that holds an integer ``k`` in ``[2**23, 2**24)`` has ``k − 2**23`` as its 23 mantissa bits, so
#: ``bits(k) − bits(2**23)`` is ``k − 2**23`` as an integer: a float-to-integer conversion by one integer subtraction.
_MAGIC = float(2**23)
_MAGIC_BITS = 0x4B000000  # the bits of float32 2**23


#: The index of a sample not counted when the reads are apart (:func:`_gather`): pixel 0 with the top bit set.
_NOT_COUNTED = 1 << 31


def _exact_float_index(V: int, W: int, H: int) -> bool:
    """Whether every flat pixel index of ``V`` maps of ``W × H`` stays below ``2**23`` (a float32 holds it exactly
    after :data:`_MAGIC` is added): up to 27 cameras at 640×480, 4 at 1920×1080."""
    return V * W * H < 2**23


def _offsets(V: int, W: int, H: int, like: jnp.ndarray) -> jnp.ndarray:
    """Per-lane start of each camera's map in the flat maps, shaped like ``like (V, ...)``: float32 with
    :data:`_MAGIC` added where :func:`_exact_float_index`, else int32. A full array, so that nothing is broadcast
    inside the sampling loops."""
    nb = like.ndim - 1
    if _exact_float_index(V, W, H):
        start = jnp.arange(V, dtype=jnp.float32) * float(W * H) + _MAGIC
    else:
        start = jnp.arange(V, dtype=jnp.int32) * (W * H)
    return _trail(start, nb) + jnp.zeros(like.shape, start.dtype)


def _count(length: jnp.ndarray, step: float, cap: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``n = max(int(length/step + 0.5), 4)`` capped, as float; and whether the length was finite."""
    finite = jnp.isfinite(length)
    n = jnp.floor(jnp.where(finite, length, 0.0) / step + 0.5)
    n = jnp.clip(n, 4.0, float(cap))
    return n, finite


def _index(x, y, offset, W: int, H: int, active, apart: bool = False):
    """Flat pixel index (uint32) and counted mask of samples ``(x, y)`` (float32).

    bodytrack reads pixel ``(int(x + 0.5), int(y + 0.5))``, truncating toward 0, and counts the sample iff that
    column and row lie in ``[0, W)`` and ``[0, H)``, that is iff ``−1 < x + 0.5 < W`` and ``−1 < y + 0.5 < H``
    (tested on the floats: a NaN never counts, like the C++'s out-of-range conversion). Where it counts (``u >
    −1``), ``int(u) = floor(|u|)``, and the flat index ``floor(|v|)·W + floor(|u|) + offset`` is an integer below
    ``2**23`` computed exactly in float32; with :data:`_MAGIC` in ``offset`` its bits minus :data:`_MAGIC_BITS`
    are the index (:func:`_offsets`). XLA's float-to-integer conversion saturates and maps NaN to 0, six vector
    instructions a coordinate on x86: this path takes the likelihood from 4.0 to 3.5 µs of CPU per particle
    (``benchmarks/perf/bench_parsec.py --against``); ``|u|`` (one AND) instead of XLA's NaN-propagating ``max(u,
    0)`` (up to three instructions) another 1.5 %. Maps too large for it (:func:`_exact_float_index`) convert.
    Unsigned indices spare the gather JAX's wrap-around of negative ones; a sample not counted reads pixel 0, and
    with ``apart`` (:func:`_gather`) its index is :data:`_NOT_COUNTED` (pixel 0 with the top bit set).
    """
    u = x + 0.5
    v = y + 0.5
    m = active & (u > -1.0) & (u < W) & (v > -1.0) & (v < H)
    if offset.dtype == jnp.float32:  # a sample not counted gets some index here, masked below
        f = jnp.floor(jnp.abs(v)) * W + jnp.floor(jnp.abs(u)) + offset
        idx = jax.lax.bitcast_convert_type(f, jnp.uint32) - jnp.uint32(_MAGIC_BITS)
    else:
        idx = (
            offset + jnp.maximum(v, 0.0).astype(jnp.int32) * W + jnp.maximum(u, 0.0).astype(jnp.int32)
        ).astype(jnp.uint32)
    return jnp.where(m, idx, jnp.uint32(_NOT_COUNTED if apart else 0)), m


def _gather(flat, idx_masks, apart: bool):
    """Pixel values at the indices of ``[(idx, mask), ...]`` (in bounds: :func:`_index`).

    Fused (``apart`` False), XLA compiles a loop iteration — sample positions, reads and sums — into one kernel,
    whose reads are scalar loads between vector arithmetic; without AVX-512 LLVM then keeps the whole kernel scalar.
    ``apart``: the indices are stacked and materialised (``lax.optimization_barrier``, which XLA does not fuse
    across) and read by one gather, so that the positions compile to vector kernels of their own and only the
    reads and the sums after them stay in a scalar kernel (a second barrier between the reads and the sums made
    no difference: 7.62 against 7.70 µs per particle). The same operations in the same order, in another XLA
    program: equal values for 4000 particles around sequenceB_2's initial pose, but a multiply-add that XLA
    contracts into an FMA in one program and not in the other can move a sample that lies on a pixel border to the
    neighbouring pixel (seen for one probe state of ``tests/parsec/test_parsec.py`` at XLA's lowest optimisation
    level: one edge sample of about 900). On an AMD EPYC without AVX-512 (family 25, model 17, AVX2) the
    likelihood ran 1.49× faster apart (12.25 → 8.06 µs per particle, 1.46× less CPU;
    ``benchmarks/perf/bench_parsec.py --bodytrack-rounds 3 --against HEAD --ab-rounds 7``, 2026-12-01).

    Apart, a sample's mask travels inside its index (:data:`_NOT_COUNTED`: the top bit, which no pixel index has):
    the reads take the index without that bit and count the sample where it is clear. With the masks as arrays of
    their own XLA computed every sample position twice, once in the kernel of the indices and once in a kernel of
    the masks beside it (a fifth of the kernel time); without them the likelihood ran 1.26× faster, 1.26× less
    CPU (6.59 → 5.36 µs per particle, seven interleaved rounds 1.01–1.33, equal values;
    ``bench_parsec.py --bodytrack-rounds 0 --against HEAD --ab-rounds 7``, the same CPU, 2026-12-01)."""
    if not apart:
        return [(flat.at[i].get(mode="promise_in_bounds"), m) for i, m in idx_masks]
    idx = jax.lax.optimization_barrier(jnp.stack([i for i, _ in idx_masks]))
    values = flat.at[idx & jnp.uint32(_NOT_COUNTED - 1)].get(mode="promise_in_bounds")
    return [(values[j], idx[j] < jnp.uint32(_NOT_COUNTED)) for j in range(len(idx_masks))]


#: Per byte value ``v``, what an edge sample adds to its lane's packed accumulator: ``(255 − v)² · 256 + 1``
#: (:func:`_edge_group`), and an inside sample: ``65537`` on background (``v = 0``), else 1 (:func:`_inside_group`).
_EDGE_TABLE = (np.arange(255, -1, -1, dtype=np.uint32) ** 2) * 256 + 1
_INSIDE_TABLE = np.where(np.arange(256) == 0, 65537, 1).astype(np.uint32)


def _lookup(table: jnp.ndarray, v: jnp.ndarray) -> jnp.ndarray:
    """``table[v]`` for bytes ``v`` (``table``: :data:`_EDGE_TABLE` or :data:`_INSIDE_TABLE` as an array, made once
    per loop): where the reads are apart (:func:`_gather`) the sums run in a scalar kernel, in which one load from a
    1 KB table costs less than the arithmetic it replaces (the likelihood 1.08–1.12× faster with both tables, equal
    values: ``bench_parsec.py --against``, two runs of seven rounds, AVX2-only EPYC, 2026-12-01). Maps of other
    dtypes than bytes are summed by comparisons."""
    return table.at[v.astype(jnp.int32)].get(mode="promise_in_bounds")


def _edge_group(uv, flat_edge, config: Config, W: int, H: int, C: int):
    """Edge term of one part group: ``uv (V, g, 4, 2, *B)`` float32 → per-lane SSD and counts ``(V, g, 2, *B)``
    (integers: uint32, or int32 for sides of more than 255 samples); ``C`` samples per lane and loop iteration."""
    V = uv.shape[0]
    p = jnp.stack([uv[:, :, 0], uv[:, :, 2]], 2)  # (V, g, 2 sides, 2 xy, *B): sides P0→P1 and P2→P3
    q = jnp.stack([uv[:, :, 1], uv[:, :, 3]], 2)
    px, py = p[:, :, :, 0], p[:, :, :, 1]
    sx = q[:, :, :, 0] - px
    sy = q[:, :, :, 1] - py
    n, finite = _count(jnp.sqrt(sx * sx + sy * sy), config.edge_step, config.max_edge_n)
    d = 1.0 / n
    count = jnp.where(finite, n + 1.0, 0.0)
    offset = _offsets(V, W, H, px)

    # one uint32 accumulator per lane, SSD in the high bits and the sample count in the low 8 bits, when a side
    # has at most 255 samples (640×480: 161); two int32 accumulators otherwise
    packed = config.max_edge_n + 1 <= 255
    table = jnp.asarray(_EDGE_TABLE) if packed and config.apart else None

    def body_fn(carry):
        k, t, acc = carry
        samples = []
        for j in range(C):
            samples.append(_index(px + t * sx, py + t * sy, offset, W, H, (k * C + j) < count, config.apart))
            t = t + d
        for v, m in _gather(flat_edge, samples, config.apart):
            if table is not None:
                acc = acc + jnp.where(m, _lookup(table, v), jnp.uint32(0))
                continue
            e = 255 - v.astype(jnp.int32)
            if packed:
                acc = acc + jnp.where(m, e * e * 256 + 1, 0).astype(jnp.uint32)
            else:
                acc = (acc[0] + jnp.where(m, e * e, 0), acc[1] + m.astype(jnp.int32))
        return k + 1.0, t, acc

    limit = jnp.max(count)  # outside the condition, which would reduce it again every iteration

    def cond_fn(carry):
        return carry[0] * C < limit

    zeros = jnp.zeros_like(px)
    acc0 = jnp.zeros(px.shape, jnp.uint32) if packed else (jnp.zeros(px.shape, jnp.int32),) * 2
    acc = jax.lax.while_loop(cond_fn, body_fn, (jnp.zeros((), uv.dtype), zeros, acc0))[2]
    if packed:
        return acc >> 8, acc & 255
    return acc


def _inside_group(uv, flat_fg, config: Config, W: int, H: int, C2: int):
    """Inside term of one part group: ``uv (V, g, 4, 2, *B)`` float32 → background and sample counts ``(V, g,
    *B)`` (uint32).

    One loop iteration visits ``config.inside_rows`` (row, block) steps per lane; a block is ``C2`` consecutive
    samples of a row (a row of ``n2`` samples takes ``ceil(n2 / C2)`` blocks). The row stepping's four carried
    values (row, column, ``t1``, ``t2``) are one stacked array: XLA computes them in one kernel instead of one
    kernel each, which recomputed the step's wrap-around four times (the likelihood 1.05× faster, equal values,
    ``bench_parsec.py --against``, AVX2-only EPYC, 2026-12-01).
    """
    V = uv.shape[0]
    p1x, p1y = uv[:, :, 0, 0], uv[:, :, 0, 1]
    p2x, p2y = uv[:, :, 3, 0], uv[:, :, 3, 1]
    s1x, s1y = uv[:, :, 1, 0] - p1x, uv[:, :, 1, 1] - p1y
    s2x, s2y = uv[:, :, 2, 0] - p2x, uv[:, :, 2, 1] - p2y
    mx = p1x + s1x / 2.0 - (p2x + s2x / 2.0)
    my = p1y + s1y / 2.0 - (p2y + s2y / 2.0)
    n1, f1 = _count(jnp.sqrt(s1x * s1x + s1y * s1y), config.inside_vstep, config.max_rows_n)
    n2, f2 = _count(jnp.sqrt(mx * mx + my * my), config.inside_hstep, config.max_cols_n)
    d1 = 1.0 / n1
    d2 = 1.0 / n2
    rows = jnp.where(f1 & f2, n1 + 1.0, 0.0)
    blocks = jnp.ceil(n2 / C2)  # blocks per row
    offset = _offsets(V, W, H, p1x)
    table = jnp.asarray(_INSIDE_TABLE) if config.apart and flat_fg.dtype == jnp.uint8 else None

    def body_fn(carry):
        k, steps, acc = carry
        r, col, delta1, delta2 = steps
        e1x = p1x + delta1 * s1x  # bodytrack's e1 and e2 − e1 of the current row
        e1y = p1y + delta1 * s1y
        ex = (p2x + delta1 * s2x) - e1x
        ey = (p2y + delta1 * s2y) - e1y
        for _ in range(config.inside_rows):
            on_row = r < rows
            left = n2 - col
            samples = []
            for j in range(C2):
                samples.append(
                    _index(
                        e1x + delta2 * ex, e1y + delta2 * ey, offset, W, H, on_row & (j < left), config.apart
                    )
                )
                delta2 = delta2 + d2
            for v, m in _gather(flat_fg, samples, config.apart):
                # one accumulator: background samples in the high 16 bits, all samples in the low 16 bits (a
                # lane has at most (max_rows_n + 1)·max_cols_n < 65536 samples, checked by Config)
                if table is not None:
                    acc = acc + jnp.where(m, _lookup(table, v), jnp.uint32(0))
                else:
                    acc = acc + jnp.where(m, jnp.where(v == 0, 65537, 1), 0).astype(jnp.uint32)
            # next block of this row, or the first block of the next row (bodytrack's two loops)
            col = col + C2
            wrap = col >= n2
            col = jnp.where(wrap, 0.0, col)
            r = jnp.where(wrap, r + 1.0, r)
            delta2 = jnp.where(wrap, 0.0, delta2)
            delta1 = jnp.where(wrap, delta1 + d1, delta1)
            a1x = p1x + delta1 * s1x
            a1y = p1y + delta1 * s1y
            ex = jnp.where(wrap, (p2x + delta1 * s2x) - a1x, ex)
            ey = jnp.where(wrap, (p2y + delta1 * s2y) - a1y, ey)
            e1x = jnp.where(wrap, a1x, e1x)
            e1y = jnp.where(wrap, a1y, e1y)
        return k + 1.0, jnp.stack([r, col, delta1, delta2]), acc

    limit = jnp.max(rows * blocks)  # outside the condition, which would reduce it again every iteration

    def cond_fn(carry):
        return carry[0] * config.inside_rows < limit

    zeros = jnp.zeros_like(p1x)
    init = (jnp.zeros((), uv.dtype), jnp.stack([zeros] * 4), jnp.zeros(p1x.shape, jnp.uint32))
    acc = jax.lax.while_loop(cond_fn, body_fn, init)[-1]
    return acc >> 16, acc & 65535


def _group_sums(uv: jnp.ndarray, obs: Observation, config: Config, totals: bool = False):
    """Per part: edge SSD and counts ``(10, V, 2, *B)`` (two sides), background and inside counts ``(10, V,
    *B)``, float32. Groups of equal size, ``chunk`` and ``inside_cols`` run in one compiled loop per term, scanned
    over them.

    With ``totals`` the four sums over all cameras and parts instead, ``B``-shaped float32: summed as integers in
    the scan's carry (exact where :func:`_exact_totals`, else in float32), so that no per-part array is stacked
    (the stacked outputs cost zero-filled buffers of ``G·V·g·2·B`` each).
    """
    uv = jnp.asarray(uv, jnp.float32)
    V, H, W = obs.edge.shape
    if (W, H) != tuple(config.image_size):
        raise ValueError(f"maps are {W}x{H} but config.image_size is {config.image_size}")
    edge = obs.edge if obs.edge.dtype == jnp.uint8 else jnp.clip(obs.edge, 0, 255).astype(jnp.uint8)
    flat_edge = edge.reshape(-1)
    flat_fg = obs.fg.reshape(-1)
    buckets: dict[tuple[int, int], list] = {}
    for g, c, c2 in zip(config.groups, config.chunks, config.inside_cols, strict=True):
        buckets.setdefault((len(g), c, c2), []).append(g)
    nb = uv.ndim - 4
    dt = jnp.uint32 if _exact_totals(config, V) else jnp.float32  # of the totals
    sums = (jnp.zeros(uv.shape[4:], dt),) * 4
    per_part = [None] * NUM_PARTS
    for (_, c, c2), groups in buckets.items():
        stacked = jnp.stack([uv[:, np.asarray(g)] for g in groups])  # (G, V, g, 4, 2, *B)

        def one(carry, u, c=c, c2=c2):
            lanes = (
                *_edge_group(u, flat_edge, config, W, H, c),
                *_inside_group(u, flat_fg, config, W, H, c2),
            )
            if not totals:
                return None, tuple(a.astype(jnp.float32) for a in lanes)
            return tuple(s + _total(a.astype(dt), nb) for s, a in zip(carry, lanes, strict=True)), None

        if totals:
            sums = jax.lax.scan(one, sums, stacked)[0]
            continue
        _, (err, cnt, bg, ni) = jax.lax.scan(one, None, stacked)
        for k, g in enumerate(groups):
            for j, part in enumerate(g):
                per_part[part] = (err[k, :, j], cnt[k, :, j], bg[k, :, j], ni[k, :, j])
    if totals:
        return tuple(s.astype(jnp.float32) for s in sums)
    return tuple(jnp.stack([p[i] for p in per_part]) for i in range(4))


def _exact_totals(config: Config, V: int) -> bool:
    """Whether the edge SSD of every sample of ``V`` cameras fits a uint32: ``V · 10 parts · 2 sides ·
    (max_edge_n + 1) · 255²`` below ``2**32`` (up to 20 cameras at 640×480)."""
    return V * NUM_PARTS * 2 * (config.max_edge_n + 1) * 255 * 255 < 2**32


def terms_from_corners(uv: jnp.ndarray, obs: Observation, config: Config = Config()):
    """Edge and inside sums for projected corners ``uv (V, 10, 4, 2)`` (cast to float32 first).

    Returns ``(edge_ssd (V, 10), edge_count (V, 10), background (V, 10), inside_count (V, 10))``: per camera and
    part the summed ``(255 − E)²`` over both sides, the number of in-image edge samples, the number of in-image
    inside samples on background and the number of in-image inside samples.
    """
    err, cnt, bg, ni = _group_sums(uv, obs, config)  # (10, V, 2) and (10, V)
    return (
        (err[:, :, 0] + err[:, :, 1]).T,
        (cnt[:, :, 0] + cnt[:, :, 1]).T,
        bg.T,
        ni.T,
    )


def _total(a: jnp.ndarray, nb: int) -> jnp.ndarray:
    """Sum over the leading (lane) axes of ``a (..., *B)`` by explicit adds (no reduction op) → ``B``."""
    flat = a.reshape((-1,) + a.shape[a.ndim - nb :])
    acc = flat[0]
    for i in range(1, flat.shape[0]):
        acc = acc + flat[i]
    return acc


# ---------------------------------------------------------------------------------------------------------------
# The likelihood


def _on_its_own(fn: Callable, x: jnp.ndarray, *args):
    """``fn(*args)`` compiled as a computation of its own: the branch taken of a conditional on a predicate that is
    always true but that XLA cannot fold (``x₀ == x₀ or x₀ ≠ x₀``, true for a NaN too); the other branch, never
    taken, only returns zeros of ``fn``'s shapes (it was a second copy of ``fn`` while the predicate was ``x₀ ==
    x₀``, false for a NaN: 640 of the likelihood program's 10 700 HLO instructions, which every compilation and
    every executable read back pay for; the same values and speed without it). XLA fuses element-wise producers
    into their consumer and drops ``lax.optimization_barrier`` on the CPU; a conditional's branch is a boundary it
    keeps. Used for the sphere test, about 400 operations per particle that XLA otherwise fused into the
    likelihood's last kernel of some 1500 operations, which runs far slower per operation than a small loop does
    (the likelihood 1.05–1.08× faster per core with it on its own: ``benchmarks/perf/bench_parsec.py
    --against``). Batched (under ``vmap``) both branches would run: use it only where ``x`` is the batch itself."""
    first = x.reshape(-1)[0]
    shapes = jax.eval_shape(fn, *args)

    def never(*_):
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    return jax.lax.cond((first == first) | (first != first), fn, never, *args)


def _terms(shape: BodyShape, cams: Cameras, obs: Observation, x: jnp.ndarray, config: Config) -> Terms:
    """:class:`Terms` of states ``x (31, *B)``, batch axes trailing (the hot path)."""
    nb = x.ndim - 1
    A, t = cylinders._cylinder_frames(shape, x)
    uv = cylinders._corners(shape, cams, A, t)
    edge_ssd, n_edge, background, n_inside = _group_sums(uv, obs, config, totals=True)
    edge_err = edge_ssd / (255.0 * 255.0) / jnp.maximum(n_edge, 1.0)
    inside_err = background / jnp.maximum(n_inside, 1.0)
    ll = -(edge_err + inside_err)
    spheres = functools.partial(_valid_from_frames, shape)
    geometry = _on_its_own(spheres, x, A, t) if nb else spheres(A, t)
    valid = geometry & (n_edge > 0) & (n_inside > 0) & jnp.isfinite(ll)
    ll = jnp.where(valid, ll.astype(x.dtype), jnp.asarray(INVALID, x.dtype))
    return Terms(ll, edge_err, inside_err, valid, n_edge, n_inside)


def likelihood_terms(
    shape: BodyShape, cams: Cameras, obs: Observation, x: jnp.ndarray, config: Config = Config()
) -> Terms:
    """bodytrack's log-likelihood and its two error terms for one state ``x (31,)`` (mm, rad). Pure; vmap it, or
    use :func:`log_likelihood_batch`, which computes the same values several times faster.

    ``loglik = −(ErrEdge + ErrInside)`` (module docstring), or ``−1e10`` with ``valid = False`` for intersecting
    cylinders or no in-image sample.
    """
    x = jnp.asarray(x)
    if x.shape != (NUM_DOFS,):
        raise ValueError(f"expected one state of shape (31,), got {x.shape}")
    return _terms(shape, cams, obs, x, config)


def log_likelihood(
    shape: BodyShape, cams: Cameras, obs: Observation, x: jnp.ndarray, config: Config = Config()
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """``(loglik, valid)`` of one state; see :func:`likelihood_terms`."""
    t = likelihood_terms(shape, cams, obs, x, config)
    return t.loglik, t.valid


def log_likelihood_batch(
    shape: BodyShape, cams: Cameras, obs: Observation, X: jnp.ndarray, config: Config = Config()
) -> Terms:
    """:func:`likelihood_terms` of particles ``X (N, 31)`` → fields of shape ``(N,)``, the same values.

    The particles are put on the last axis of every intermediate array, where XLA on CPU vectorises the
    per-sample arithmetic (several times faster than ``vmap``, whose batch axis leads); a batch of more than
    ``config.max_batch`` particles is evaluated in equal chunks, one after the other
    (:func:`jaxmocap.filters.sharding.chunked`).
    """
    X = jnp.asarray(X)
    if X.ndim != 2 or X.shape[1] != NUM_DOFS:
        raise ValueError(f"expected particles of shape (N, 31), got {X.shape}")
    return chunked(lambda x: _terms(shape, cams, obs, x.T, config), config.max_batch)(X)


def make_loglik_batch(shape: BodyShape, cams: Cameras, config: Config = Config()) -> Callable:
    """``loglik_batch(X (N, 31), observation, layer=None) -> (N,)`` for the annealed filters
    (:mod:`jaxmocap.filters`); invalid particles get ``−1e10`` as in bodytrack. The shape is kept concrete so
    that the sphere test uses its static sphere counts."""
    shape = BodyShape(np.asarray(shape.limbs), np.asarray(shape.lengths))

    def loglik_batch(X, observation: Observation, layer=None):
        return log_likelihood_batch(shape, cams, observation, X, config).loglik

    return loglik_batch


def jit_loglik_batch(shape: BodyShape, cams: Cameras, config: Config = Config()) -> Callable:
    """:func:`make_loglik_batch` jitted with this CPU's options for it (:func:`jaxmocap.host.particle_options`):
    ``f(X (N, 31), observation) -> (N,)``."""
    return jax.jit(make_loglik_batch(shape, cams, config), compiler_options=host.particle_options())
