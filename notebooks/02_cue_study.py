# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---

# %% [markdown]
# # Cue study: likelihood sweeps over two joint angles, and mode counting
#
# After Fontmarty et al. (IROS 2007, Fig. 1) and López Méndez (2009, Fig. 4.3): the log-likelihood of each cue on a
# grid of two joint angles of the left arm (shoulder flexion × elbow), all other entries at the true pose. A sharp,
# single peak at the truth makes a cue easy to anneal; flat plateaus and secondary peaks make it ambiguous.
#
# Then the thesis' mode-counting test (§5.2.1): draw particles uniformly over the same two angles, resample them in
# proportion to each cue's likelihood, and fit Gaussian mixtures with the number of components chosen by BIC
# (:func:`jaxmocap.eval.mixtures.count_modes`). Fewer modes: a less ambiguous cue.

# %%
import matplotlib

matplotlib.use("Agg")
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import scene

from jaxmocap.eval import mixtures as gmm
from jaxmocap.filters import annealing, resampling
from jaxmocap.geometry import body
from jaxmocap.likelihood import compose as L

OUT = scene.output_dir("02_cue_study")
GRID = 21 if scene.SMALL else 41
model = body.full25()
rig = scene.rig()
truth = scene.pose(model)
frame = scene.render_frame(model, rig, truth)
i, j = (model.dof_index(n) for n in scene.SWEEP)

# %% [markdown]
# ## Sweeps
# Each cue alone in a :class:`jaxmocap.likelihood.compose.Likelihood`; the grid spans ±1.2 rad around the true angles.

# %%
CUES = {
    "foreground": L.Cue("foreground"),
    "edge_distance": L.Cue("edge_distance"),
    "edges": L.Cue("edges"),
    "keypoints": L.Cue("keypoints", params={"pairs": scene.PAIRS, "sigma_px": 6.0}),
}
a = np.linspace(-1.2, 1.2, GRID) + float(truth[i])
b = np.linspace(-1.2, 1.2, GRID) + float(truth[j])
A, B = np.meshgrid(a, b, indexing="ij")
X = jnp.tile(truth, (A.size, 1)).at[:, i].set(A.ravel()).at[:, j].set(B.ravel())
X = jnp.clip(X, model.lower, model.upper)

# the uniform particles of the mode-counting test below are evaluated in the same call (one compilation per cue)
M = A.size
U = jax.random.uniform(jax.random.key(0), (M, 2), minval=-1.2, maxval=1.2) + jnp.asarray([truth[i], truth[j]])
XU = jnp.clip(jnp.tile(truth, (M, 1)).at[:, i].set(U[:, 0]).at[:, j].set(U[:, 1]), model.lower, model.upper)
sweeps, uniform_ll = {}, {}
for name, cue in CUES.items():
    lik = L.Likelihood.create(model, rig, [cue], surface_points=150)
    ll = np.asarray(jax.jit(lik.batch)(jnp.concatenate([X, XU]), frame.observation, 0))
    sweeps[name], uniform_ll[name] = ll[:M].reshape(A.shape), jnp.asarray(ll[M:])

fig, axes = plt.subplots(1, len(sweeps), figsize=(4 * len(sweeps), 3.6))
for ax, (name, ll) in zip(axes, sweeps.items(), strict=True):
    im = ax.imshow(ll.T, origin="lower", extent=(a[0], a[-1], b[0], b[-1]), aspect="auto", cmap="viridis")
    ax.plot(float(truth[i]), float(truth[j]), "r+", ms=12, mew=2)
    ax.set_title(name)
    ax.set_xlabel(scene.SWEEP[0] + " (rad)")
    ax.set_ylabel(scene.SWEEP[1] + " (rad)")
    fig.colorbar(im, ax=ax, shrink=0.8)
fig.tight_layout()
fig.savefig(OUT / "sweeps.png", dpi=80)
for name, ll in sweeps.items():
    k = np.unravel_index(np.argmax(ll), ll.shape)
    print(
        f"{name:>14}: maximum at ({a[k[0]]:+.2f}, {b[k[1]]:+.2f}) rad; truth ({truth[i]:+.2f}, {truth[j]:+.2f})"
    )

# %% [markdown]
# ## Mode counting (thesis §5.2.1)
# ``M`` uniform particles over the two angles (evaluated above), weights ``∝ p(z | x)^β`` with β set so that the survival rate is 0.2
# (a peaked but not degenerate set), systematic resampling, then a BIC-selected mixture on the resampled angles.

# %%
rng = np.random.default_rng(0)
modes, resampled = {}, {}
for name, ll in uniform_ll.items():
    beta = annealing.solve_beta(ll, 0.2).beta
    idx = resampling.systematic(jax.random.key(1), beta * ll, M)
    S = np.asarray(XU[idx][:, jnp.asarray([i, j])])
    # regularised resampling: a kernel of 0.05 rad on each copy, so that the copies of one particle do not make a
    # degenerate cluster of their own (the grid of uniform draws is ≈ 0.11 rad apart in the small mode)
    S = S + rng.normal(0, 0.05, S.shape)
    K, fits, bics = gmm.count_modes(S, rng, max_components=5)
    modes[name], resampled[name] = K, (S, fits[K - 1])
    print(f"{name:>14}: β = {float(beta):.3g}, modes by BIC = {K} (BIC {np.round(bics, 1)})")

fig, axes = plt.subplots(1, len(CUES) + 1, figsize=(4 * (len(CUES) + 1), 3.6))
for ax, (name, (S, mix)) in zip(axes, resampled.items(), strict=False):
    ax.scatter(S[:, 0], S[:, 1], s=3, alpha=0.4)
    ax.scatter(mix.means[:, 0], mix.means[:, 1], c="k", marker="x", s=60)
    ax.plot(float(truth[i]), float(truth[j]), "r+", ms=12, mew=2)
    ax.set_title(f"{name}: {modes[name]} mode(s)")
    ax.set_xlim(a[0], a[-1])
    ax.set_ylim(b[0], b[-1])
axes[-1].bar(list(modes), list(modes.values()))
axes[-1].set_ylabel("modes (BIC)")
axes[-1].tick_params(axis="x", rotation=30)
fig.tight_layout()
fig.savefig(OUT / "modes.png", dpi=80)
print("figures in", OUT)
