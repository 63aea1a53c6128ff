"""Published decentralised tunings of the MIMO benchmark plants, as data with their citations.

Each :class:`MimoReference` is one published design: the plant, the method, the citation, the
controller form, and every loop's gains as printed (PI rows as ``Kc``, ``Ti``; PID rows as
``Kp``, ``Ki``, ``Kd``). :meth:`MimoReference.gains` gives them in gaintune's parallel form
``{"Kp", "Ki"[, "Kd"]}``. Time units are the plant's (minutes for Wood-Berry, seconds for the
quadruple tank). Loop 1 of Wood-Berry is the distillate composition xD driven by reflux R; loop 2
the bottoms composition xB driven by steam S, reverse-acting (negative gains).

Where each number was checked (``source`` of every row):

* Luyben 1986 BLT: reproduced by :func:`gaintune.classical.blt.blt_tune` to the published
  rounding (tests/classical/test_blt.py); the same values appear in a third-party MATLAB script
  comparing Wood-Berry tunings found with the search tool.
* Chen & Seborg 2003, Boyd-Hast-Åström 2016 and Garrido et al. 2021: the values match that
  third-party script, which cites each paper (Garrido et al. by DOI 10.3390/pr9010140); the
  papers themselves were not reachable, so these are confirmed second-hand only.
* Johansson 2000 quadruple-tank PI: from the issue text; a third-party Python model of the
  process that cites the paper carries K = 3.0, Ti = 30 s for loop 1 in a comment; loop 2
  (K = 2.7, Ti = 40 s) was not found anywhere else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["MimoReference", "WOOD_BERRY_REFERENCES", "QUADTANK_REFERENCES", "REFERENCES"]


@dataclass(frozen=True)
class MimoReference:
    """One published decentralised design: loop ``i`` has the gains ``loops[i]`` as printed."""

    plant: str
    method: str
    citation: str
    form: Literal["PI", "PID"]
    loops: tuple[dict[str, float], ...]
    time_unit: str
    source: str

    def gains(self) -> tuple[dict[str, float], ...]:
        """Every loop in gaintune's parallel form: ``{"Kp", "Ki"}`` (PI) or ``{"Kp", "Ki", "Kd"}`` (PID)."""
        if self.form == "PI":
            return tuple({"Kp": g["Kc"], "Ki": g["Kc"] / g["Ti"]} for g in self.loops)
        return tuple(dict(g) for g in self.loops)


_SECOND_HAND = ("values match a third-party MATLAB comparison of Wood-Berry tunings that cites the paper; "
                "the paper itself not checked")

WOOD_BERRY_REFERENCES: tuple[MimoReference, ...] = (
    MimoReference(
        plant="wood_berry", method="BLT", form="PI", time_unit="min",
        citation="W. L. Luyben, Simple method for tuning SISO controllers in multivariable systems, "
                 "Ind. Eng. Chem. Process Des. Dev. 25(3), 654-660, 1986",
        loops=({"Kc": 0.375, "Ti": 8.29}, {"Kc": -0.075, "Ti": 23.6}),
        source="reproduced by gaintune.classical.blt.blt_tune (F = 2.545); " + _SECOND_HAND),
    MimoReference(
        plant="wood_berry", method="Chen-Seborg", form="PI", time_unit="min",
        citation="D. Chen and D. E. Seborg, Design of decentralized PI control systems based on Nyquist "
                 "stability analysis, J. Process Control 13(1), 27-39, 2003",
        loops=({"Kc": 0.436, "Ti": 11.0}, {"Kc": -0.0945, "Ti": 15.5}),
        source=_SECOND_HAND),
    MimoReference(
        plant="wood_berry", method="Boyd-Hast-Astrom", form="PID", time_unit="min",
        citation="S. Boyd, M. Hast and K. J. Åström, MIMO PID tuning via iterated LMI restriction, "
                 "Int. J. Robust Nonlinear Control 26(8), 1718-1731, 2016",
        loops=({"Kp": 0.1535, "Ki": 0.0210, "Kd": 0.1714}, {"Kp": -0.0692, "Ki": -0.0136, "Kd": -0.1725}),
        source=_SECOND_HAND + "; the derivative filter used with Kd is not recorded here"),
    MimoReference(
        plant="wood_berry", method="Garrido", form="PID", time_unit="min",
        citation="J. Garrido, M. L. Ruz, F. Morilla and F. Vázquez, Iterative method for tuning multiloop "
                 "PID controllers based on single loop robustness specifications in the frequency domain, "
                 "Processes 9(1), 140, 2021, doi:10.3390/pr9010140",
        loops=({"Kp": 0.65, "Ki": 0.064, "Kd": 0.26}, {"Kp": -0.093, "Ki": -0.032, "Kd": -0.176}),
        source=_SECOND_HAND + "; the derivative filter used with Kd is not recorded here"),
)

QUADTANK_REFERENCES: tuple[MimoReference, ...] = (
    MimoReference(
        plant="quadtank_min_phase", method="Johansson PI", form="PI", time_unit="s",
        citation="K. H. Johansson, The quadruple-tank process: a multivariable laboratory process with an "
                 "adjustable zero, IEEE Trans. Control Syst. Technol. 8(3), 456-465, 2000",
        loops=({"Kc": 3.0, "Ti": 30.0}, {"Kc": 2.7, "Ti": 40.0}),
        source="issue text; loop 1 (3.0, 30 s) also in a third-party model citing the paper; loop 2 unconfirmed; "
               "the loops act on y = kc h (V), loop 1 y1 <- v1, loop 2 y2 <- v2"),
)

#: Every reference row, Wood-Berry first.
REFERENCES: tuple[MimoReference, ...] = WOOD_BERRY_REFERENCES + QUADTANK_REFERENCES
