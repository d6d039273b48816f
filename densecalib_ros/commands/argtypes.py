"""argparse types that refuse out-of-range numbers at the command line (a usage error, exit 2),
before any work: a negative seed or a zero tolerance would otherwise fail late or mean nothing."""
from __future__ import annotations

import argparse
import math
from typing import Callable, Optional

MAX_SEED = 2 ** 32 - 1  # numpy's and COLMAP's seeds are 32-bit


def number_in(low: float, high: Optional[float] = None, *, integer: bool = False,
              low_open: bool = False) -> Callable[[str], float]:
    """A type: a finite number in [low, high] ((low, high] with low_open)."""
    def parse(text: str):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        too_low = value <= low if low_open else value < low
        if not math.isfinite(value) or too_low or (high is not None and value > high):
            shown = (lambda v: f"{v:d}") if integer else (lambda v: f"{v:g}")
            bound = (f"above {shown(low)}" if low_open else f"at least {shown(low)}") + (
                f" and at most {shown(high)}" if high is not None else "")
            raise argparse.ArgumentTypeError(f"{text} is out of range: give a number {bound}")
        return value
    return parse


def positive(integer: bool = False) -> Callable[[str], float]:
    return number_in(0, integer=integer, low_open=True)


seed = number_in(0, MAX_SEED, integer=True)
