"""The loop map of a MIMO architecture: an inline SVG drawn from the loop graph (no graphviz).

One row per chain, left to right: the chain's reference, its loops outer to inner (each box names
the loop, its law and the plant output it measures), then the decoupler when there is one, then
the plant with its inputs on the left edge (each fed by the loop or the decoupler row driving it)
and its outputs on the right edge (each with the loops that measure it).
"""

from __future__ import annotations

import itertools
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


def loop_map_svg(arch: dict[str, Any]) -> str:
    """The loop map of ``arch`` (:func:`gaintune.export.mimo.mimo_architecture`) as an ``<svg>`` element."""
    loops, inputs, outputs = arch["loops"], arch["inputs"], arch["outputs"]
    chains = chains_of(loops)
    K = max(len(c) for c in chains)
    dec = arch.get("decoupler")
    n_rows = max(len(chains), len(inputs), len(outputs))
    height = TOP + n_rows * ROW_H + 20
    x_after = LEFT + K * (BOX_W + GAP)
    x_dec = x_after if dec else None
    x_plant = x_after + (DEC_W + GAP if dec else 0) + 8 * len(chains)
    width = x_plant + PLANT_W + 14 + PORT_LABEL_W
    marker = f"lm{next(_ids)}_arrow"
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="loopmap" viewBox="0 0 {width:.0f} {height:.0f}" '
        f'role="img" aria-label="loop map" font-family="DejaVu Sans, Arial, sans-serif">',
        f'<defs><marker id="{marker}" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="7" markerHeight="7" '
        'orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" fill="#344054"/></marker></defs>',
    ]
    span = n_rows * ROW_H
    y_in = [TOP + (j + 0.5) * span / len(inputs) for j in range(len(inputs))]
    y_out = [TOP + (i + 0.5) * span / len(outputs) for i in range(len(outputs))]
    y_row = [TOP + (r + 0.5) * span / len(chains) for r in range(len(chains))]
    dec_inputs = set(dec["inputs"]) if dec else set()
    for r, chain in enumerate(chains):
        yc = y_row[r]
        parts.append(_text(8, yc - 6, "r", anchor="start", size=11, fill="#667085"))
        parts.append(_text(8, yc + 9, loops[chain[0]]["name"], anchor="start", size=11, fill="#667085"))
        parts.append(_arrow([(LEFT - 26, yc), (LEFT, yc)], marker))
        for k, pos in enumerate(chain):
            lp = loops[pos]
            x = LEFT + k * (BOX_W + GAP)
            parts.append(f'<g class="loop" data-loop="{escape(lp["name"])}">')
            parts.append(_box(x, yc - BOX_H / 2, BOX_W, BOX_H, "#eef4ff"))
            parts.append(_text(x + BOX_W / 2, yc - 4, f"{lp['name']} ({lp['type'].upper()})", weight="bold"))
            parts.append(_text(x + BOX_W / 2, yc + 13, f"measures {lp['measure']}", size=11, fill="#475467"))
            parts.append("</g>")
            if k + 1 < len(chain):
                parts.append(_arrow([(x + BOX_W, yc), (x + BOX_W + GAP, yc)], marker))
                parts.append(_text(x + BOX_W + GAP / 2, yc - 6, "sp", size=10, fill="#667085"))
        last = loops[chain[-1]]
        x_end = LEFT + (len(chain) - 1) * (BOX_W + GAP) + BOX_W
        j = last["drive_index"]
        if j < 0:
            continue
        if dec and inputs[j]["name"] in dec_inputs:
            assert x_dec is not None
            parts.append(_arrow([(x_end, yc), (x_dec, yc)], marker))
        else:
            x_turn = x_plant - 10 - 8 * r
            parts.append(_arrow([(x_end, yc), (x_turn, yc), (x_turn, y_in[j]), (x_plant, y_in[j])], marker))
    if dec:
        assert x_dec is not None
        parts.append(_box(x_dec, TOP + 4, DEC_W, span - 8, "#fef7e6"))
        parts.append(_text(x_dec + DEC_W / 2, TOP + span / 2 - 4, "decoupler", weight="bold"))
        parts.append(_text(x_dec + DEC_W / 2, TOP + span / 2 + 12, "u = W v", size=11, fill="#475467"))
        for j, inp in enumerate(inputs):
            if inp["name"] in dec_inputs:
                parts.append(_arrow([(x_dec + DEC_W, y_in[j]), (x_plant, y_in[j])], marker))
    parts.append(_box(x_plant, TOP, PLANT_W, span, "#f2f4f7"))
    parts.append(_text(x_plant + PLANT_W / 2, TOP + span / 2, "plant", size=13, weight="bold"))
    for j, inp in enumerate(inputs):
        label = inp["name"] + ("" if inp["driven_by"] or inp["name"] in dec_inputs else " (no loop)")
        parts.append(_text(x_plant + 6, y_in[j] + 4, label, anchor="start", size=11))
    measured: dict[str, list[str]] = {}
    for lp in loops:
        measured.setdefault(lp["measure"], []).append(lp["name"])
    for i, o in enumerate(outputs):
        parts.append(_text(x_plant + PLANT_W - 6, y_out[i] + 4, o["name"], anchor="end", size=11))
        by = measured.get(o["name"])
        parts.append(_arrow([(x_plant + PLANT_W, y_out[i]), (x_plant + PLANT_W + 14, y_out[i])], marker,
                            dashed=not by))
        parts.append(_text(x_plant + PLANT_W + 18, y_out[i] + 4,
                           f"measured by {', '.join(by)}" if by else "not measured", anchor="start", size=11,
                           fill="#475467"))
    parts.append("</svg>")
    return "\n".join(parts)
