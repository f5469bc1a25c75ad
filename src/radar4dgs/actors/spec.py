"""Actor edits as the render command writes them, parsed and checked without loading torch
(``radar4dgs render --help`` stays fast); the forms are described in :mod:`radar4dgs.actors.edit`."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Sequence

_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"


@dataclass
class ActorEdits:
    """Parsed edits: ``remove_all``, ``remove`` actor ids, ``move`` id -> (lateral, longitudinal) m,
    ``retime`` id -> ("scale", factor) or ("shift", seconds)."""

    remove_all: bool = False
    remove: tuple[int, ...] = ()
    move: dict[int, tuple[float, float]] = field(default_factory=dict)
    retime: dict[int, tuple[str, float]] = field(default_factory=dict)

    @property
    def empty(self) -> bool:
        return not (self.remove_all or self.remove or self.move or self.retime)

    def ids(self) -> set[int]:
        """Every actor id the edits name."""
        return set(self.remove) | set(self.move) | set(self.retime)

    def slug(self) -> str:
        """A file-name-safe suffix naming the edits ('' when none)."""
        parts = ["rm-all"] if self.remove_all else [f"rm{i}" for i in self.remove]
        parts += [f"mv{i}_{x:g},{y:g}" for i, (x, y) in self.move.items()]
        parts += [f"rt{i}_{v:+g}" if kind == "shift" else f"rt{i}_x{v:g}" for i, (kind, v) in self.retime.items()]
        # Only letters, digits and . + - in a file name (as the trajectory slug).
        return re.sub(r"[^A-Za-z0-9.+-]+", "_", "_".join(parts)).strip("_")


def _actor_id(text: str, flag: str, whole: str) -> int:
    if not re.fullmatch(r"\d+", text.strip()):
        raise ValueError(f"{flag} {whole!r}: actor id {text.strip()!r} is not a non-negative integer "
                         "(see `radar4dgs actors RUN` for the ids)")
    return int(text)


def _finite(text: str, flag: str, whole: str, what: str) -> float:
    if not re.fullmatch(_NUMBER, text.strip()) or not math.isfinite(float(text)):
        raise ValueError(f"{flag} {whole!r}: {what} {text.strip()!r} is not a finite number")
    return float(text)


def parse_edits(remove: Sequence[str] = (), move: Sequence[str] = (), retime: Sequence[str] = ()) -> ActorEdits:
    """Parse the render command's flags (module docstring). Raises ValueError naming the flag."""
    edits = ActorEdits()
    removed: list[int] = []
    for text in remove:
        if text.strip().lower() == "all":
            edits.remove_all = True
            continue
        removed += [_actor_id(part, "--remove-actors", text) for part in text.split(",")]
    edits.remove = tuple(sorted(set(removed)))
    for text in move:
        head, sep, tail = text.partition(":")
        values = tail.split(",")
        if not sep or len(values) != 2:
            raise ValueError(f"--move-actor {text!r}: expected ID:DX,DY (metres: lateral, + = left; longitudinal, "
                             "+ = forward)")
        edits.move[_actor_id(head, "--move-actor", text)] = (_finite(values[0], "--move-actor", text, "DX"),
                                                             _finite(values[1], "--move-actor", text, "DY"))
    for text in retime:
        head, sep, tail = text.partition(":")
        tail = tail.strip()
        if not sep or not tail:
            raise ValueError(f"--retime-actor {text!r}: expected ID:SCALE or ID:+SECONDS / ID:-SECONDS")
        actor = _actor_id(head, "--retime-actor", text)
        if tail[0] in "+-":
            edits.retime[actor] = ("shift", _finite(tail, "--retime-actor", text, "SECONDS"))
        else:
            scale = _finite(tail, "--retime-actor", text, "SCALE")
            if scale <= 0:
                raise ValueError(f"--retime-actor {text!r}: SCALE must be positive (write +S or -S for a shift)")
            edits.retime[actor] = ("scale", scale)
    return edits


def check_ids(edits: ActorEdits, actors, where: str) -> None:
    """Raise ValueError naming ``where`` (the actors file) when an edit names an unknown actor."""
    known = {a.id for a in actors}
    unknown = sorted(edits.ids() - known)
    if unknown:
        listing = ", ".join(str(i) for i in sorted(known)) or "none"
        raise ValueError(f"{where}: no actor {unknown[0]} (actors: {listing})")
