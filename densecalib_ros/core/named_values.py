"""NAME=VALUE values (options such as --mask cam0=PATH, --intrinsics cam0=PATH) whose camera names
may themselves hold '=' (names come from file stems and folders): the name is the longest known
camera name that the value starts with, followed by '='; only without a known one is it the text
before the first '='."""
from __future__ import annotations

from typing import Optional, Sequence


def split_named(value: str, names: Optional[Sequence[str]] = None) -> tuple[str, str, str]:
    """(name, '=', rest) as str.partition('=') gives it, but with a camera of `names` whose name
    holds '=' recognised as the name: 'a=b=/x.png' with camera 'a=b' -> ('a=b', '=', '/x.png')."""
    known = [n for n in names or () if value.startswith(f"{n}=")]
    if known:
        name = max(known, key=len)
        return name, "=", value[len(name) + 1:]
    return value.partition("=")
