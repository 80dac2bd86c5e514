"""NumPy baselines the timed benchmarks compare against, in one module: :mod:`reference.numpy_baselines`."""
