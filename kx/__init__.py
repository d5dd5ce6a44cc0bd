"""kx: keep-away soccer teams evolved with NEAT and HyperNEAT, in JAX.

Reproduces Didi & Nitschke, "Multi-Agent Behavior-Based Policy Transfer" (EvoApplications 2016).
"""

__version__ = "0.1.0"
