"""JSON read and written exactly as the Rust side's `serde_json` does.

A scene bundle's manifest is JSON that the Rust packer writes with
`serde_json` (shared/scene/src/bundle.rs); for the Python packer to produce
the same bytes, and so the same bundle hash, this module reproduces three
things Python's `json` does differently:

* numbers are *read* with serde_json's default (not `float_roundtrip`)
  algorithm: the decimal digits gathered into a u64, then one multiply or
  divide by a power of ten. That is not always correctly rounded (e.g.
  `2.5e-308` reads as 2.5000000000000003e-308), and the manifest keeps
  whatever it read. Integers stay integers while they fit a u64 (or an
  i64 when negative); others become floats; `-0` is the float -0.0;
* floats are *written* as the `zmij` crate prints them (serde_json 1.0.154
  uses it): the shortest round-trip digits (Python's `repr` has the same),
  laid out fixed for decimal exponents -5..=15 (`1000000000000000.0`,
  `0.00001`) and scientific beyond, with a signed exponent and no padding
  (`1e+16`, `1e-6`, `1.5e+300`);
* strings are escaped minimally (`"`, `\\`, `\\b \\f \\n \\r \\t`, other
  controls as `\\u00xx`), everything else raw UTF-8; objects (serde_json's
  `Value` maps are BTreeMaps) are written with their keys sorted, with no
  spaces anywhere.
"""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["JsonError", "dumps", "format_float", "loads", "parse_number"]

# serde_json refuses the 128th level of nesting (its recursion limit).
MAX_DEPTH = 127

_U64_MAX = (1 << 64) - 1
_I32_MAX = (1 << 31) - 1
_I32_MIN = -(1 << 31)
# serde_json's POW10 table: Rust's `1eN` literals, correctly rounded as
# Python's float("1eN") is.
_POW10 = [float(f"1e{i}") for i in range(309)]


class JsonError(ValueError):
    """JSON that serde_json would refuse (syntax, NaN, out-of-range
    numbers, lone surrogates, too deep)."""


def _overflows(a: int, b: int, c: int) -> bool:
    """serde_json's `overflow!(a * 10 + b, c)`."""
    return a >= c // 10 and (a > c // 10 or b > c % 10)


def _from_parts(positive: bool, significand: int, exponent: int) -> float:
    """serde_json's `f64_from_parts` without `float_roundtrip`."""
    f = float(significand)  # u64 as f64: round to nearest, ties to even
    while True:
        index = abs(exponent)
        if index < len(_POW10):
            if exponent >= 0:
                f *= _POW10[index]
                if math.isinf(f):
                    raise JsonError("number out of range")
            else:
                f /= _POW10[index]
            break
        if f == 0.0:
            break
        if exponent >= 0:
            raise JsonError("number out of range")
        f /= 1e308
        exponent += 308
    return f if positive else -f


def parse_number(text: str) -> int | float:
    """A JSON number literal as serde_json reads it into a `Value`: an int
    (u64, or i64 when negative) or a float, following its digit loop,
    its overflow paths and its (not always correctly rounded) float
    conversion step by step."""
    s, n = text, len(text)
    i = 0
    positive = True
    if s[0] == "-":
        positive = False
        i = 1

    def digit(at: int) -> int | None:
        return ord(s[at]) - 48 if at < n and "0" <= s[at] <= "9" else None

    def exponent_part(significand: int, starting: int, at: int) -> float:
        at += 1  # the 'e'
        positive_exp = True
        if at < n and s[at] in "+-":
            positive_exp = s[at] == "+"
            at += 1
        d = digit(at)
        if d is None:
            raise JsonError(f"invalid number {text!r}")
        exp = d
        at += 1
        while (d := digit(at)) is not None:
            at += 1
            if _overflows(exp, d, _I32_MAX):
                # The rest of the digits are skipped: zero, or out of range.
                if significand != 0 and positive_exp:
                    raise JsonError("number out of range")
                return 0.0 if positive else -0.0
            exp = exp * 10 + d
        final = starting + exp if positive_exp else starting - exp
        final = max(_I32_MIN, min(_I32_MAX, final))  # saturating
        return _from_parts(positive, significand, final)

    def after_digits(significand: int, exponent: int, at: int) -> float:
        if at < n and s[at] in "eE":
            return exponent_part(significand, exponent, at)
        return _from_parts(positive, significand, exponent)

    def decimal(significand: int, before: int, at: int) -> float:
        at += 1  # the '.'
        after = 0
        while (d := digit(at)) is not None:
            if _overflows(significand, d, _U64_MAX):
                # Further digits are ignored (truncated, not rounded).
                while digit(at) is not None:
                    at += 1
                return after_digits(significand, before + after, at)
            at += 1
            significand = significand * 10 + d
            after -= 1
        return after_digits(significand, before + after, at)

    def long_integer(significand: int, at: int) -> float:
        # Past u64: the remaining integer digits only scale it.
        exponent = 0
        while digit(at) is not None:
            at += 1
            exponent += 1
        if at < n and s[at] == ".":
            return decimal(significand, exponent, at)
        return after_digits(significand, exponent, at)

    d = digit(i)
    if d is None:
        raise JsonError(f"invalid number {text!r}")
    significand = d
    i += 1
    if d != 0:
        while (d := digit(i)) is not None:
            if _overflows(significand, d, _U64_MAX):
                return long_integer(significand, i)
            i += 1
            significand = significand * 10 + d
    if i < n and s[i] == ".":
        return decimal(significand, 0, i)
    if i < n and s[i] in "eE":
        return exponent_part(significand, 0, i)
    if positive:
        return significand
    # `(significand as i64).wrapping_neg()`: negative fits an i64, else a float.
    as_i64 = significand - (1 << 64) if significand >= 1 << 63 else significand
    neg = -as_i64
    if neg == 1 << 63:
        neg = -(1 << 63)  # wrapping
    if neg >= 0:
        return -float(significand)
    return neg


