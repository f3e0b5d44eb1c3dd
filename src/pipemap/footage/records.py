"""What reading a recording found: damaged frames, repeated frames, dropped frames (for run.json)."""

from __future__ import annotations

from dataclasses import dataclass, field

DAMAGE_KINDS = ("unreadable", "undecodable", "truncated")


@dataclass(frozen=True)
class Damage:
    """Frames `index` .. `index + frames - 1` of the recording could not be read.

    kind: `unreadable` (an image file or bag message that does not decode), `undecodable` (video
    frames the decoder rejected or could not rebuild) or `truncated` (the recording ends before the
    frames its header lists)."""

    path: str
    index: int
    frames: int
    kind: str
    reason: str

    def span(self) -> str:
        if self.frames <= 0:  # the container cannot say how many frames the damage took
            return f"frames from {self.index} on"
        return f"frame {self.index}" if self.frames == 1 else f"frames {self.index}-{self.index + self.frames - 1}"

    def line(self) -> str:
        return f"{self.path}: {self.span()} {self.reason}"

    def to_dict(self) -> dict:
        return {"path": self.path, "index": self.index, "frames": self.frames, "kind": self.kind, "reason": self.reason}


def _ranges(indices: list[int]) -> list[list[int]]:
    """[3, 4, 5, 9] -> [[3, 5], [9, 9]]: long runs of repeated frames stay short in run.json."""
    out: list[list[int]] = []
    for i in indices:
        if out and i == out[-1][1] + 1:
            out[-1][1] = i
        else:
            out.append([i, i])
    return out


@dataclass
class FootageLog:
    """Filled by `Dataset.frames(log=...)` while it streams: one per pass that the caller reports.

    frames: frames handed out (readable, repeated ones included); repeated: their indices, in order;
    drops: (index of the frame after a gap, frames missing in the gap); damage: unreadable stretches;
    predicted: a video whose pictures are predicted from earlier ones; settling_left_out: observations the tracking
    made that the map leaves out for it (frontend/settling.py)."""

    frames: int = 0
    repeated: list[int] = field(default_factory=list)
    drops: list[tuple[int, int]] = field(default_factory=list)
    damage: list[Damage] = field(default_factory=list)
    predicted: bool = False
    settling_left_out: int = 0
    deinterlace: str = "none"  # the de-interlacing the frames got
    deinterlace_why: str = ""  # why, where `auto` chose it

    @property
    def dropped(self) -> int:
        return sum(n for _, n in self.drops)

    @property
    def damaged_frames(self) -> int:
        return sum(d.frames for d in self.damage)

    def add_damage(self, record: Damage) -> None:
        last = self.damage[-1] if self.damage else None
        # Neighbouring holes with the same cause are one record, however the reader found them.
        if last and (last.path, last.kind, last.reason) == (record.path, record.kind, record.reason) \
                and last.index + last.frames == record.index:
            self.damage[-1] = Damage(last.path, last.index, last.frames + record.frames, last.kind, last.reason)
        else:
            self.damage.append(record)

    def to_dict(self) -> dict:
        return {
            "frames_read": self.frames,
            "repeated": len(self.repeated),
            "repeated_frames": _ranges(self.repeated),
            "dropped": self.dropped,
            "drops": [{"before": i, "missing": n} for i, n in self.drops],
            "damaged": self.damaged_frames,
            "damage": [d.to_dict() for d in self.damage],
            "predicted": self.predicted,
            "settling_left_out": self.settling_left_out,
            "deinterlace": {"method": self.deinterlace, "why": self.deinterlace_why or None},
        }

    def line(self) -> str:
        """One line for the terminal: counts, then the damage records."""
        parts = [f"{self.frames} frames read"]
        if self.repeated:
            parts.append(f"{len(self.repeated)} repeated")
        if self.drops:
            parts.append(f"{self.dropped} dropped in {len(self.drops)} gap{'s' if len(self.drops) > 1 else ''}")
        if self.deinterlace != "none":
            why = f": {self.deinterlace_why}" if self.deinterlace_why else ""
            parts.append(f"de-interlaced ({self.deinterlace}{why})")
        text = "footage: " + ", ".join(parts)
        if self.damage:
            text += f"; damage: {'; '.join(d.line() for d in self.damage)}"
        return text
