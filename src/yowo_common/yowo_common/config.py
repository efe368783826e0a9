"""The configuration tree's mechanics: typed (frozen) dataclasses from YAML or dicts, with
dotted overrides (`ego.odometry.scale=1`), validated by dacite: an unknown key or a value
of the wrong type is a ConfigError naming the key. The dataclasses are the one place where
defaults live; this module knows none of them."""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from typing import Any, TypeVar

import dacite
import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    pass


# A decimal number in exponent notation without a dot (1e-10): YAML 1.1 reads it as a string.
_EXPONENT = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)[eE][+-]?\d+")


def _number(value):
    """An int where a float is expected (YAML writes 4 for 4.0), or 1e-10 (YAML 1.1 gives the
    string); anything else is checked."""
    if isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
        return float(value)
    return float(value) if isinstance(value, int) and not isinstance(value, bool) else value


_DACITE = dacite.Config(strict=True, check_types=True, cast=[tuple], type_hooks={float: _number})


def to_dict(obj) -> dict:
    """The tree as plain YAML-able values (tuples as lists)."""

    def plain(v):
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(dataclasses.asdict(obj))


# Every number's range unless its field says otherwise: finite, not negative (no default is),
# 0 or within RANGE_FACTOR of its default either way (of 1 for a default of 0).
# Values beyond are typing errors (1e26 for 2); a stage given one hangs or overflows.
RANGE_FACTOR = 1e6


def check_ranges(obj, where: str = "") -> None:
    """ConfigError naming the first number of the tree outside its range."""
    defaults = type(obj)()
    for f in dataclasses.fields(obj):
        value, default, key = getattr(obj, f.name), getattr(defaults, f.name), _key(where, f.name)
        if dataclasses.is_dataclass(value):
            check_ranges(value, key)
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and value != default:
            lo, hi = f.metadata.get(
                "range", ((abs(default) or 1.0) / RANGE_FACTOR, max(abs(default), 1.0) * RANGE_FACTOR)
            )
            if not math.isfinite(value) or value < 0 or value > hi or 0 < value < lo:
                raise ConfigError(f"{key}={value!r}: outside its range (0 or {lo:g} .. {hi:g}; default {default!r})")


def from_dict(cls: type[T], data: dict | None, where: str = "") -> T:
    """`cls` with `data` over its defaults (nested sections may be partial), every number
    within its range (check_ranges)."""
    merged = _merge(to_dict(cls()), data or {}, where)
    try:
        obj = dacite.from_dict(cls, merged, config=_DACITE)
    except dacite.UnexpectedDataError as exc:
        raise ConfigError(f"unknown key(s) {', '.join(_key(where, k) for k in sorted(exc.keys))}") from exc
    except dacite.WrongTypeError as exc:
        raise ConfigError(
            f"{_key(where, exc.field_path)}: expected {_type_name(exc.field_type)}, got {exc.value!r}"
        ) from exc
    except dacite.DaciteError as exc:
        raise ConfigError(f"{where or 'configuration'}: {exc}") from exc
    check_ranges(obj, where)
    return obj


