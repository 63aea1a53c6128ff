"""What every plant form shares about its states and parameters (single-input and MIMO plants alike)."""

from __future__ import annotations

from gaintune.errors import SpecError

__all__ = ["NamedParams"]


class NamedParams:
    """Mixin of a plant dataclass with ``states: list[str]`` and ``params: dict[str, float]`` fields."""

    states: list[str]
    params: dict[str, float]

    @property
    def order(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def param_names(self) -> list[str]:
        """Parameter names, in :meth:`param_vector` order."""
        return list(self.params)

    def with_params(self, values: dict[str, float] | None) -> dict[str, float]:
        """Nominal parameters updated by ``values``; unknown names raise SpecError."""
        out = dict(self.params)
        for k, v in (values or {}).items():
            if k not in out:
                raise SpecError(f"params.{k}", f"unknown parameter; known: {', '.join(out) or 'none'}")
            out[k] = float(v)
        return out
