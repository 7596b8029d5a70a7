"""SPADE: sketch-guided path planning augmented with diffusion experts."""

__version__ = "0.1.0"
