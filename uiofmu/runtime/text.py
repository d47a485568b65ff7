"""Free text from other people's files, made safe for where it goes (standard library only).

Names and descriptions come from problem files and design cards. They reach generated code
and XML only through this module: :func:`check_text` refuses control characters and
unbounded lengths, :func:`identifier` whitelists the characters of a C or Python identifier,
:func:`c_string` and :func:`py_string` produce escaped literals, and
:func:`fill_template` fills a template in one pass with checked fields.
"""

from __future__ import annotations

import re
import string
import unicodedata

#: Longest model name accepted from a problem file or a card (characters).
MAX_NAME = 128
#: Longest identifier derived from a name (characters; FMI model identifiers become file names).
MAX_IDENTIFIER = 64
#: Unicode categories never accepted in a name: controls, format characters, surrogates,
#: private use and unassigned code points.
_REFUSED = {"Cc", "Cf", "Cs", "Co", "Cn"}
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def check_text(value, key: str, error=ValueError, max_len: int = MAX_NAME, allow_empty: bool = False) -> str:
    """Free text from a file: a string of at most ``max_len`` printable characters.

    Parameters
    ----------
    value : object
        What the file holds under ``key``.
    key : str
        The key, for the message.
    error : type
        Exception raised.
    max_len : int
        Longest accepted string.
    allow_empty : bool
        Accept an empty (or blank) string.

    Returns
    -------
    str
        ``value`` itself.

    Raises
    ------
    error
        For a non-string, an empty (unless allowed) or over-long string, or a control
        character (named by its code point and position).
    """
    if not isinstance(value, str):
        raise error(f"{key}: expected a string, found {type(value).__name__} {_short(value)}")
    if not allow_empty and not value.strip():
        raise error(f"{key}: expected a non-empty string, found {value!r}")
    if len(value) > max_len:
        raise error(f"{key}: at most {max_len} characters, found {len(value)}")
    if value.isascii() and value.isprintable():     # of ASCII, only the controls (Cc) are refused: none here
        return value
    for i, ch in enumerate(value):
        if unicodedata.category(ch) in _REFUSED:
            raise error(f"{key}: character U+{ord(ch):04X} at position {i} is not allowed "
                        "(control, format, surrogate or unassigned characters are refused)")
    return value


def check_name(value, key: str, error=ValueError) -> str:
    """A model name: a non-empty string of at most :data:`MAX_NAME` printable characters
    (see :func:`check_text`).

    Parameters
    ----------
    value : object
        What the file holds under ``key``.
    key : str
        The key, for the message.
    error : type
        Exception raised.

    Returns
    -------
    str
    """
    return check_text(value, key, error)


def _short(value, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def identifier(text: str, suffix: str = "", max_len: int = MAX_IDENTIFIER) -> str:
    """A C and Python identifier derived from ``text`` (ASCII letters, digits, underscores).

    Parameters
    ----------
    text : str
        Any name.
    suffix : str
        Appended with an underscore (``"observer"`` gives ``NAME_observer``); itself an identifier.
    max_len : int
        Longest result.

    Returns
    -------
    str
        Starts with a letter; every other character outside ``[A-Za-z0-9_]`` became ``_``.

    Examples
    --------
    >>> identifier("two-room building", "observer")
    'two_room_building_observer'
    >>> identifier("../../x", "plant")
    'x_plant'
    """
    core = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", text)).strip("_")
    if not core[:1].isalpha():
        core = f"m_{core}".rstrip("_")
    tail = f"_{suffix}" if suffix else ""
    out = core[:max_len - len(tail)].rstrip("_") + tail
    if not _IDENT.match(out):
        raise ValueError(f"cannot derive an identifier from {text!r}")
    return out


def c_string(text: str) -> str:
    r"""A C string literal of ``text`` (UTF-8): every byte outside printable ASCII, and ``"``,
    ``\`` and ``?`` (trigraphs), as a three-digit octal escape.

    Examples
    --------
    >>> print(c_string('say "hi" */ ?'))
    "say \042hi\042 */ \077"
    """
    out = []
    for byte in text.encode("utf-8", "surrogatepass"):
        ch = chr(byte)
        out.append(ch if 0x20 <= byte < 0x7F and ch not in '"\\?' else f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def py_string(text: str) -> str:
    """A Python string literal of ``text`` (ASCII only, so the source needs no encoding)."""
    return ascii(str(text))


def fill_template(template: str, identifiers: dict, literals: dict) -> str:
    """Fill a :class:`string.Template` in one pass.

    Parameters
    ----------
    template : str
        Text with ``${name}`` fields.
    identifiers : dict of str to str
        Fields that must be identifiers (checked, inserted as they are).
    literals : dict of str to str
        Fields inserted as already escaped literals (from :func:`py_string` or :func:`c_string`).

    Returns
    -------
    str

    Raises
    ------
    ValueError
        For a field that is not an identifier, or a field of the template left unfilled.
    """
    for key, value in identifiers.items():
        if not _IDENT.match(value):
            raise ValueError(f"template field {key}: {value!r} is not an identifier")
    return string.Template(template).substitute({**identifiers, **literals})