def _no_constant(name: str) -> Any:
    raise JsonError(f"{name} is not JSON")


def _check(value: Any, depth: int = 0) -> None:
    """Refuses what serde_json would: nesting past its limit, and strings
    with lone surrogates (which are not UTF-8)."""
    if isinstance(value, str):
        _check_str(value)
    elif isinstance(value, list):
        if depth + 1 > MAX_DEPTH:
            raise JsonError("recursion limit exceeded")
        for v in value:
            _check(v, depth + 1)
    elif isinstance(value, dict):
        if depth + 1 > MAX_DEPTH:
            raise JsonError("recursion limit exceeded")
        for k, v in value.items():
            _check_str(k)
            _check(v, depth + 1)


def _check_str(s: str) -> None:
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        raise JsonError("lone surrogate in a string escape") from None


def loads(text: str) -> Any:
    """Parses `text` as serde_json parses it into a `serde_json::Value`
    (see the module's doc); raises `JsonError` where serde_json fails."""
    try:
        value = json.loads(
            text,
            parse_int=parse_number,
            parse_float=parse_number,
            parse_constant=_no_constant,
        )
    except RecursionError:
        raise JsonError("recursion limit exceeded") from None
    except json.JSONDecodeError as e:
        raise JsonError(str(e)) from None
    _check(value)
    return value


_ESCAPES = {
    '"': '\\"',
    "\\": "\\\\",
    "\b": "\\b",
    "\f": "\\f",
    "\n": "\\n",
    "\r": "\\r",
    "\t": "\\t",
}


def _escape(s: str) -> str:
    out = ['"']
    for c in s:
        e = _ESCAPES.get(c)
        if e is not None:
            out.append(e)
        elif c < " ":
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def format_float(x: float) -> str:
    """`x` as serde_json (through `zmij`) writes a finite f64."""
    if not math.isfinite(x):
        raise JsonError(f"{x} is not JSON")
    sign = "-" if math.copysign(1.0, x) < 0 else ""
    if x == 0.0:
        return sign + "0.0"
    # repr gives the shortest digits that round-trip, as zmij does; only
    # their layout differs.
    mantissa, _, exp = repr(abs(x)).partition("e")
    whole, _, frac = mantissa.partition(".")
    digits = whole + frac
    point = len(whole) + (int(exp) if exp else 0)
    stripped = digits.lstrip("0")
    point -= len(digits) - len(stripped)
    digits = stripped.rstrip("0") or "0"
    e = point - 1  # the power of ten of the first digit
    if -5 <= e <= 15:
        if len(digits) - 1 <= e:
            return sign + digits + "0" * (e - len(digits) + 1) + ".0"
        if e >= 0:
            return sign + digits[: e + 1] + "." + digits[e + 1 :]
        return sign + "0." + "0" * (-e - 1) + digits
    body = digits[0] + ("." + digits[1:] if len(digits) > 1 else "")
    return f"{sign}{body}e{'+' if e >= 0 else '-'}{abs(e)}"


def dumps(value: Any) -> str:
    """`value` (as `loads` returns, or built of the same types) written as
    `serde_json::to_string` writes a `serde_json::Value`."""
    if value is None:
        return "null"
    if value is True:
        return "true"
    if value is False:
        return "false"
    if isinstance(value, int):
        if not -(1 << 63) <= value <= _U64_MAX:
            raise JsonError(f"{value}: beyond what serde_json holds as an integer")
        return str(value)
    if isinstance(value, float):
        return format_float(value)
    if isinstance(value, str):
        return _escape(value)
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(dumps(v) for v in value) + "]"
    if isinstance(value, dict):
        keys = sorted(value)
        return "{" + ",".join(_escape(k) + ":" + dumps(value[k]) for k in keys) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as JSON")
