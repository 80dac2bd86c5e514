"""jaxmocap: differentiable markerless human motion capture with particle filters, in JAX."""

__version__ = "0.1.0"
