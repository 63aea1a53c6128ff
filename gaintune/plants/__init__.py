"""Plant models: LTI (tf/ss + delay), nonlinear casadi ODEs, and the built-in library."""

from gaintune.plants.plant import LinearModel, Plant, build_plant

__all__ = ["LinearModel", "Plant", "build_plant"]
