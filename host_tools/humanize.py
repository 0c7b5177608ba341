"""Values written for people (stdout, README files, plot titles) instead of Python reprs:
numbers with a few significant digits, parameter sets as ``name = value``, lists joined with
commas, the analyzer's selected effects and the suite's parameter score in words."""
from __future__ import annotations

import math
from typing import Any, Iterable, Mapping


def number(v: Any, digits: int = 4) -> str:
    """A number with ``digits`` significant digits (integers as they are); None: 'none'."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    if not math.isfinite(f):
        return str(f)
    return f"{f:.{digits}g}"


def params(p: Mapping[str, Any] | None) -> str:
    """{'ke_ratio': 1.0601} -> 'ke_ratio = 1.06'."""
    return ", ".join(f"{k} = {number(v)}" for k, v in (p or {}).items())


def names(items: Iterable[Any], empty: str = "none") -> str:
    items = [str(x) for x in items]
    return ", ".join(items) if items else empty


def effects(e: Mapping[str, Mapping[str, Any]] | None) -> str:
    """{'motor_back_emf': {'ke_ratio': 1.2}} -> 'motor_back_emf (ke_ratio = 1.2)'."""
    if not e:
        return "none"
    return "; ".join(f"{k} ({params(v)})" if v else k for k, v in e.items())


def selected(sel: Iterable[Mapping[str, Any]] | None) -> str:
    """The analyzer's 'selected' list in words, with what each cannot be told apart from."""
    out = []
    for s in sel or []:
        text = str(s.get("effect"))
        if s.get("params"):
            text += f" ({params(s['params'])})"
        if s.get("equivalent"):
            text += f", equivalent on these data: {names(s['equivalent'])}"
        out.append(text)
    return "; ".join(out) if out else "nothing"


def param_score(p: Mapping[str, Any] | None) -> str:
    """The suite's main-parameter score: 'ke_ratio of motor_back_emf: fitted 1.06, true 1.2
    (error 11.7 %)'."""
    if not p:
        return "not scored"
    text = f"{p.get('name')} of {p.get('effect')}: fitted {number(p.get('fitted'))}, " \
           f"true {number(p.get('true'))}"
    if p.get("rel_err_value") is not None:
        text += f" (error {100 * float(p['rel_err_value']):.2g} %)"
    return text
