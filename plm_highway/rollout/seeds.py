"""Seeds as the commands take them (``--seeds``, a sweep grid's ``seeds``): one parser for all of them."""

from __future__ import annotations

from collections.abc import Iterable

from plm_highway.errors import BadInput
from plm_highway.io.bounded import refuse_non_ascii_digits

MAX_SEEDS = 1000  # per setting of a report; a sweep grid allows more (its own limit)
SEED_LIMIT = 2 ** 32  # numpy seeds the env and the start perturbation with; a seed lies in [0, 2**32)


def parse_seeds(value: int | str | Iterable, first_seed: int = 0, *, limit: int = MAX_SEEDS,
                what: str = "--seeds") -> list[int]:
    """Seeds from a count N (seeds ``first_seed .. first_seed + N - 1``; an int or text such as ``"5"``) or a list
    (``"0,3,7"`` or a list of ints, taken as given): at most ``limit`` seeds, each in [0, 2**32), none repeated.
    Every error is a BadInput naming ``what`` and the value."""
    if isinstance(value, bool):
        raise BadInput(f"{what} {value!r}: expected a count (e.g. 5) or a list of seeds (e.g. 0,3,7)")
    if isinstance(value, int):
        items, count = [value], True
    elif isinstance(value, str):
        refuse_non_ascii_digits(value, what)
        items = [v.strip() for v in value.split(",")]
        count = len(items) == 1
    else:
        items, count = list(value), False
    try:
        numbers = [int(v) if isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool)) else _not_int(v)
                   for v in items]
    except ValueError:
        raise BadInput(f"{what} {value!r}: expected a count (e.g. 5) or a comma-separated list of seeds "
                       "(e.g. 0,3,7)") from None
    if count:
        n = numbers[0]
        if not 1 <= n <= limit:
            raise BadInput(f"{what} {n}: a count must lie in [1, {limit}]")
        return [first_seed + k for k in range(n)]
    if not numbers or len(numbers) > limit or any(not 0 <= n < SEED_LIMIT for n in numbers):
        raise BadInput(f"{what} {value!r}: give 1..{limit} seeds, each in [0, 2**32)")
    if len(set(numbers)) != len(numbers):
        raise BadInput(f"{what} {value!r}: a seed is repeated")
    return numbers


def _not_int(value) -> int:
    raise ValueError(value)
