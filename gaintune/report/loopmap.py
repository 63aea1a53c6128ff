"""The loop map of a MIMO architecture: an inline SVG drawn from the loop graph (no graphviz).

One row per chain, left to right: the chain's reference, its loops outer to inner (each box names
the loop, its law and the plant output it measures), then the decoupler when there is one, then
the plant with its inputs on the left edge (each fed by the loop or the decoupler row driving it)
and its outputs on the right edge (each with the loops that measure it).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from html import escape
from typing import Any

__all__ = ["loop_map_svg", "chains_of"]

_ids = itertools.count()
BOX_W, BOX_H, GAP, ROW_H, TOP, LEFT = 150, 44, 46, 70, 30, 70
DEC_W, PLANT_W, PORT_LABEL_W = 92, 150, 150


def chains_of(loops: list[dict[str, Any]]) -> list[list[int]]:
    """The chains of an architecture (positions in evaluation order, outer loop first), in chain order."""
    roots = sorted((lp["chain"], k) for k, lp in enumerate(loops) if lp["parent"] < 0)
    out = []
    for _, k in roots:
        chain = [k]
        nxt = [i for i, lp in enumerate(loops) if lp["parent"] == chain[-1]]
        while nxt:  # each setpoint is driven by one loop and each loop drives one target: a chain is a path
            chain.append(nxt[0])
            nxt = [i for i, lp in enumerate(loops) if lp["parent"] == chain[-1]]
        out.append(chain)
    return out


def _text(x: float, y: float, s: str, *, anchor: str = "middle", size: int = 12, weight: str = "normal",
          fill: str = "#101828") -> str:
    return (f'<text x="{x:.1f}" y="{y:.1f}" text-anchor="{anchor}" font-size="{size}" font-weight="{weight}" '
            f'fill="{fill}">{escape(s)}</text>')


def _arrow(points: list[tuple[float, float]], marker: str, dashed: bool = False) -> str:
    pts = " ".join(f"{x:.1f},{y:.1f}" for x, y in points)
    dash = ' stroke-dasharray="4 3"' if dashed else ""
    return (f'<polyline points="{pts}" fill="none" stroke="#344054" stroke-width="1.4"{dash} '
            f'marker-end="url(#{marker})"/>')


def _box(x: float, y: float, w: float, h: float, fill: str) -> str:
    return (f'<rect x="{x:.1f}" y="{y:.1f}" width="{w:.1f}" height="{h:.1f}" rx="6" fill="{fill}" '
            'stroke="#344054" stroke-width="1.2"/>')


@dataclass(frozen=True)
class _Geo:
    """Where things are: the plant's and the decoupler's x, the y of each chain row, input and output port."""

    x_plant: float
    x_dec: float | None
    span: float
    y_row: list[float]
    y_in: list[float]
    y_out: list[float]
    marker: str


def loop_map_svg(arch: dict[str, Any]) -> str:
    """The loop map of ``arch`` (:func:`gaintune.export.mimo.mimo_architecture`) as an ``<svg>`` element."""
    loops, inputs, outputs = arch["loops"], arch["inputs"], arch["outputs"]
    chains = chains_of(loops)
    K = max(len(c) for c in chains)
    dec = arch.get("decoupler")
    n_rows = max(len(chains), len(inputs), len(outputs))
    span = n_rows * ROW_H
    x_after = LEFT + K * (BOX_W + GAP)
    x_plant = x_after + (DEC_W + GAP if dec else 0) + 8 * len(chains)
    g = _Geo(x_plant=x_plant, x_dec=x_after if dec else None, span=span,
             y_row=[TOP + (r + 0.5) * span / len(chains) for r in range(len(chains))],
             y_in=[TOP + (j + 0.5) * span / len(inputs) for j in range(len(inputs))],
             y_out=[TOP + (i + 0.5) * span / len(outputs) for i in range(len(outputs))],
             marker=f"lm{next(_ids)}_arrow")
    width, height = x_plant + PLANT_W + 14 + PORT_LABEL_W, TOP + span + 20
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="loopmap" viewBox="0 0 {width:.0f} {height:.0f}" '
        f'role="img" aria-label="loop map" font-family="DejaVu Sans, Arial, sans-serif">',
        f'<defs><marker id="{g.marker}" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7" '
        'orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" fill="#344054"/></marker></defs>',
    ]
    dec_inputs = set(dec["inputs"]) if dec else set()
    for r, chain in enumerate(chains):
        parts += _chain(g, r, [loops[k] for k in chain], inputs, dec_inputs)
    parts += _plant(g, loops, inputs, outputs, dec_inputs)
    parts.append("</svg>")
    return "\n".join(parts)


def _chain(g: _Geo, r: int, chain: list[dict[str, Any]], inputs: list[dict[str, Any]],
           dec_inputs: set[str]) -> list[str]:
    """Row ``r``: the reference, the chain's loop boxes outer to inner, the arrow to its input or the decoupler."""
    yc, m = g.y_row[r], g.marker
    parts = [_text(8, yc - 6, "r", anchor="start", size=11, fill="#667085"),
             _text(8, yc + 9, chain[0]["name"], anchor="start", size=11, fill="#667085"),
             _arrow([(LEFT - 26, yc), (LEFT, yc)], m)]
    for k, lp in enumerate(chain):
        x = LEFT + k * (BOX_W + GAP)
        parts += [f'<g class="loop" data-loop="{escape(lp["name"])}">',
                  _box(x, yc - BOX_H / 2, BOX_W, BOX_H, "#eef4ff"),
                  _text(x + BOX_W / 2, yc - 4, f"{lp['name']} ({lp['type'].upper()})", weight="bold"),
                  _text(x + BOX_W / 2, yc + 13, f"measures {lp['measure']}", size=11, fill="#475467"), "</g>"]
        if k + 1 < len(chain):
            parts += [_arrow([(x + BOX_W, yc), (x + BOX_W + GAP, yc)], m),
                      _text(x + BOX_W + GAP / 2, yc - 6, "sp", size=10, fill="#667085")]
    x_end = LEFT + (len(chain) - 1) * (BOX_W + GAP) + BOX_W
    j = chain[-1]["drive_index"]
    if j < 0:
        return parts
    if g.x_dec is not None and inputs[j]["name"] in dec_inputs:
        parts.append(_arrow([(x_end, yc), (g.x_dec, yc)], m))
    else:  # elbows side by side, one per row, so that they do not overlap
        x_turn = g.x_plant - 10 - 8 * r
        parts.append(_arrow([(x_end, yc), (x_turn, yc), (x_turn, g.y_in[j]), (g.x_plant, g.y_in[j])], m))
    return parts


