"""The answer first: what a bridge engineer reads in 30 seconds, on top of both reports and at the end of
the terminal output.

`headline(result)` says, in order: EI (and EI per segment when inferred) with its 90 % interval in GN·m²;
the fit check's verdict in words and what it means for that interval; whether the PINN methods agree with
the modal reference; and, when something is wrong, the one thing to do next. A misfit comes first of all,
in the first sentence, with its advice (`advice.diagnose` picks it from the residuals, never per example).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..uq.agreement import agreement
from .document import Headline
from .units import REFERENCE_KEY, name

#: the unit the headline writes EI in
UNIT = "GN·m²"


@dataclass(frozen=True)
class Answer:
    """The headline's content: `lead` (one sentence), `statements` ((label, sentence) pairs), `ok`."""

    lead: str
    statements: tuple[tuple[str, str], ...]
    ok: bool

    def block(self) -> Headline:
        return Headline(self.lead, self.items, "ok" if self.ok else "warning")

    @property
    def items(self) -> tuple[tuple[str, str], ...]:
        """The statements, each starting with a capital (they follow a label)."""
        return tuple((label, capital(text)) for label, text in self.statements)

    def lines(self) -> list[str]:
        """Plain text for the terminal: the inline marks of the report removed."""
        plain = [strip_marks(self.lead)]
        plain += [f"{label}: {strip_marks(text)}" for label, text in self.items]
        return plain


def capital(text: str) -> str:
    """The first letter a capital, past any leading ** mark."""
    i = 2 if text.startswith("**") else 0
    return text[:i] + text[i : i + 1].upper() + text[i + 1 :]


def strip_marks(text: str) -> str:
    """The report's **bold** marks removed (code marks stay: they quote what to type)."""
    return re.sub(r"\*\*(.+?)\*\*", r"\1", text)


def _gn(v: float, digits: int) -> str:
    return f"{v / 1e9:.{digits}f}"


def _digits(ci) -> int:
    """Decimals in GN·m² that show an interval's width with two significant digits."""
    w = abs(ci[1] - ci[0]) / 1e9
    if not math.isfinite(w) or w <= 0:
        return 3
    return int(min(6, max(2, 1 - math.floor(math.log10(w)))))


def ei_sentence(key: str, m: dict, truth: dict | None) -> str:
    """'EI = 1.038 GN·m², 90 % interval 0.979 to 1.077 GN·m² (modal reference; ...)'."""
    e = m["EI"]
    d = _digits(e["ci90"])
    where = ""
    t = (truth or {}).get("EI")
    if t is not None:
        inside = e["ci90"][0] <= t <= e["ci90"][1]
        where = f"; the true {_gn(t, d)} lies {'inside' if inside else '**outside**'}"
    span = "span-equivalent " if m.get("EI_segments") or m.get("EI_x") else ""
    return (
        f"**{span}EI = {_gn(e['mean'], d)} {UNIT}, 90 % interval {_gn(e['ci90'][0], d)} to "
        f"{_gn(e['ci90'][1], d)} {UNIT}**, by the {lower(name(key))}{where}."
    )


def lower(display: str) -> str:
    """'Modal reference (emcee)' -> 'modal reference (emcee)'; 'B-PINN' stays."""
    return display[0].lower() + display[1:] if display[1:2].islower() else display


def segments_sentence(m: dict) -> str | None:
    segs = m.get("EI_segments")
    if not segs:
        return None
    parts = []
    for i, s in enumerate(segs, 1):
        d = _digits(s["ci90"])
        flag = " **likely damaged**" if s.get("p_damaged", 0.0) >= 0.9 else ""
        parts.append(
            f"{i} ({s['x0']:.1f}-{s['x1']:.1f} m) {_gn(s['mean'], d)} "
            f"[{_gn(s['ci90'][0], d)}, {_gn(s['ci90'][1], d)}]{flag}"
        )
    return f"EI per segment ({UNIT}, 90 % interval): " + "; ".join(parts) + "."


def loss_sentence(m: dict) -> str | None:
    """The smooth field's local loss: depth, position and width with their 90 % intervals, and where the
    field is likely damaged."""
    loss, ex = m.get("local_loss"), m.get("EI_x")
    if not loss or not ex:
        return None
    d, p, w = loss["depth"], loss["position"], loss["width"]
    x = [xi for xi, pd in zip(ex["x"], ex["p_damaged"], strict=True) if pd >= 0.9]
    where = (
        f"; **likely damaged** (P > 0.9 that EI is below 90 % of nominal) from {x[0]:.1f} to {x[-1]:.1f} m"
        if x
        else ""
    )
    return (
        f"a local loss {100 * d['median']:.0f} % deep [{100 * d['ci90'][0]:.0f}, {100 * d['ci90'][1]:.0f}] "
        f"at {p['median']:.2f} m [{p['ci90'][0]:.2f}, {p['ci90'][1]:.2f}], width (sd) {w['median']:.2f} m "
        f"[{w['ci90'][0]:.2f}, {w['ci90'][1]:.2f}] (medians, 90 % intervals){where}."
    )


def _fit(methods: dict, key: str) -> tuple[str | None, dict]:
    fc = methods.get(key, {}).get("fit_check") or {}
    return fc.get("verdict"), fc


