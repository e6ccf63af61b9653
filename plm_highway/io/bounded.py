"""Reading JSON, YAML and CSV text with every size bounded before the work it would cost.

One loader for every structured input the kit reads (tracks, grids, checkpoint descriptions,
dataset manifests, output markers, sweep cells, latency traces). Each limit is explicit
(:class:`JsonLimits`), checked in time linear in the input, and refused with
:class:`~plm_highway.errors.BadInput` naming the file, the field (a path such as
``segments[3].length_m``, or a line and column) and the limit:

- bytes: the file's size, before it is read;
- depth: brackets (JSON) or collections (YAML) nested deeper than ``max_depth``, found by one scan
  before the parser recurses (Python's parsers recurse per level, so 200,000 levels would crash them);
- nodes: values in the document, counted after YAML aliases are expanded (a small YAML file
  whose aliases nest can stand for billions of values); the characters of the expanded scalars too;
- integers longer than ``max_int_digits`` digits (Python refuses to convert 4,300 digits and more
  without saying where they were);
- a key given twice in one object (JSON and YAML parsers silently keep the last one).

Numbers in text (command-line options, seed lists, CSV cells, latency specs) are read by one strict
parser, :func:`parse_int_text` and :func:`parse_float_text`: the ASCII digits 0-9 only (Python's
``int``/``float`` also read Arabic-Indic, Devanagari and full-width digits, which a reader of the file
would not take for the same number: :func:`refuse_non_ascii_digits`), no ``_`` separators (``int("1_0")``
is 10), an integer where an integer is meant. In JSON and YAML documents a number must be a number:
``seeds: ['1']`` is text, and refused where integers are meant.
"""

from __future__ import annotations

import json
import math
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from plm_highway.errors import BadInput


@dataclass(frozen=True)
class JsonLimits:
    """Bounds of one kind of structured input (the same for JSON and YAML)."""

    max_bytes: int = 16 << 20
    max_depth: int = 64
    max_nodes: int = 1_000_000
    max_int_digits: int = 100
    max_expanded_chars: int | None = None  # YAML: characters of all scalars after alias expansion (default 8x bytes)


# -- reading a file ---------------------------------------------------------------------------------


