"""``tpnet crosscheck``'s output: the comparison as text or JSON."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .compare import CaseResult, LayerResult, first_divergence


def report_json(results: Sequence[CaseResult], layers: Sequence[str]) -> dict[str, Any]:
    first = first_divergence(results, layers)

    def fd(r: CaseResult, f: LayerResult) -> dict[str, Any]:
        return {"case": r.case, "layer": f.layer, "max_abs": f.max_abs,
                "tolerance": f.tolerance, "where": f.where}

    return {"first_divergence": fd(*first) if first else None,
            "cases": {r.case: {"first_divergence": fd(r, r.first) if r.first else None,
                               "layers_compared": len(r.layers), "layers_missing": r.missing}
                      for r in results}}


def report_text(results: Sequence[CaseResult], layers: Sequence[str], after: int = 6) -> str:
    """Per case: the first layer beyond its tolerance, its largest error and where it starts,
    then the ``after`` layers that follow it (all agree: the closest call)."""
    lines = []
    width = max(len(r.case) for r in results)
    same_missing = all(r.missing == results[0].missing for r in results)
    for r in results:
        head = f"{r.case:<{width}}  "
        f = r.first
        if f is None:
            worst = max(r.layers, key=lambda x: x.max_abs / x.tolerance)
            lines.append(head + f"agrees: {len(r.layers)} layers within tolerance (closest: "
                         f"{worst.layer}, {worst.max_abs:.2g} of {worst.tolerance:.2g})")
        else:
            lines.append(head + f"DIVERGES at {f.layer}: max |diff| {f.max_abs:.3g} > "
                         f"tolerance {f.tolerance:.2g}, from {f.where_text()}")
            i = r.layers.index(f)
            rest = r.layers[i + 1:i + 1 + after]
            if rest:
                lines.append(" " * (width + 2) + "then: " + ", ".join(
                    f"{x.layer} {x.max_abs:.2g}{'' if x.ok else ' (beyond)'}" for x in rest)
                    + (" ..." if len(r.layers) > i + 1 + after else ""))
        if r.missing and not same_missing:
            lines.append(" " * (width + 2) + f"not in the trace: {', '.join(r.missing)}")
    if results and results[0].missing and same_missing:
        lines.append(f"not in the trace (any case): {', '.join(results[0].missing)}")
    first = first_divergence(results, layers)
    n_bad = sum(r.first is not None for r in results)
    if first is None:
        lines.append(f"all {len(results)} case(s) agree with the reference")
    else:
        c, f = first
        lines.append(f"{n_bad} of {len(results)} case(s) diverge; the earliest layer: {f.layer} "
                     f"(case {c.case}, {f.where_text()})")
    return "\n".join(lines)


__all__ = ["report_json", "report_text"]
