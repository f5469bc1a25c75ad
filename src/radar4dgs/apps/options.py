"""What the command dataclasses share about their options' help."""

from __future__ import annotations

from typing import Any

import tyro


def default_is(text: str) -> Any:
    """``Annotated`` metadata for an option whose value (None, an empty tuple) does not say what
    happens without it: its help ends with "(default: TEXT)" instead of "(default: None)"."""
    return tyro.conf.arg(help_behavior_hint=f"(default: {text})")
