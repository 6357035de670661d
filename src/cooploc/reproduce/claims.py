"""A paper's claims as data, and their verdicts computed from our numbers (DESIGN §10).

A `Claim` records what a paper states (``statement``), the paper's number or direction
as it prints it (``paper``), the quantity we compute (``quantity``) and a `Verdict`. A
verdict comes from one of the checks below, never from hand-written prose:

- `less` (and `greater`): is a < b? With per-run samples, the mean difference and its
  90 % t interval (paired over common random numbers unless ``paired=False``, then
  Welch): reproduced when the interval lies below 0, "reversed" when it lies above,
  "not significant" otherwise. With single values, the point comparison.
- `close_to`: does ours equal the paper's number within a tolerance? With samples, an
  equivalence test (TOST at the interval's level): reproduced when the whole interval
  lies inside paper ± tolerance, not reproduced when it lies outside, inconclusive
  (not reproduced) when it straddles a bound.
- `at_most` / `at_least`: a target or threshold, decided on the point estimate (the
  interval, if any, is printed beside it).
- `trend`: a curve increases or decreases (each step may go against the trend by at
  most ``tolerance``; the ends must move by more than it).
- `flat`: a curve's span stays within a tolerance (relative to its mean by default).
- `linear`: a straight-line fit's R² reaches a minimum.
- `not_checked`: the claim cannot be checked, with the reason.

Outcomes are the three strings of `OUTCOMES`. `claims_table` renders the Markdown table
of a report; `Claim.to_dict` is what `claims.json` holds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from cooploc.errors import InvalidInputError

__all__ = [
    "LEVEL",
    "NOT_CHECKED",
    "NOT_REPRODUCED",
    "OUTCOMES",
    "REPRODUCED",
    "Claim",
    "Verdict",
    "at_least",
    "at_most",
    "claims_table",
    "close_to",
    "flat",
    "greater",
    "less",
    "linear",
    "mean_interval",
    "not_checked",
    "trend",
]

REPRODUCED = "reproduced"
NOT_REPRODUCED = "not reproduced"
NOT_CHECKED = "not checked"
OUTCOMES = (REPRODUCED, NOT_REPRODUCED, NOT_CHECKED)
LEVEL = 0.90


@dataclass(frozen=True)
class Verdict:
    """The outcome of one check.

    Attributes
    ----------
    outcome : one of `OUTCOMES`.
    ours : our number(s), formatted for the report.
    test : the comparison made and its result, in words (e.g. the interval).
    """

    outcome: str
    ours: str
    test: str

    @property
    def reproduced(self) -> bool:
        return self.outcome == REPRODUCED


@dataclass(frozen=True)
class Claim:
    """One statement of a paper and its computed verdict.

    Attributes
    ----------
    statement : what the paper says, with where (figure, section).
    paper : the paper's number or direction, as it prints it.
    quantity : what we compute to check it.
    verdict : from a check of this module.
    """

    statement: str
    paper: str
    quantity: str
    verdict: Verdict

    @property
    def outcome(self) -> str:
        return self.verdict.outcome

    def to_dict(self) -> dict[str, Any]:
        return {"statement": self.statement, "paper": self.paper, "quantity": self.quantity,
                **asdict(self.verdict)}


def claims_table(claims: Sequence[Claim], first_column: str = "statement of the paper") -> list[str]:
    """The Markdown table of a report: statement, paper, ours, test, verdict (`first_column`
    names the statements, e.g. for checks of a report's own analysis)."""
    lines = [f"| {first_column} | paper | ours | test | verdict |", "|---|---|---|---|---|"]
    for c in claims:
        verdict = f"**{c.outcome}**" if c.outcome == REPRODUCED else c.outcome
        lines.append(f"| {_cell(c.statement)} | {_cell(c.paper)} | {_cell(c.quantity)}: "
                     f"{_cell(c.verdict.ours)} | {_cell(c.verdict.test)} | {verdict} |")
    return lines


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _samples(name: str, values: float | Sequence[float] | np.ndarray) -> np.ndarray:
    array = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
    if array.size == 0:
        raise InvalidInputError(f"claim check: {name} has no values")
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"claim check: {name} has non-finite values {array[~np.isfinite(array)][:3]}")
    return array


