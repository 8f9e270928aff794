"""Plants the closed-loop engine can drive: the ideal ODE chain and the MuJoCo model."""

from .base import Plant

__all__ = ["Plant"]
