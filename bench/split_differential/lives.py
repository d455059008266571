"""What every driver of compare.py shares: printing its seeded lives, and numbers made
comparable (NaN as text, floats rounded past the noise of a sum's order)."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterable
from typing import Any


def norm(value: Any) -> Any:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else round(value, 6)
    if isinstance(value, (list, tuple)):
        return [norm(item) for item in value]
    return value


def print_lives(life: Callable[[int], Iterable[Any]]) -> None:
    """``life(seed)`` for the seeds ``argv[1]`` .. ``argv[1] + argv[2] - 1``, one line per item."""
    first, count = int(sys.argv[1]), int(sys.argv[2])
    for seed in range(first, first + count):
        for line in life(seed):
            print(seed, repr(line))
