"""Seeds as the commands take them (``--seeds``, a sweep grid's ``seeds``): one parser for all of them."""

from __future__ import annotations

from collections.abc import Iterable

from plm_highway.errors import BadInput
from plm_highway.io.bounded import parse_int_text, refuse_non_ascii_digits

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
        numbers, count = [value], True
    elif isinstance(value, str):
        refuse_non_ascii_digits(value, what)
        items = [v.strip() for v in value.split(",")]
        count = len(items) == 1
        try:
            numbers = [parse_int_text(v, what) for v in items]
        except BadInput as exc:
            raise BadInput(f"{what} {value!r}: expected a count (e.g. 5) or a comma-separated list of seeds "
                           f"(e.g. 0,3,7) in the digits 0-9 ({str(exc).removeprefix(what + ': ')})") from None
    else:
        numbers, count = list(value), False
        for index, item in enumerate(numbers):  # a list from a file: numbers, not text ('1' is not the seed 1)
            if isinstance(item, bool) or not isinstance(item, int):
                raise BadInput(f"{what}[{index}] = {item!r}: a seed in a list must be an integer, not "
                               f"{type(item).__name__}")
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