def _plant(g: _Geo, loops: list[dict[str, Any]], inputs: list[dict[str, Any]], outputs: list[dict[str, Any]],
           dec_inputs: set[str]) -> list[str]:
    """The decoupler (if any), the plant box, its input ports and its outputs with the loops measuring each."""
    parts, m, x0 = [], g.marker, g.x_plant
    if g.x_dec is not None:
        xd = g.x_dec
        parts += [_box(xd, TOP + 4, DEC_W, g.span - 8, "#fef7e6"),
                  _text(xd + DEC_W / 2, TOP + g.span / 2 - 4, "decoupler", weight="bold"),
                  _text(xd + DEC_W / 2, TOP + g.span / 2 + 12, "u = W v", size=11, fill="#475467")]
        parts += [_arrow([(xd + DEC_W, g.y_in[j]), (x0, g.y_in[j])], m)
                  for j, inp in enumerate(inputs) if inp["name"] in dec_inputs]
    parts += [_box(x0, TOP, PLANT_W, g.span, "#f2f4f7"),
              _text(x0 + PLANT_W / 2, TOP + g.span / 2, "plant", size=13, weight="bold")]
    for j, inp in enumerate(inputs):
        label = inp["name"] + ("" if inp["driven_by"] or inp["name"] in dec_inputs else " (no loop)")
        parts.append(_text(x0 + 6, g.y_in[j] + 4, label, anchor="start", size=11))
    measured: dict[str, list[str]] = {}
    for lp in loops:
        measured.setdefault(lp["measure"], []).append(lp["name"])
    for i, o in enumerate(outputs):
        y, by = g.y_out[i], measured.get(o["name"])
        parts += [_text(x0 + PLANT_W - 6, y + 4, o["name"], anchor="end", size=11),
                  _arrow([(x0 + PLANT_W, y), (x0 + PLANT_W + 14, y)], m, dashed=not by),
                  _text(x0 + PLANT_W + 18, y + 4, f"measured by {', '.join(by)}" if by else "not measured",
                        anchor="start", size=11, fill="#475467")]
    return parts
