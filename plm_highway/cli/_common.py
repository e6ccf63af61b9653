"""Pieces every adapter uses: the command entry, bounded number types, the shared options."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    name: str
    help: str
    configure: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str | None = None


def strict_int(text: str) -> int:
    """An argparse type: an integer in the digits 0-9 (no '_' separators, no other scripts' digits)."""
    from plm_highway.errors import BadInput
    from plm_highway.io.bounded import parse_int_text

    try:
        return parse_int_text(text, "value")
    except BadInput as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("value: ")) from None


strict_int.__name__ = "integer"


def strict_float(text: str, *, non_finite: bool = False) -> float:
    """An argparse type: a decimal number in the digits 0-9 (no '_' separators, no other scripts' digits)."""
    from plm_highway.errors import BadInput
    from plm_highway.io.bounded import parse_float_text

    try:
        return parse_float_text(text, "value", non_finite=non_finite)
    except BadInput as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("value: ")) from None


strict_float.__name__ = "number"


def bounded_int(minimum: int, maximum: int) -> Callable[[str], int]:
    """An argparse type: an integer in [minimum, maximum], refused by name otherwise."""

    def parse(text: str) -> int:
        value = strict_int(text)
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"{value} is outside the accepted range [{minimum}, {maximum:,}]")
        return value

    parse.__name__ = "integer"
    return parse