def _key(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _type_name(t) -> str:
    return getattr(t, "__name__", None) or str(t)


def _merge(base: dict, over: dict, where: str, known: bool = True) -> dict:
    """`over` onto `base`, section by section. `known`: `base` holds every key of the
    section (a dataclass's), so any other key is unknown."""
    if not isinstance(over, dict):
        raise ConfigError(f"{where or 'configuration'}: expected a mapping of keys, got {over!r}")
    out = dict(base)
    for k, v in over.items():
        if known and k not in out:
            near = difflib.get_close_matches(str(k), list(out), n=1)
            raise ConfigError(
                f"unknown key {_key(where, k)}"
                + (
                    f" (did you mean {_key(where, near[0])}?)"
                    if near
                    else f"; {where or 'the tree'} has " + ", ".join(out)
                )
            )
        if isinstance(out.get(k), dict) and isinstance(v, dict):
            out[k] = _merge(out[k], v, _key(where, k), known)
        elif isinstance(out.get(k), dict):
            raise ConfigError(f"{_key(where, k)}: is a section of keys, got {v!r}")
        else:
            out[k] = v
    return out


def dotted(items: list[str]) -> dict:
    """['a.b=1', 'a.c=[1, 2]'] -> {'a': {'b': 1, 'c': [1, 2]}} (values parsed as YAML)."""
    tree: dict[str, Any] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise ConfigError(f"--set {item}: expected section.key=value")
        *path, leaf = key.strip().split(".")
        node = tree
        for part in path:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {item}: {part} is set to a value and used as a section")
        node[leaf] = yaml.safe_load(value)
    return tree


def load(
    cls: type[T], text_or_dict: str | dict | None = None, overrides: list[str] | None = None, where: str = ""
) -> T:
    """`cls` from YAML text (or a dict), then dotted overrides on top."""
    data = yaml.safe_load(text_or_dict) if isinstance(text_or_dict, str) else text_or_dict
    if data is not None and not isinstance(data, dict):
        raise ConfigError(f"expected a mapping of sections ({where or 'replay, ego, ...'}), got {data!r}")
    return from_dict(cls, _merge(data or {}, dotted(overrides or []), where, known=False), where)


def changed(obj) -> dict[str, Any]:
    """{dotted key: value} where `obj` differs from its class's defaults."""

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
        return out

    mine, defaults = flat(to_dict(obj)), flat(to_dict(type(obj)()))
    return {k: v for k, v in mine.items() if defaults.get(k) != v}


def describe_changes(obj, where: str = "") -> str:
    """One line for a log: the keys set away from their defaults."""
    diff = changed(obj)
    return ", ".join(f"{_key(where, k)}={v}" for k, v in diff.items()) or "defaults"


def dump(obj) -> str:
    return yaml.safe_dump(to_dict(obj), sort_keys=False)


# A key's unit from its name's suffix; a number without one states it at the end of its
# comment in brackets ("[count]", "[share]", "[px]").
UNIT_SUFFIXES = {
    "_m": "m",
    "_m2": "m²",
    "_mm": "mm",
    "_s": "s",
    "_ns": "ns",
    "_ms": "ms",
    "_px": "px",
    "_deg": "deg",
    "_rad": "rad",
    "_hz": "Hz",
    "_mps": "m/s",
    "_mps2": "m/s²",
    "_radps": "rad/s",
    "_mb": "MB",
    "_percent": "%",
}
_BRACKET_UNIT = re.compile(r"\s*\[([^\]]+)\]\s*$")
# The end of a comment's first sentence (its one-line description); what follows says why.
_SENTENCE_END = re.compile(r"(?<=[a-z0-9)\]])(?<!e\.g)(?<!i\.e)\.\s+(?=[A-Z0-9(])")


@dataclasses.dataclass(frozen=True, kw_only=True)
class FieldDoc:
    description: str  # the first sentence of the field's comment (inline, or the block just above)
    unit: str  # from the name's suffix or the comment's trailing [unit]; "" when none applies


def field_docs(cls) -> dict[str, FieldDoc]:
    """{field name: FieldDoc} of a configuration dataclass, read from its source's comments:
    the one on the field's line, else the comment lines right above it."""
    import inspect
    import io
    import tokenize

    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    lines = src.splitlines()
    comments = {
        t.start[0]: t.string.lstrip("#").strip()
        for t in tokenize.generate_tokens(io.StringIO(src).readline)
        if t.type == tokenize.COMMENT
    }
    names = {f.name for f in dataclasses.fields(cls)}
    docs = {}
    for number, line in enumerate(lines, 1):
        name, colon, _ = line.strip().partition(":")
        if not colon or name not in names or line.strip().startswith("#"):
            continue
        if number in comments:
            text = comments[number]
        else:
            block, above = [], number - 1
            while above in comments and lines[above - 1].strip().startswith("#"):
                block.insert(0, comments[above])
                above -= 1
            text = " ".join(block)
        if not text:
            continue
        unit = next((u for s, u in UNIT_SUFFIXES.items() if name.endswith(s)), "")
        first = _SENTENCE_END.split(text, maxsplit=1)[0].rstrip(".")
        bracket = _BRACKET_UNIT.search(first) or _BRACKET_UNIT.search(text)
        if bracket:
            unit = bracket.group(1)
            first = _BRACKET_UNIT.sub("", first).rstrip(".")
        text = first
        docs[name] = FieldDoc(description=text, unit=unit)
    return docs


def leaf_docs(obj, where: str = "") -> dict[str, tuple[Any, FieldDoc | None]]:
    """{dotted key: (value, its FieldDoc or None)} over every leaf of the tree."""
    out = {}
    docs = field_docs(type(obj))
    for f in dataclasses.fields(obj):
        value, key = getattr(obj, f.name), _key(where, f.name)
        if dataclasses.is_dataclass(value):
            out.update(leaf_docs(value, key))
        else:
            out[key] = (value, docs.get(f.name))
    return out


def dump_described(obj) -> str:
    """The tree as YAML (a --config file takes it) with each key's description and unit."""
    lines: list[str] = []

    def walk(node, depth: int) -> None:
        docs = field_docs(type(node))
        for f in dataclasses.fields(node):
            value, pad = getattr(node, f.name), "  " * depth
            if dataclasses.is_dataclass(value):
                lines.append(f"{pad}{f.name}:")
                walk(value, depth + 1)
                continue
            text = yaml.safe_dump(to_dict_value(value), default_flow_style=True, width=1 << 16).strip()
            text = text.removesuffix("\n...").removesuffix("...").strip()
            doc = docs.get(f.name)
            note = f"  # {doc.description}" + (f" [{doc.unit}]" if doc.unit else "") if doc else ""
            lines.append(f"{pad}{f.name}: {text}{note}")

    walk(obj, 0)
    return "\n".join(lines) + "\n"


def to_dict_value(v):
    """One value as plain YAML-able data (tuples as lists, dataclasses as dicts)."""
    if dataclasses.is_dataclass(v):
        return to_dict(v)
    if isinstance(v, (list, tuple)):
        return [to_dict_value(x) for x in v]
    if isinstance(v, dict):
        return {k: to_dict_value(x) for k, x in v.items()}
    return v
