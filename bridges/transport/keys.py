"""Key names and key expressions: validation, prefixing, and the wildcard matcher the UDP backend needs.

Keys follow Zenoh's rules so that a key valid on one backend is valid on all: chunks separated by
``/``, no empty chunk, none of ``# ? $`` (Zenoh reserves them), no whitespace or control characters.
In an expression a whole chunk may be ``*`` (exactly one chunk) or ``**`` (any number, zero included);
a ``*`` inside a chunk (``cam*``) is refused, as Zenoh refuses it.
"""
from __future__ import annotations

from functools import lru_cache

from bridges.transport.errors import KeyExprError

__all__ = ["validate_key", "validate_expr", "canonize", "join", "relative", "matches"]

_RESERVED = set("#?$*")


def _check_chunks(text: str, what: str, wildcards: bool) -> list[str]:
    if not isinstance(text, str):
        raise KeyExprError(f"{what} must be a str, not {type(text).__name__}")
    if not text:
        raise KeyExprError(f"{what} is empty")
    chunks = text.split("/")
    for i, chunk in enumerate(chunks):
        if not chunk:
            where = "leading" if i == 0 else "trailing" if i == len(chunks) - 1 else "empty"
            raise KeyExprError(f"{what} {text!r} has an {where} '/' (chunk {i} is empty)")
        if wildcards and chunk in ("*", "**"):
            continue
        for ch in chunk:
            if ch in _RESERVED:
                hint = " (wildcards are whole chunks: '*' or '**')" if ch == "*" and wildcards else ""
                raise KeyExprError(f"{what} {text!r}: chunk {chunk!r} holds the reserved character {ch!r}{hint}")
            if ch.isspace() or not ch.isprintable():
                raise KeyExprError(f"{what} {text!r}: chunk {chunk!r} holds whitespace or a control character")
    return chunks


def validate_key(key: str, what: str = "key") -> str:
    """A concrete key (no wildcards), returned unchanged; raise KeyExprError otherwise."""
    _check_chunks(key, what, wildcards=False)
    return key


def canonize(chunks: list[str]) -> list[str]:
    """Zenoh's canonical form: ``**/**`` -> ``**`` and ``**/*`` -> ``*/**``."""
    out: list[str] = []
    for chunk in chunks:
        if chunk == "**" and out and out[-1] == "**":
            continue
        if chunk == "*" and out and out[-1] == "**":
            out.insert(len(out) - 1, "*")  # move the single-chunk wildcard before the '**' run
            continue
        out.append(chunk)
    return out


def validate_expr(expr: str, what: str = "key expression") -> str:
    """A key expression in canonical form; raise KeyExprError if it is not valid."""
    return "/".join(canonize(_check_chunks(expr, what, wildcards=True)))


def join(prefix: str, key: str) -> str:
    return f"{prefix}/{key}"


def relative(prefix: str, full_key: str) -> str | None:
    """`full_key` without `prefix/`, or None when it lies outside the prefix."""
    head = prefix + "/"
    return full_key[len(head):] if full_key.startswith(head) and len(full_key) > len(head) else None


@lru_cache(maxsize=4096)
def _match(expr: tuple[str, ...], key: tuple[str, ...]) -> bool:
    if not expr:
        return not key
    head, rest = expr[0], expr[1:]
    if head == "**":
        return any(_match(rest, key[i:]) for i in range(len(key) + 1))
    if not key:
        return False
    return (head == "*" or head == key[0]) and _match(rest, key[1:])


def matches(expr: str, key: str) -> bool:
    """Whether the concrete `key` is in the set `expr` denotes (``*`` one chunk, ``**`` any number)."""
    return _match(tuple(expr.split("/")), tuple(key.split("/")))