def read_bounded(path: str | Path, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``max_bytes``, refused by name otherwise (read with a cap,
    so a file that grows after the size check cannot slip past it)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise FileNotFoundError(2, f"no such {what}", str(path)) from None
    if stat.S_ISDIR(info.st_mode):
        raise BadInput(f"{path}: is a directory, not a {what}")
    if not stat.S_ISREG(info.st_mode):
        raise BadInput(f"{path}: is not a regular file (a {what} is expected)")
    if info.st_size > max_bytes:
        raise BadInput(f"{path}: {info.st_size:,} bytes; a {what} is at most {max_bytes:,} bytes (limit)")
    with open(path, "rb") as handle:
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise BadInput(f"{path}: more than {max_bytes:,} bytes; a {what} is at most {max_bytes:,} bytes (limit)")
    return data


def decode_utf8(data: bytes, source: str, *, bom: str = "accept") -> str:
    """UTF-8 text; ``bom``: "accept" (dropped) or "refuse" (named)."""
    if data.startswith(b"\xef\xbb\xbf"):
        if bom == "refuse":
            raise BadInput(f"{source}: starts with a UTF-8 byte-order mark; save it as UTF-8 without BOM")
        data = data[3:]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise BadInput(f"{source}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}, line {line}); "
                       "a UTF-8 text file is expected") from None


# -- JSON -------------------------------------------------------------------------------------------


class _DuplicateKeys(dict):
    """An object in which a key appeared twice (found by the parser, reported with its path afterwards)."""

    duplicate: str = ""


@dataclass(frozen=True)
class _LongInteger:
    digits: str


_SPECIAL = re.compile(r'["\\\[\]{}]')


def json_depth(text: str) -> tuple[int, int]:
    """(deepest bracket nesting outside strings, offset where it is first reached), in one linear scan."""
    depth = deepest = 0
    where = 0
    in_string = False
    skip_to = -1  # the character after a backslash inside a string is taken literally
    for match in _SPECIAL.finditer(text):
        position = match.start()
        if position <= skip_to:
            continue
        char = match.group()
        if in_string:
            if char == "\\":
                skip_to = position + 1
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > deepest:
                deepest, where = depth, position
        elif char in "]}":
            depth -= 1
    return deepest, where


def _line_column(text: str, offset: int) -> str:
    line = text.count("\n", 0, offset) + 1
    column = offset - (text.rfind("\n", 0, offset) + 1) + 1
    return f"line {line} column {column}"


def parse_json(data: bytes | str, source: str, limits: JsonLimits = JsonLimits(), *, bom: str = "accept"):
    """A JSON document within ``limits`` (see the module docstring); NaN and Infinity are read as floats
    (range checks downstream refuse them by field)."""
    size = len(data.encode("utf-8")) if isinstance(data, str) else len(data)
    if size > limits.max_bytes:
        raise BadInput(f"{source}: {size:,} bytes; at most {limits.max_bytes:,} bytes are read (limit)")
    text = data if isinstance(data, str) else decode_utf8(data, source, bom=bom)
    depth, where = json_depth(text)
    if depth > limits.max_depth:
        raise BadInput(f"{source}: brackets nested {depth} deep (from {_line_column(text, where)}); at most "
                       f"{limits.max_depth} (nesting limit)")

    def pairs(items):
        result = dict(items)
        if len(result) != len(items):
            seen = set()
            duplicated = next(key for key, _ in items if key in seen or seen.add(key))
            result = _DuplicateKeys(result)
            result.duplicate = duplicated
        return result

    def integer(digits: str):
        return _LongInteger(digits) if len(digits.lstrip("-")) > limits.max_int_digits else int(digits)

    try:
        document = json.loads(text, object_pairs_hook=pairs, parse_int=integer)
    except json.JSONDecodeError as exc:
        raise BadInput(f"{source}: not valid JSON ({exc})") from None
    _check_tree(document, source, limits)
    return document


def load_json(path: str | Path, limits: JsonLimits = JsonLimits(), *, what: str = "JSON file", bom: str = "accept"):
    """:func:`parse_json` of a file, its size checked before it is read."""
    return parse_json(read_bounded(path, limits.max_bytes, what), str(path), limits, bom=bom)


def field_path(parts) -> str:
    text = ""
    for part in parts:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text or "(top level)"


def _check_tree(document, source: str, limits: JsonLimits, expanded_chars: int | None = None) -> None:
    """Count the nodes (with multiplicity: a shared YAML alias counts each time) and find the markers the
    parser left; iterative, and never more than ``max_nodes`` steps. Paths are kept as links to the
    parent's (a tuple per node would cost time quadratic in the depth of a self-referencing alias)."""
    max_chars = expanded_chars
    nodes = chars = 0
    stack: list[tuple[object, tuple | None]] = [(document, None)]

    def where(link) -> str:
        parts = []
        while link is not None:
            key, link = link
            parts.append(key)
        return field_path(reversed(parts))

    while stack:
        node, link = stack.pop()
        nodes += 1
        if nodes > limits.max_nodes:
            raise BadInput(f"{source}: more than {limits.max_nodes:,} values (near field {where(link)!r})"
                           + ("; aliases are counted after expansion" if max_chars is not None else "")
                           + " (node limit)")
        if isinstance(node, _LongInteger):
            shown = node.digits[:12] + "..." if len(node.digits) > 12 else node.digits
            raise BadInput(f"{source}: field {where(link)!r}: an integer of {len(node.digits.lstrip('-')):,} "
                           f"digits ({shown}); at most {limits.max_int_digits} digits (limit)")
        if isinstance(node, _DuplicateKeys):
            raise BadInput(f"{source}: field {where(link)!r}: key {node.duplicate!r} appears more than once; "
                           "each key may appear once")
        if isinstance(node, dict):
            for key, value in node.items():
                if max_chars is not None:
                    chars += len(str(key)) if isinstance(key, str) else 0
                stack.append((value, (key, link)))
        elif isinstance(node, (list, tuple)):
            stack.extend((value, (index, link)) for index, value in enumerate(node))
        elif max_chars is not None and isinstance(node, (str, bytes)):
            chars += len(node)
        if max_chars is not None and chars > max_chars:
            raise BadInput(f"{source}: more than {max_chars:,} characters of values once aliases are expanded "
                           f"(near field {where(link)!r}; expansion limit)")


# -- YAML -------------------------------------------------------------------------------------------


def parse_yaml(text: str, source: str, limits: JsonLimits = JsonLimits()):
    """A YAML document (safe types only) within ``limits``: depth, long integers and the event count are
    checked on the event stream before anything is built; duplicate keys are refused; nodes and
    characters are counted after aliases are expanded."""
    import yaml  # lazy here and below: io is on every command line's path; YAML only for grid files

    size = len(text.encode("utf-8"))
    if size > limits.max_bytes:
        raise BadInput(f"{source}: {size:,} bytes; at most {limits.max_bytes:,} bytes are read (limit)")
    _scan_yaml_events(text, source, limits)
    try:
        document = yaml.load(text, Loader=_strict_loader())  # a SafeLoader subclass: safe types only
    except yaml.YAMLError as exc:
        raise BadInput(f"{source}: not valid YAML ({_one_line(exc)})") from None
    except (ValueError, OverflowError) as exc:  # a value the safe constructors cannot convert
        raise BadInput(f"{source}: a value cannot be read ({exc})") from None
    max_chars = limits.max_expanded_chars if limits.max_expanded_chars is not None else 8 * limits.max_bytes
    _check_tree(document, source, limits, expanded_chars=max_chars)
    return document


def load_yaml(path: str | Path, limits: JsonLimits = JsonLimits(), *, what: str = "YAML file"):
    return parse_yaml(decode_utf8(read_bounded(path, limits.max_bytes, what), str(path)), str(path), limits)


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


_PLAIN_INTEGER = re.compile(r"[-+]?[0-9_]+")


def _scan_yaml_events(text: str, source: str, limits: JsonLimits) -> None:
    """Depth, event count and over-long integers, on the parser's event stream (no tree is built)."""
    # lazy: io is on every command's path and only grid files need YAML
    import yaml
    from yaml import events as ev

    stack: list[list] = []  # frames: ["map", key, expecting_key] or ["seq", index]

    def path() -> str:
        parts = []
        for frame in stack:
            if frame[0] == "seq":
                parts.append(frame[1])
            elif not frame[2]:
                parts.append(frame[1])
        return field_path(parts)

    def done() -> None:
        if stack:
            frame = stack[-1]
            if frame[0] == "seq":
                frame[1] += 1
            else:
                frame[2] = not frame[2]

    count = 0
    try:
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            count += 1
            if count > 2 * limits.max_nodes + 8:
                raise BadInput(f"{source}: more than {limits.max_nodes:,} values (node limit)")
            where = f"line {event.start_mark.line + 1} column {event.start_mark.column + 1}"
            if isinstance(event, (ev.MappingStartEvent, ev.SequenceStartEvent)):
                if len(stack) >= limits.max_depth:
                    raise BadInput(f"{source}: field {path()!r} ({where}): collections nested more than "
                                   f"{limits.max_depth} deep (nesting limit)")
                if stack and stack[-1][0] == "map" and stack[-1][2]:
                    stack[-1][1] = "?"
                stack.append(["map", None, True] if isinstance(event, ev.MappingStartEvent) else ["seq", 0])
            elif isinstance(event, (ev.MappingEndEvent, ev.SequenceEndEvent)):
                stack.pop()
                done()
            elif isinstance(event, (ev.ScalarEvent, ev.AliasEvent)):
                if isinstance(event, ev.ScalarEvent):
                    value = event.value
                    if event.style is None and len(value) > limits.max_int_digits and _PLAIN_INTEGER.fullmatch(value):
                        raise BadInput(f"{source}: field {path()!r} ({where}): an integer of {len(value):,} digits; "
                                       f"at most {limits.max_int_digits} digits (limit)")
                    if stack and stack[-1][0] == "map" and stack[-1][2]:
                        stack[-1][1] = value
                elif stack and stack[-1][0] == "map" and stack[-1][2]:
                    stack[-1][1] = f"*{event.anchor}"
                done()
    except yaml.YAMLError as exc:
        raise BadInput(f"{source}: not valid YAML ({_one_line(exc)})") from None


_LOADER = None


def _strict_loader():
    """A SafeLoader that refuses a mapping key given twice."""
    global _LOADER
    if _LOADER is None:
        # lazy: io is on every command's path and only grid files need YAML
        import yaml

        class StrictSafeLoader(yaml.SafeLoader):
            def construct_mapping(self, node, deep=False):
                if isinstance(node, yaml.MappingNode):
                    seen = set()
                    for key_node, _ in node.value:
                        if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                            continue
                        key = (key_node.tag, key_node.value)
                        if key in seen:
                            raise yaml.constructor.ConstructorError(
                                "while constructing a mapping", node.start_mark,
                                f"key {key_node.value!r} appears more than once; each key may appear once",
                                key_node.start_mark)
                        seen.add(key)
                return super().construct_mapping(node, deep=deep)

        _LOADER = StrictSafeLoader
    return _LOADER


# -- CSV and numbers in text ---------------------------------------------------------------------------


def check_csv_columns(text: str, source: str, max_columns: int) -> None:
    """Refuse a row with more than ``max_columns`` cells before a CSV reader builds it (one linear pass;
    commas inside quotes count too, which only makes the bound stricter)."""
    start = 0
    row = 1
    length = len(text)
    while start < length:
        end = text.find("\n", start)
        end = length if end < 0 else end
        if text.count(",", start, end) >= max_columns:
            raise BadInput(f"{source}: row {row}: more than {max_columns} columns (limit)")
        start, row = end + 1, row + 1


def refuse_non_ascii_digits(text: str, where: str) -> str:
    """``text`` unchanged, or BadInput when it holds a digit other than 0-9 (e.g. Arabic-Indic)."""
    for char in text:
        if not char.isascii() and char.isdecimal():
            raise BadInput(f"{where}: {text!r} holds the non-ASCII digit {char!r}; write numbers with the digits 0-9")
    return text


_TEXT_INTEGER = re.compile(r"[+-]?[0-9]+")
_TEXT_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NON_FINITE = frozenset({"nan", "+nan", "-nan", "inf", "+inf", "-inf", "infinity", "+infinity", "-infinity"})
MAX_TEXT_NUMBER_CHARS = 100


def _number_text(text, where: str, what: str) -> str:
    if not isinstance(text, str):
        raise BadInput(f"{where}: expected {what} written as text, got {text!r}")
    refuse_non_ascii_digits(text, where)
    stripped = text.strip()
    if len(stripped) > MAX_TEXT_NUMBER_CHARS:
        raise BadInput(f"{where}: {stripped[:20]!r}... is {len(stripped):,} characters; {what} has at most "
                       f"{MAX_TEXT_NUMBER_CHARS} (limit)")
    if "_" in stripped:
        raise BadInput(f"{where}: {text!r} holds '_'; write {what} without separators (digits 0-9 only)")
    return stripped


def parse_int_text(text: str, where: str) -> int:
    """An integer written in text: optional sign and the digits 0-9, nothing else (no '_', no '1.0', no
    Arabic-Indic digits); BadInput naming ``where`` and the text otherwise."""
    stripped = _number_text(text, where, "an integer")
    if not _TEXT_INTEGER.fullmatch(stripped):
        raise BadInput(f"{where}: {text!r} is not an integer (optional sign and the digits 0-9)")
    return int(stripped)


def parse_float_text(text: str, where: str, *, non_finite: bool = False) -> float:
    """A decimal number written in text (``-1.5``, ``2e-3``, ``.5``), digits 0-9 only, no '_';
    ``non_finite``: also ``nan``/``inf`` (a recording's missing sample). BadInput naming ``where`` otherwise."""
    stripped = _number_text(text, where, "a number")
    if non_finite and stripped.lower() in _NON_FINITE:
        return float(stripped)
    if not _TEXT_DECIMAL.fullmatch(stripped):
        raise BadInput(f"{where}: {text!r} is not a number (a plain decimal: digits 0-9, optional sign, point "
                       "and exponent)")
    value = float(stripped)
    if not non_finite and not math.isfinite(value):
        raise BadInput(f"{where}: {text!r} is not finite")
    return value


def require_int(value, where: str) -> int:
    """An integer from a parsed JSON/YAML document: an int (not a bool, not text, not 1.0)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadInput(f"{where}: expected an integer, got {value!r} ({type(value).__name__})")
    return value
