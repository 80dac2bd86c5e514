# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---

# %% [markdown]
# # Annealing schedules
#
# The annealed particle filter weighs layer ``l`` by ``p(z | x)^β_l``. How β grows over the layers is the schedule
# (:class:`jaxmocap.filters.annealing.Schedule`):
#
# * **fixed** sequences, e.g. IROS 2007 Table II: β = (0.1, 0.4, 1) with diffusion std multipliers (1, 1/2, 1/5);
# * **survival-rate targets** (Deutscher): each β_l solves ``α(β_l) = α_target``, with the survival rate
#   ``α = (Σ w)² / (N Σ w²)``;
# * the thesis' **correction rule** (López Méndez 2009, eq. 6.4): ``β_l = β_{l−1} − ε_l (α_target − α_{l−1})``,
#   ``ε_l = 1/(1 + l)``: one cheap correction per layer instead of a root search;
# * **feature-based** schedules: the cue weights ``λ_c(l)`` change over the layers too
#   (:func:`jaxmocap.likelihood.compose.schedule_preset`: coarse cues first, fine cues later).
#
# On a short synthetic sequence (a ``full25`` subject rendered from its own model, :mod:`scene`) we run one APF
# frame layer by layer and plot the particle clouds of each layer on two joint angles.

# %%
import matplotlib

matplotlib.use("Agg")
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import scene

from jaxmocap.filters import annealing, base
from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import APF
from jaxmocap.geometry import body
from jaxmocap.likelihood import compose as L

OUT = scene.output_dir("01_annealing_schedules")
N = 60 if scene.SMALL else 200
LAYERS = 4
model = body.full25()
rig = scene.rig()
frames = [scene.render_frame(model, rig, scene.pose(model, t)) for t in range(2)]
i, j = (model.dof_index(n) for n in scene.SWEEP)

# %% [markdown]
# ## Feature-based λ schedules
# ``schedule_preset(name, cues, L)`` gives the ``(L, C)`` table of cue weights per layer.

# %%
cue_names = ["foreground", "edge_distance", "keypoints"]
presets = ["apf", "fbapf", "fbapf2", "fbapf3"]
fig, axes = plt.subplots(1, len(presets), figsize=(3.2 * len(presets), 2.8), sharey=True)
for ax, name in zip(axes, presets, strict=True):
    table = L.schedule_preset(name, cue_names, LAYERS)
    for c, cue in enumerate(cue_names):
        ax.plot(range(LAYERS), table[:, c], "o-", label=cue)
    ax.set_title(name)
    ax.set_xlabel("layer")
axes[0].set_ylabel("λ_c(l)")
axes[0].legend(fontsize=7)
fig.tight_layout()
fig.savefig(OUT / "lambda_schedules.png", dpi=80)

# %% [markdown]
# ## β per layer under each rule
# One frame of the APF (``N`` particles × ``L`` layers) from the true pose of frame 0 moved 0.2 rad on every joint
# angle, on the second frame; the same keys for every schedule. ``Info.layers`` reports β and the survival rate.

# %%
lik = L.Likelihood.create(
    model,
    rig,
    [L.Cue("foreground"), L.Cue("edge_distance"), L.Cue("keypoints", params={"pairs": scene.PAIRS})],
    num_layers=LAYERS,
    schedule=L.schedule_preset("fbapf", cue_names, LAYERS),
    surface_points=150,
)


def loglik(X, o, layer):
    return lik.batch(X, o, layer.index)


weigh = jax.jit(loglik)  # the likelihood compiled once for the cells below that call it outside a filter

std = jnp.where(jnp.asarray(model.angular), 0.15, 0.03).astype(jnp.float32)
scales = tuple(0.5**l for l in range(LAYERS))
schedules = {
    "fixed (IROS 2007-like)": Schedule.fixed(np.geomspace(0.02, 1.0, LAYERS), scales),
    "survival α = 0.5": Schedule.deutscher(LAYERS, 0.5, diffusion_scales=scales),
    "corrected (eq. 6.4)": Schedule(
        kind="corrected", num_layers=LAYERS, diffusion_scales=scales, survival_target=0.5
    ),
}
start = jnp.asarray(frames[0].state) + jnp.where(jnp.asarray(model.angular), 0.2, 0.0)
stats = {}
for name, sched in schedules.items():
    f = APF(loglik, std, N, sched, lower=model.lower, upper=model.upper)
    state = f.init(jax.random.key(0), start)
    _, info = jax.jit(f.step)(jax.random.key(1), state, frames[1].observation)
    stats[name] = (np.asarray(info.layers.beta), np.asarray(info.layers.survival_rate))
    print(f"{name:>24}: β = {np.round(stats[name][0], 4)}, α = {np.round(stats[name][1], 2)}")

fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3))
for name, (beta, alpha) in stats.items():
    a1.semilogy(range(LAYERS), beta, "o-", label=name)
    a2.plot(range(LAYERS), alpha, "o-", label=name)
a1.set_xlabel("layer")
a1.set_ylabel("β")
a2.set_xlabel("layer")
a2.set_ylabel("survival rate α")
a2.axhline(0.5, color="k", lw=0.5)
a1.legend(fontsize=7)
fig.tight_layout()
fig.savefig(OUT / "beta_per_layer.png", dpi=80)

# %% [markdown]
# ## The correction rule on its own
# Eq. 6.4 applied repeatedly to one fixed set of log-likelihoods: β moves towards the survival-rate root with
# shrinking steps ``ε_l = 1/(1 + l)`` (the monotone variant never lowers β).

# %%
ll0 = weigh(
    jnp.asarray(start) + 0.1 * jax.random.normal(jax.random.key(2), (N, model.num_dofs)),
    frames[1].observation,
    base.Layer(jnp.int32(LAYERS - 1), jnp.float32(0)),
)
root = float(annealing.solve_beta(ll0, 0.5).beta)
beta, trace = jnp.float32(0.5 * root), []
for l in range(1, 12):
    alpha = annealing.tempered_survival_rate(beta, ll0)
    trace.append((float(beta), float(alpha)))
    beta = annealing.corrected_beta(beta, alpha, l, 0.5, monotone=False)
fig, ax = plt.subplots(figsize=(4, 3))
ax.plot([t[0] for t in trace], "o-", label="β (eq. 6.4)")
ax.axhline(root, color="k", lw=0.5, label="α(β) = 0.5 root")
ax.set_xlabel("iteration")
ax.legend(fontsize=7)
fig.tight_layout()
fig.savefig(OUT / "correction_rule.png", dpi=80)

# %% [markdown]
# ## Particle clouds per layer
# The APF's layers written out with its building blocks (resample, diffuse, weigh with Deutscher's β), keeping every
# layer's particles; the clouds are shown on the two swept joint angles with the true value.

# %%
sched = schedules["survival α = 0.5"]


@jax.jit
def move(k1, k2, X, log_w, l):
    """Resample, then diffuse with layer ``l``'s scale (compiled once: the layer index is data)."""
    X = base.resample("systematic", k1, X, log_w, N)[0]
    return base.diffuse(k2, X, std * jnp.asarray(scales)[l], model.lower, model.upper)


@jax.jit
def temper(ll):
    """Normalised log-weights ``β ll`` with Deutscher's β."""
    return base.normalise(annealing.solve_beta(ll, 0.5).beta * ll)[0]


X = f.init(jax.random.key(0), start).particles
log_w = jnp.full((N,), -jnp.log(N))
clouds = []
key = jax.random.key(3)
for l in range(LAYERS):
    key, k1, k2 = jax.random.split(key, 3)
    X = move(k1, k2, X, log_w, jnp.int32(l))
    log_w = temper(weigh(X, frames[1].observation, base.Layer(jnp.int32(l), jnp.float32(0))))
    clouds.append((np.asarray(X[:, [i, j]]), np.asarray(jnp.exp(log_w))))
truth = frames[1].state
fig, axes = plt.subplots(1, LAYERS, figsize=(3 * LAYERS, 3), sharex=True, sharey=True)
for l, (ax, (P, w)) in enumerate(zip(axes, clouds, strict=True)):
    ax.scatter(P[:, 0], P[:, 1], s=4 + 400 * w, alpha=0.5)
    ax.plot(truth[i], truth[j], "r+", ms=12, mew=2)
    ax.set_title(f"layer {l}")
    ax.set_xlabel(scene.SWEEP[0])
axes[0].set_ylabel(scene.SWEEP[1])
fig.tight_layout()
fig.savefig(OUT / "clouds_per_layer.png", dpi=80)
print("figures in", OUT)
