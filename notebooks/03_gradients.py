# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---

# %% [markdown]
# # Gradients of the likelihood, and the hybrid filter against the plain APF
#
# With bilinear map lookups (``params={"bilinear": True}``, see :data:`jaxmocap.likelihood.cues.DIFFERENTIABLE`) the image cues
# are differentiable in the pose, and :func:`jaxmocap.likelihood.gradients.batch_value_and_grad` gives every particle's
# ``∂ℓ/∂x`` in one reverse pass. We plot the gradient field over two joint angles of the left arm, then track a
# short synthetic sequence with the APF and with the hybrid APF (:class:`jaxmocap.filters.hybrid.HybridAPF`:
# normalised gradient steps on the best particles of each layer) at the same particle count.
# The full comparison on real mocap (error against likelihood evaluations) is ``benchmarks/experiments/hybrid_vs_apf.py``.

# %%
import matplotlib

matplotlib.use("Agg")
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import scene

from jaxmocap.filters.annealing import Schedule
from jaxmocap.filters.apf import APF
from jaxmocap.filters.hybrid import GradientMove, HybridAPF
from jaxmocap.geometry import body
from jaxmocap.likelihood import compose as L
from jaxmocap.likelihood.gradients import batch_value_and_grad

OUT = scene.output_dir("03_gradients")
GRID = 11 if scene.SMALL else 21
model = body.full25()
rig = scene.rig()
truth = scene.pose(model)
frame = scene.render_frame(model, rig, truth)
i, j = (model.dof_index(n) for n in scene.SWEEP)
lik = L.Likelihood.create(
    model,
    rig,
    [L.Cue("foreground", params={"bilinear": True}), L.Cue("edge_distance", params={"bilinear": True})],
    surface_points=150,
)

# %% [markdown]
# ## Gradient field
# ``ℓ`` and ``(∂ℓ/∂θ_shoulder, ∂ℓ/∂θ_elbow)`` on a grid of ±1 rad around the true angles, the other entries at the truth.

# %%
a = np.linspace(-1.0, 1.0, GRID) + float(truth[i])
b = np.linspace(-1.0, 1.0, GRID) + float(truth[j])
A, B = np.meshgrid(a, b, indexing="ij")
X = jnp.tile(truth, (A.size, 1)).at[:, i].set(A.ravel()).at[:, j].set(B.ravel())
X = jnp.clip(X, model.lower, model.upper)
value_grad = jax.jit(lambda X, o: batch_value_and_grad(lik.batch, X, o, 0))
ll, G = value_grad(X, frame.observation)
ll, G = np.asarray(ll).reshape(A.shape), np.asarray(G)
gi, gj = G[:, i].reshape(A.shape), G[:, j].reshape(A.shape)
norm = np.hypot(gi, gj) + 1e-12
fig, ax = plt.subplots(figsize=(5, 4))
im = ax.imshow(ll.T, origin="lower", extent=(a[0], a[-1], b[0], b[-1]), aspect="auto", cmap="viridis")
ax.quiver(A, B, gi / norm, gj / norm, color="w", scale=30)
ax.plot(float(truth[i]), float(truth[j]), "r+", ms=12, mew=2)
ax.set_xlabel(scene.SWEEP[0] + " (rad)")
ax.set_ylabel(scene.SWEEP[1] + " (rad)")
ax.set_title("ℓ and the direction of ∇ℓ")
fig.colorbar(im, ax=ax)
fig.tight_layout()
fig.savefig(OUT / "gradient_field.png", dpi=80)
# how often does the gradient point towards the truth (positive dot product with the direction to it)?
to_truth = np.stack([float(truth[i]) - A, float(truth[j]) - B], -1)
cos = np.sum(np.stack([gi, gj], -1) * to_truth, -1) / (norm * (np.linalg.norm(to_truth, axis=-1) + 1e-12))
print(f"grid points whose gradient points towards the truth: {100 * np.mean(cos > 0):.0f} %")

# %% [markdown]
# ## Hybrid APF against the plain APF
# A few frames of the arm swinging (:func:`scene.pose`); both filters start at the true first pose with the same
# keys, ``N`` particles × 3 layers, Deutscher's survival-rate rule. Error: mean distance of the 15 evaluation joints.

# %%
T = 3 if scene.SMALL else 8
N = 30 if scene.SMALL else 60
frames = [scene.render_frame(model, rig, scene.pose(model, t)) for t in range(T)]
obs = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[f.observation for f in frames])
std = jnp.where(jnp.asarray(model.angular), 0.08, 0.02).astype(jnp.float32)
sched = Schedule.deutscher(3, 0.5, diffusion_scales=(1.0, 0.6, 0.36))


def loglik(X, o, layer):
    return lik.batch(X, o, 0)


common = dict(lower=model.lower, upper=model.upper)
filters = {
    "APF": APF(loglik, std, N, sched, **common),
    "hybrid (k=5, S=3)": HybridAPF(
        loglik, std, N, sched, move=GradientMove(steps=3, learning_rate=1.0, best_k=5), **common
    ),
}
eval_idx = np.asarray([model.joint_names.index(n) for n in body.EVAL_JOINTS])
joints = jax.vmap(lambda x: body.joint_positions(model, x)[eval_idx])
true_joints = np.asarray(joints(jnp.stack([jnp.asarray(f.state) for f in frames])))
errors = {}
for name, f in filters.items():

    def run(key, f=f):
        state = f.init(key, jnp.asarray(frames[0].state))
        keys = jax.random.split(jax.random.fold_in(key, 1), T)
        _, info = jax.lax.scan(lambda s, ko: f.step(ko[0], s, ko[1]), state, (keys, obs))
        return info.estimate

    est = np.asarray(jax.jit(run)(jax.random.key(0)))
    errors[name] = 1000 * np.mean(
        np.linalg.norm(np.asarray(joints(jnp.asarray(est))) - true_joints, axis=-1), -1
    )
    ev = f.evaluations() if hasattr(f, "evaluations") else {"likelihood": N * 3, "gradient": 0}
    print(f"{name:>18}: mean joint error {errors[name].mean():5.1f} mm; per frame {ev}")

fig, ax = plt.subplots(figsize=(5, 3))
for name, e in errors.items():
    ax.plot(e, "o-", label=name)
ax.set_xlabel("frame")
ax.set_ylabel("mean joint error (mm)")
ax.legend()
fig.tight_layout()
fig.savefig(OUT / "hybrid_vs_apf.png", dpi=80)
print("figures in", OUT)