def mean_interval(values: float | Sequence[float] | np.ndarray, level: float = LEVEL
                  ) -> tuple[float, float, float]:
    """Mean of `values` and its two-sided `level` t interval ((nan, nan) for one value)."""
    x = _samples("values", values)
    mean = float(x.mean())
    if x.size < 2:
        return mean, float("nan"), float("nan")
    from scipy import stats

    half = float(stats.t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return mean, mean - half, mean + half


def _fmt(value: float, digits: int) -> str:
    return f"{value:.{digits}g}"


def _with_interval(mean: float, lo: float, hi: float, unit: str, digits: int, level: float) -> str:
    text = f"{_fmt(mean, digits)}{unit}"
    if np.isfinite(lo):
        text += f" ({level:.0%} interval {_fmt(lo, digits)} … {_fmt(hi, digits)})"
    return text


def _difference_interval(a: np.ndarray, b: np.ndarray, paired: bool, level: float
                         ) -> tuple[float, float, float]:
    if paired:
        if a.size != b.size:
            raise InvalidInputError(f"claim check: paired samples differ in size ({a.size} vs {b.size})")
        return mean_interval(a - b, level)
    mean = float(a.mean() - b.mean())
    if a.size < 2 or b.size < 2:
        return mean, float("nan"), float("nan")
    from scipy import stats

    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    dof = (va + vb) ** 2 / (va ** 2 / (a.size - 1) + vb ** 2 / (b.size - 1)) if va + vb > 0 else np.inf
    half = float(stats.t.ppf(0.5 + level / 2, dof) * np.sqrt(va + vb))
    return mean, mean - half, mean + half


def less(a: float | Sequence[float], b: float | Sequence[float], *, names: tuple[str, str] = ("a", "b"),
         unit: str = "", paired: bool = True, level: float = LEVEL, digits: int = 3) -> Verdict:
    """Is a < b? Per-run samples give a `level` interval of the mean difference a − b."""
    x, y = _samples(names[0], a), _samples(names[1], b)
    ours = (f"{names[0]} {_with_interval(*mean_interval(x, level), unit, digits, level)}, "
            f"{names[1]} {_with_interval(*mean_interval(y, level), unit, digits, level)}")
    if x.size == 1 and y.size == 1:
        outcome = REPRODUCED if x[0] < y[0] else NOT_REPRODUCED
        return Verdict(outcome, ours, f"single values: {names[0]} − {names[1]} = "
                                      f"{_fmt(x[0] - y[0], digits)}{unit} (no interval)")
    mean, lo, hi = _difference_interval(x, y, paired, level)
    kind = "paired over the same runs" if paired else "Welch, unpaired"
    test = (f"{names[0]} − {names[1]} = {_fmt(mean, digits)}{unit}, {level:.0%} interval "
            f"{_fmt(lo, digits)} … {_fmt(hi, digits)} ({kind})")
    if not np.isfinite(lo):
        outcome, word = (REPRODUCED if mean < 0 else NOT_REPRODUCED), "one run, no interval"
    elif hi < 0:
        outcome, word = REPRODUCED, "significant"
    elif lo > 0:
        outcome, word = NOT_REPRODUCED, "reversed"
    else:
        outcome, word = NOT_REPRODUCED, "not significant"
    return Verdict(outcome, ours, f"{test}: {word}")


def greater(a: float | Sequence[float], b: float | Sequence[float], *, names: tuple[str, str] = ("a", "b"),
            unit: str = "", paired: bool = True, level: float = LEVEL, digits: int = 3) -> Verdict:
    """Is a > b? (`less` with the roles swapped.)"""
    return less(b, a, names=(names[1], names[0]), unit=unit, paired=paired, level=level, digits=digits)


def close_to(ours: float | Sequence[float], paper: float, *, rel: float | None = None,
             abs: float | None = None, unit: str = "", level: float = LEVEL, digits: int = 3) -> Verdict:
    """Does ours equal the paper's number within ``abs`` or ``rel`` × |paper| (the larger)?"""
    if rel is None and abs is None:
        raise InvalidInputError("claim check close_to: give rel or abs, the tolerance")
    tol = max(0.0 if abs is None else abs, 0.0 if rel is None else rel * np.fabs(paper))
    mean, lo, hi = mean_interval(ours, level)
    band = f"{_fmt(paper - tol, digits)} … {_fmt(paper + tol, digits)}{unit}"
    text = _with_interval(mean, lo, hi, unit, digits, level)
    if not np.isfinite(lo):
        outcome = REPRODUCED if np.fabs(mean - paper) <= tol else NOT_REPRODUCED
        return Verdict(outcome, text, f"point estimate against paper ± tolerance {band}")
    if paper - tol <= lo and hi <= paper + tol:
        outcome, word = REPRODUCED, "interval inside"
    elif hi < paper - tol or lo > paper + tol:
        outcome, word = NOT_REPRODUCED, "interval outside"
    else:
        outcome, word = NOT_REPRODUCED, "inconclusive: interval straddles a bound of"
    return Verdict(outcome, text, f"equivalence test: {word} paper ± tolerance {band}")


def _threshold(ours: float | Sequence[float], limit: float, below: bool, unit: str, level: float,
               digits: int) -> Verdict:
    mean, lo, hi = mean_interval(ours, level)
    ok = mean <= limit if below else mean >= limit
    sign = "≤" if below else "≥"
    test = f"point estimate {sign} {_fmt(limit, digits)}{unit}"
    if np.isfinite(lo) and lo <= limit <= hi:
        test += " (the interval contains the limit)"
    ours_text = _with_interval(mean, lo, hi, unit, digits, level)
    return Verdict(REPRODUCED if ok else NOT_REPRODUCED, ours_text, test)


def at_most(ours: float | Sequence[float], limit: float, *, unit: str = "", level: float = LEVEL,
            digits: int = 3) -> Verdict:
    """Is ours ≤ limit (a target or a paper's bound)?"""
    return _threshold(ours, limit, True, unit, level, digits)


def at_least(ours: float | Sequence[float], limit: float, *, unit: str = "", level: float = LEVEL,
             digits: int = 3) -> Verdict:
    """Is ours ≥ limit?"""
    return _threshold(ours, limit, False, unit, level, digits)


def _curve(values: Sequence[float], unit: str, digits: int) -> str:
    return ", ".join(_fmt(v, digits) for v in values) + unit


def trend(values: Sequence[float], direction: str, *, tolerance: float = 0.0, unit: str = "",
          digits: int = 3) -> Verdict:
    """Does the curve `values` go ``"up"`` or ``"down"``? Each step may go against the
    trend by at most `tolerance`, and the last value must differ from the first by more."""
    if direction not in ("up", "down"):
        raise InvalidInputError(f"claim check trend: direction must be 'up' or 'down', got {direction!r}")
    y = _samples("curve", values)
    if y.size < 2:
        raise InvalidInputError(f"claim check trend: needs at least two values, got {y.size}")
    sign = 1.0 if direction == "up" else -1.0
    steps = sign * np.diff(y)
    total = sign * (y[-1] - y[0])
    ok = bool(steps.min() >= -tolerance and total > tolerance)
    word = "increasing" if direction == "up" else "decreasing"
    test = (f"{word}: ends move {_fmt(y[-1] - y[0], digits)}{unit}, worst step against the trend "
            f"{_fmt(max(0.0, -steps.min()), digits)}{unit} (tolerance {_fmt(tolerance, digits)}{unit})")
    return Verdict(REPRODUCED if ok else NOT_REPRODUCED, _curve(y, unit, digits), test)


def flat(values: Sequence[float], *, tolerance: float, relative: bool = True, unit: str = "",
         digits: int = 3) -> Verdict:
    """Is the curve's span (max − min) within `tolerance` (× |mean| when `relative`)?"""
    y = _samples("curve", values)
    span = float(y.max() - y.min())
    limit = tolerance * float(np.fabs(y.mean())) if relative else tolerance
    what = f"{tolerance:.0%} of the mean" if relative else f"{_fmt(tolerance, digits)}{unit}"
    return Verdict(REPRODUCED if span <= limit else NOT_REPRODUCED, _curve(y, unit, digits),
                   f"span {_fmt(span, digits)}{unit} against {what}")


def linear(x: Sequence[float], y: Sequence[float], *, min_r2: float, digits: int = 3) -> Verdict:
    """Does a straight line fit (R² ≥ `min_r2`)?"""
    xs, ys = _samples("x", x), _samples("y", y)
    if xs.size != ys.size or xs.size < 3:
        raise InvalidInputError(f"claim check linear: needs ≥ 3 paired points, got {xs.size} and {ys.size}")
    slope, intercept = np.polyfit(xs, ys, 1)
    residual = float(np.sum((ys - (slope * xs + intercept)) ** 2))
    total = float(np.sum((ys - ys.mean()) ** 2))
    r2 = 1.0 - residual / total if total > 0 else 1.0
    return Verdict(REPRODUCED if r2 >= min_r2 else NOT_REPRODUCED, _curve(ys, "", digits),
                   f"straight-line fit R² = {r2:.3f} against ≥ {min_r2:g}")


def not_checked(why: str, ours: str = "–") -> Verdict:
    """A claim we cannot check, and why."""
    return Verdict(NOT_CHECKED, ours, why)
