"""qcontrol: adaptive backstepping control of uncertain nonlinear systems with quantized states.

Implements Sun et al., "Global Adaptive Control for Uncertain Nonlinear Systems under
Non-Lipschitz Condition with Quantized States", Electronics 2022, 11, 3160. The data flow is
quantizer -> controller -> plant (ODE or MuJoCo) -> closed-loop engine -> recording/plots/metrics.
"""

from ._version import __version__

__all__ = ["__version__"]