def bounded_float(minimum: float, maximum: float, *, open_minimum: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [minimum, maximum] (or (minimum, maximum] if ``open_minimum``)."""

    def parse(text: str) -> float:
        value = strict_float(text, non_finite=True)
        low_ok = value > minimum if open_minimum else value >= minimum
        if not math.isfinite(value) or not low_ok or value > maximum:
            bracket = "(" if open_minimum else "["
            raise argparse.ArgumentTypeError(f"{text} is outside the accepted range {bracket}{minimum:g}, {maximum:g}]")
        return value

    parse.__name__ = "number"
    return parse


SEED = bounded_int(0, 2**32 - 1)


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an earlier output of the same kind written by plm-highway (never anything else)")


DEVICE_CHOICES = ("auto", "cpu", "cuda")  # plm_highway.models.device's, spelled here so --help imports no torch


def add_device(parser: argparse.ArgumentParser, default: str = "auto") -> None:
    """``--device auto|cpu|cuda``; :func:`device_of` turns it into a torch.device (``cuda`` without CUDA: exit 2)."""
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=default,
                        help="where the models run: auto (a CUDA GPU when torch sees one, else the CPU), cpu, or "
                             "cuda (refused when torch has no CUDA)")


def device_of(args: argparse.Namespace):
    """The torch.device that ``--device`` names (:class:`~plm_highway.errors.BadInput` for CUDA without CUDA)."""
    from plm_highway.models.device import resolve_device

    return resolve_device(args.device)


def add_seed(parser: argparse.ArgumentParser, default: int = 0) -> None:
    parser.add_argument("--seed", type=SEED, default=default, help="random seed (0 to 2**32-1)")


def _module_tree(module: str):
    """The parsed source of a ``plm_highway`` module, read without importing it (or anything it imports)."""
    import ast
    from pathlib import Path

    parts = module.split(".")
    if parts[0] != "plm_highway":
        raise ValueError(f"{module}: not a plm_highway module")
    path = Path(__file__).resolve().parent.parent.joinpath(*parts[1:]).with_suffix(".py")
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def static_defaults(module: str, function: str) -> dict:
    """The keyword defaults of ``module.function``, read from its source: what :func:`defaults_of` gives, without
    importing the library behind a command (``--help`` stays fast and imports no torch). Only the defaults
    :func:`static_fields` can read are there (a computed one, e.g. ``np.arange(...)``, is left out)."""
    import ast

    for node in _module_tree(module).body:
        if isinstance(node, ast.FunctionDef) and node.name == function:
            args = node.args
            positional = [*args.posonlyargs, *args.args]
            pairs = list(zip(positional[len(positional) - len(args.defaults):], args.defaults))
            pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults) if d is not None]
            return {arg.arg: value for arg, default in pairs
                    if (value := _static_eval(module, default, None)) is not _UNREADABLE}
    raise ValueError(f"{module}: no function {function}")


def static_names(module: str, name: str) -> tuple:
    """A module-level tuple of names (or a dict's keys, or ``tuple(OTHER)`` of such a constant), read from the
    module's source without importing it."""
    import ast

    assigned = {target.id: node.value for node in _module_tree(module).body if isinstance(node, ast.Assign)
                for target in node.targets if isinstance(target, ast.Name)}

    def names(value) -> tuple:
        if isinstance(value, ast.Call) and getattr(value.func, "id", None) == "tuple" and len(value.args) == 1:
            inner = value.args[0]
            return names(assigned[inner.id]) if isinstance(inner, ast.Name) else names(inner)
        if isinstance(value, ast.Dict):  # its keys (the values need not be literals)
            return tuple(ast.literal_eval(key) for key in value.keys)
        return tuple(ast.literal_eval(value))  # a tuple or a list

    if name not in assigned:
        raise ValueError(f"{module}: no module-level {name}")
    return names(assigned[name])


def static_fields(module: str, cls: str) -> dict:
    """The defaults of a dataclass's fields (``name: type = value``), read from ``module``'s source without
    importing it: what ``defaults_of(cls)`` gives for the fields whose default :func:`static_value` can read
    (a literal, arithmetic on literals, ``Path(...)`` of literals, an item of a literal dict, or a module-level
    constant, also one imported from another module)."""
    import ast

    for node in _module_tree(module).body:
        if isinstance(node, ast.ClassDef) and node.name == cls:
            return {item.target.id: _static_eval(module, item.value) for item in node.body
                    if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)
                    and item.value is not None and not isinstance(item.value, ast.Call)}
    raise ValueError(f"{module}: no class {cls}")


def static_value(module: str, name: str):
    """A module-level constant of ``module`` (see :func:`static_fields` for what can be read), without importing it."""
    return _static_eval(module, _module_names(module)[name])


def _module_names(module: str) -> dict:
    """Module-level names: assigned ones to their value node, ``from plm_highway.X import NAME`` ones to
    ``(X, NAME)``."""
    import ast

    found = {}
    for node in _module_tree(module).body:
        if isinstance(node, ast.Assign):
            found.update({target.id: node.value for target in node.targets if isinstance(target, ast.Name)})
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value is not None:
            found[node.target.id] = node.value
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("plm_highway"):
            found.update({alias.asname or alias.name: (node.module, alias.name) for alias in node.names})
    return found


_UNREADABLE = object()


def _static_eval(module: str, node, unreadable=ValueError):
    """The value of ``node``, an expression of ``module``; one it cannot read raises ``ValueError``, or with
    ``unreadable=None`` gives :data:`_UNREADABLE`."""
    import ast

    if unreadable is None:
        try:
            return _static_eval(module, node)
        except (ValueError, KeyError, TypeError, IndexError):
            return _UNREADABLE
    import operator

    binary = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
              ast.Pow: operator.pow, ast.FloorDiv: operator.floordiv}
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, (ast.Tuple, ast.List)):
        values = [_static_eval(module, item) for item in node.elts]
        return tuple(values) if isinstance(node, ast.Tuple) else values
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return -_static_eval(module, node.operand)
    if isinstance(node, ast.BinOp) and type(node.op) in binary:
        return binary[type(node.op)](_static_eval(module, node.left), _static_eval(module, node.right))
    if isinstance(node, ast.Dict) and None not in node.keys:
        return {_static_eval(module, key): _static_eval(module, value) for key, value in zip(node.keys, node.values)}
    if isinstance(node, ast.Subscript):
        return _static_eval(module, node.value)[_static_eval(module, node.slice)]
    if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Path" and not node.keywords:
        from pathlib import Path

        return Path(*(_static_eval(module, arg) for arg in node.args))
    if isinstance(node, ast.Name):
        target = _module_names(module).get(node.id)
        if isinstance(target, tuple):
            return static_value(*target)
        if target is not None:
            return _static_eval(module, target)
    raise ValueError(f"{module}: {ast.unparse(node)!r} is not a constant that can be read without importing it")


def defaults_of(function: Callable) -> dict:
    """The keyword defaults of a library function: the one place a command's defaults are defined."""
    import inspect

    return {name: p.default for name, p in inspect.signature(function).parameters.items()
            if p.default is not inspect.Parameter.empty}


def publish_figure_and_numbers(args, compute: Callable[[], dict], write: Callable, summary: Callable,
                               numbers_kind) -> int:
    """The body of a command that computes a result and publishes its figure (``args.out``) and numbers (beside
    it, ``.json``, of ``numbers_kind``): both targets are checked before the work, the result records its command
    line, ``summary(result)`` lines print."""
    from pathlib import Path

    from plm_highway.io import FIGURE, check_target
    from plm_highway.rollout.policies import single_threaded_inference

    check_target(args.out, FIGURE, overwrite=args.overwrite)
    check_target(Path(args.out).with_suffix(".json"), numbers_kind, overwrite=args.overwrite)
    with single_threaded_inference():
        result = compute()
    result["command"] = args.command_line
    figure_path, json_path = write(result, args.out, overwrite=args.overwrite)
    for line in summary(result):
        print(line)
    print(f"figure: {figure_path}\nnumbers: {json_path}")
    return 0
