"""Ratings of a result's sections from its own figures: good, suspect or failed, with the reasons.

A check compares one figure with a (suspect, failed) pair of limits from the `quality` settings;
a section takes the worst rating of its checks, the run the worst of its sections. The reasons
name the figure and its limit, so that an inspector reads why, not only that.
"""

from __future__ import annotations

from dataclasses import dataclass, field

GOOD, SUSPECT, FAILED = "good", "suspect", "failed"
_ORDER = {GOOD: 0, SUSPECT: 1, FAILED: 2}


def worst(ratings) -> str:
    return max(ratings, key=_ORDER.__getitem__, default=GOOD)


@dataclass
class Check:
    name: str  # what was measured, e.g. "free radius"
    value: float | None  # the figure (None: not measured)
    rating: str
    reason: str = ""  # why it is not good ("" when good)

    def to_dict(self) -> dict:
        v = self.value
        return {"check": self.name, "value": None if v is None else round(float(v), 6), "rating": self.rating,
                "reason": self.reason or None}


def above(name: str, value: float | None, limits: tuple[float, float], what: str, fmt=lambda v: f"{v:.3g}") -> Check:
    """A figure that must stay below its limits (value > limit[0]: suspect, > limit[1]: failed)."""
    if value is None:
        return Check(name, None, GOOD)
    rating = FAILED if value > limits[1] else SUSPECT if value > limits[0] else GOOD
    limit = limits[1] if rating == FAILED else limits[0]
    return Check(name, value, rating, "" if rating == GOOD else f"{what} {fmt(value)} (limit {fmt(limit)})")


def below(name: str, value: float | None, limits: tuple[float, float], what: str, fmt=lambda v: f"{v:.3g}") -> Check:
    """A figure that must stay above its limits (value < limit[0]: suspect, < limit[1]: failed)."""
    if value is None:
        return Check(name, None, GOOD)
    rating = FAILED if value < limits[1] else SUSPECT if value < limits[0] else GOOD
    limit = limits[1] if rating == FAILED else limits[0]
    return Check(name, value, rating, "" if rating == GOOD else f"{what} {fmt(value)} (limit {fmt(limit)})")


@dataclass
class SectionVerdict:
    number: int
    kind: str  # "straight", "junction" or the straight-pipe method's "pipe"
    first_frame: int  # image indices (inclusive)
    last_frame: int
    keyframes: int
    checks: list[Check] = field(default_factory=list)
    figures: dict = field(default_factory=dict)  # figures shown but not rated

    @property
    def rating(self) -> str:
        return worst(c.rating for c in self.checks)

    @property
    def reasons(self) -> list[str]:
        bad = sorted((c for c in self.checks if c.rating != GOOD), key=lambda c: -_ORDER[c.rating])
        return [c.reason for c in bad]

    def to_dict(self) -> dict:
        return {"section": self.number, "kind": self.kind, "first_frame": self.first_frame,
                "last_frame": self.last_frame, "keyframes": self.keyframes, "rating": self.rating,
                "reasons": self.reasons, "checks": [c.to_dict() for c in self.checks], "figures": self.figures}


@dataclass
class RunVerdict:
    sections: list[SectionVerdict]
    checks: list[Check] = field(default_factory=list)  # run-wide: loop closure, footage damage
    gaps: list[dict] = field(default_factory=list)  # stretches of the route the trajectory does not bridge

    @property
    def rating(self) -> str:
        return worst([s.rating for s in self.sections] + [c.rating for c in self.checks])

    def counts(self) -> dict[str, int]:
        out = {GOOD: 0, SUSPECT: 0, FAILED: 0}
        for s in self.sections:
            out[s.rating] += 1
        return out

    def line(self) -> str:
        """One line: the map's rating, the sections per rating, and the first reason for the worst."""
        n = self.counts()
        parts = [f"{n[r]} section{'s' if n[r] != 1 else ''} {r}" for r in (GOOD, SUSPECT, FAILED) if n[r]]
        text = f"map {self.rating}: " + (", ".join(parts) if parts else "no sections")
        why = [f"section {s.number}: {s.reasons[0]}" for s in self.sections if s.rating == self.rating and s.reasons]
        why += [c.reason for c in self.checks if c.rating == self.rating and c.reason]
        if self.rating != GOOD and why:
            text += ": " + why[0] + (f" (and {len(why) - 1} more)" if len(why) > 1 else "")
        if self.gaps:
            text += f"; {len(self.gaps)} gap{'s' if len(self.gaps) > 1 else ''} in the trajectory"
        return text

    def to_dict(self) -> dict:
        return {"rating": self.rating, "line": self.line(), "counts": self.counts(),
                "sections": [s.to_dict() for s in self.sections], "checks": [c.to_dict() for c in self.checks],
                "gaps": self.gaps}


__all__ = ["GOOD", "SUSPECT", "FAILED", "Check", "SectionVerdict", "RunVerdict", "above", "below", "worst"]