def fit_sentence(methods: dict, key: str, extra: str = "") -> str:
    verdict, fc = _fit(methods, key)
    others = [k for k in methods if k != key and _fit(methods, k)[0] == "misfit"]
    if verdict == "fits":
        s = (
            f"the model fits the data (fit check p = {fc.get('p_value', float('nan')):.2g}), so the "
            "interval can be read as the girder's EI under the model's assumptions (stated loads and "
            "supports, the noise model)"
        )
        if others:
            s += f"; but {', '.join(name(k) for k in others)} leaves structure in its residuals"
        return s + "."
    if verdict == "misfit":
        return (
            f"**the data contradict the model** (fit check p = {fc.get('p_value', float('nan')):.2g}"
            f"{extra}); the residual figure (`fig_residuals.png`, under Figures) shows what the model "
            "leaves unexplained."
        )
    return "no fit check could run (no predictor or too few data): the model's fit is unknown."


def agreement_sentence(methods: dict) -> tuple[str, bool]:
    """The PINN methods against the reference, in one sentence, and whether nothing disagrees."""
    verdicts = agreement(methods)
    if not verdicts:
        return "only the modal reference ran: no PINN method to compare.", True
    if REFERENCE_KEY not in methods:
        return "the modal reference did not run: no agreement verdict.", True
    agree = [v for v in verdicts if v.agrees]
    bad = [v for v in verdicts if v.agrees is False]
    none = [v for v in verdicts if v.agrees is None]
    parts = []
    if agree:
        worst = max(abs(v.mean_diff_sd) for v in agree)
        lo = min(v.sd_ratio for v in agree)
        hi = max(v.sd_ratio for v in agree)
        ratios = f"{lo:.2f}" if math.isclose(lo, hi) else f"{lo:.2f}-{hi:.2f}"
        who = " and ".join(name(v.method) for v in agree)
        verb = "agrees" if len(agree) == 1 else "agree"
        parts.append(
            f"{who} {verb} with the modal reference (means within {worst:.2f} reference sd, "
            f"spreads {ratios} times the reference's)"
        )
    for v in bad:
        parts.append(
            f"**{name(v.method)} disagrees** with the modal reference ({'; '.join(v.reasons)})"
        )
    for v in none:
        parts.append(f"{name(v.method)}: no verdict")
    return "; ".join(parts) + ".", not bad


def _unconverged(methods: dict) -> list[str]:
    return [k for k, m in methods.items() if (m.get("diagnostics") or {}).get("converged") is False]


def _headline_key(methods: dict) -> str:
    return REFERENCE_KEY if REFERENCE_KEY in methods else next(iter(methods))


def answer(result, advise=None) -> Answer:
    """The headline of a run (module docstring). `advise(result, key)` gives the misfit's `advice.Advice`
    (default `advice.diagnose` with the run's configuration)."""
    from .advice import diagnose

    s = result.summary
    methods = s["methods"]
    key = _headline_key(methods)
    m = methods[key]
    items: list[tuple[str, str]] = []
    ei = ei_sentence(key, m, s.get("truth"))
    verdict, _fc = _fit(methods, key)
    misfit_key = key if verdict == "misfit" else None
    if misfit_key is None:
        misfit_key = next((k for k in methods if _fit(methods, k)[0] == "misfit"), None)
    next_step = None
    if misfit_key is not None:
        adv = (advise or (lambda r, k: diagnose(r, r.config, k)))(result, misfit_key)
        lead = f"**The model does not fit these data**: the residuals point to {adv.cause}; next, {adv.text}."
        e = m["EI"]
        d = _digits(e["ci90"])
        items.append(
            (
                "EI",
                f"{_gn(e['mean'], d)} {UNIT}, 90 % interval {_gn(e['ci90'][0], d)} to "
                f"{_gn(e['ci90'][1], d)} {UNIT} by the {lower(name(key))}: conditional on a model the "
                "data contradict, so not a measurement of the girder until the model is extended.",
            )
        )
        if adv.share is not None:
            explained = f"; the advised extension explains {100 * adv.share:.0f} % of the residuals"
        else:
            explained = ""
        fit_extra = explained
    else:
        lead = ei
    seg = segments_sentence(m) or loss_sentence(m)
    if seg:
        items.append(("Along the span", seg))
    if m.get("identified") is False:
        items.append(
            (
                "Identified",
                "**EI is not identified by these data**: its interval is essentially the prior.",
            )
        )
        next_step = (
            next_step
            or "add measurements that the girder's stiffness moves (more sensors, a heavier load)."
        )
    items.append(("Fit", fit_sentence(methods, key, fit_extra if misfit_key else "")))
    agree_text, agree_ok = agreement_sentence(methods)
    items.append(("Agreement", agree_text))
    if not agree_ok and misfit_key is None:
        next_step = next_step or (
            "use the modal reference's interval, and re-run the disagreeing method with more training "
            "(`--profile fast` or `paper`)."
        )
    bad = _unconverged(methods)
    if bad:
        items.append(
            (
                "Convergence",
                f"{', '.join(name(k) for k in bad)} did not meet {'its' if len(bad) == 1 else 'their'} "
                "convergence criteria: read "
                f"{'its' if len(bad) == 1 else 'their'} interval with care (see Diagnostics).",
            )
        )
        if misfit_key is None and s.get("profile") == "smoke":
            next_step = next_step or "re-run with a longer profile (`--profile fast`)."
    if next_step and misfit_key is None:
        items.append(("Next", next_step))
    ok = misfit_key is None and agree_ok and not bad and m.get("identified") is not False
    return Answer(lead, tuple(items), ok)


#: the last answer computed, so that the terminal reuses the report's (a misfit diagnosis costs seconds)
_LAST: list = []


def cached_answer(result) -> Answer:
    """`answer(result)`, computed once per result object."""
    if _LAST and _LAST[0] is result:
        return _LAST[1]
    a = answer(result)
    _LAST[:] = [result, a]
    return a
