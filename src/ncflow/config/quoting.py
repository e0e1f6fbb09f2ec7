"""Values and setting names quoted in one-line error messages, cut to a bounded length."""

from __future__ import annotations

#: characters of a user's value quoted in an error message
QUOTE_LIMIT = 80


def quote(value, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` cut to ``limit`` characters (``…`` marks a cut), for one-line error messages."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 -- a broken or too deep __repr__ must not hide the real error
        text = f"<{type(value).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def cut(text: str, limit: int = 2 * QUOTE_LIMIT) -> str:
    """``text`` on one line, cut to ``limit`` characters."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def one_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name when it has none), cut."""
    text = str(exc).strip()
    return cut(text.splitlines()[0] if text else type(exc).__name__)


def names(keys, most: int = 10) -> str:
    """Setting names for a message: at most ``most``, each cut to 40 characters."""
    shown = [k if k.isidentifier() and len(k) <= 40 else quote(k, 40) for k in sorted(keys)[:most]]
    return ", ".join(shown) + (", …" if len(keys) > most else "")
