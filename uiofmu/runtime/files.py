"""Reading other people's files with bounds, and writing outputs atomically (standard library only).

Problem files, design cards, step files and input tables are read through :func:`read_text`:
regular files only (a FIFO or a device is refused before it is opened for reading, so nothing
blocks or streams forever), at most :data:`MAX_INPUT_BYTES`, valid UTF-8. Parsed documents are
refused beyond :data:`MAX_DEPTH` levels of nesting, and JSON's ``NaN``/``Infinity`` are refused.

Every output goes through :func:`atomic_output`: it is written to a temporary file in the
target's folder and renamed over the target only when complete, so a failure leaves an
existing file as it was. Targets that exist and are not regular files (a folder, ``/dev/full``)
are refused before any work starts (:func:`check_output_file`).
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import tempfile
import tomllib
from pathlib import Path

from .errors import UserError

#: Largest input file read (bytes): problem files, cards, step files, input tables.
MAX_INPUT_BYTES = 64 * 2**20
#: Deepest nesting of tables and arrays accepted in a parsed document.
MAX_DEPTH = 64


class InputFileError(UserError):
    """An input file that cannot be read as the data it should hold."""


class OutputError(UserError):
    """An output that cannot be written where it was asked for."""


def read_bytes(path, what: str, limit: int = MAX_INPUT_BYTES, error=InputFileError) -> bytes:
    """The content of a regular file of at most ``limit`` bytes.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What it is, for messages (``"problem file"``).
    limit : int
        Largest accepted size in bytes.
    error : type
        Exception raised.

    Returns
    -------
    bytes

    Raises
    ------
    error
        For a missing or unreadable file, a non-regular file, or one above ``limit``.
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):             # before fdopen, which refuses a folder by its descriptor
        os.close(fd)
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise error(f"{path}: the {what} is {kind}; give a regular file")
    with os.fdopen(fd, "rb") as f:
        if info.st_size > limit:
            raise error(f"{path}: the {what} has {info.st_size} bytes, more than the limit of {limit}")
        try:
            data = f.read(limit + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise error(f"{path}: the {what} has more than the limit of {limit} bytes")
    return data


def read_text(path, what: str, limit: int = MAX_INPUT_BYTES, error=InputFileError) -> str:
    """A regular UTF-8 text file of at most ``limit`` bytes (see :func:`read_bytes`).

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What it is, for messages.
    limit : int
        Largest accepted size in bytes.
    error : type
        Exception raised.

    Returns
    -------
    str
    """
    data = read_bytes(path, what, limit, error)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: the {what} is not UTF-8 text (byte {exc.start})") from None
    if "\x00" in text:
        raise error(f"{path}: the {what} contains a NUL character (offset {text.index(chr(0))}); "
                    "it is not a text file")
    return text


def check_depth(document, what: str, limit: int = MAX_DEPTH, error=InputFileError) -> None:
    """Refuse a parsed document nested deeper than ``limit`` levels (iteratively: no recursion).

    Parameters
    ----------
    document : object
        Dicts, lists and scalars.
    what : str
        Where it came from, for the message.
    limit : int
        Deepest accepted nesting.
    error : type
        Exception raised.
    """
    stack = [(document, 1)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else ()
        for child in children:
            if isinstance(child, (dict, list)):
                if depth + 1 > limit:
                    raise error(f"{what}: nested more than {limit} levels deep")
                stack.append((child, depth + 1))


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number a design card may hold")


def _parsed(load, text: str, what: str, error, kind: str):
    """``load(text)``, its failures as ``error`` naming ``what``, then the depth limit."""
    try:
        data = load(text)
    except RecursionError:
        raise error(f"{what}: nested too deep (the limit is {MAX_DEPTH} levels)") from None
    except ValueError as exc:      # the decoders' errors, and integers of more than 4300 digits
        raise error(f"{what}: not valid {kind} ({str(exc)[:300]})") from None
    check_depth(data, what, error=error)
    return data


def parse_json(text: str, what: str, error=InputFileError):
    """Parse JSON data: no ``NaN``/``Infinity``, at most :data:`MAX_DEPTH` levels.

    Parameters
    ----------
    text : str
        The document.
    what : str
        Where it came from, for messages.
    error : type
        Exception raised.

    Returns
    -------
    object
    """
    return _parsed(lambda s: json.loads(s, parse_constant=_no_constant), text, what, error, "JSON")


def parse_toml(text: str, what: str, error=InputFileError) -> dict:
    """Parse TOML data, at most :data:`MAX_DEPTH` levels.

    Parameters
    ----------
    text : str
        The document.
    what : str
        Where it came from, for messages.
    error : type
        Exception raised.

    Returns
    -------
    dict
    """
    return _parsed(tomllib.loads, text, what, error, "TOML")


def check_output_file(path, what: str, suffix: str | None = None) -> Path:
    """Refuse, before any work, an output path that cannot become a regular file.

    Parameters
    ----------
    path : str or Path
        The target.
    what : str
        What will be written, for messages (``"design card"``).
    suffix : str, optional
        Required file name suffix (``".fmu"``).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        For an existing folder or non-regular file, a wrong suffix, or a parent that is a file.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder; give the {what} a file name")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path} exists and is not a regular file; refusing to replace it with the {what}")
    if suffix and path.suffix != suffix:
        raise OutputError(f"{path}: the {what} file name must end in {suffix}")
    _check_parents(path)
    return path


def _check_parents(path: Path) -> None:
    """Refuse a path whose nearest existing parent is not a folder, or is the filesystem's root
    while folders below it are missing (``-o /nonexistent/dir/x.json`` is a typo far more often
    than a wish for a new top-level folder): missing folders are created only inside an existing
    folder the path names (the current folder for a relative path)."""
    missing = None
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{path}: {parent} is not a folder")
            if missing is not None and parent.anchor and parent == Path(parent.anchor):
                raise OutputError(f"{path}: {missing} does not exist; outputs create missing folders only inside "
                                  f"an existing folder other than {parent} (create {missing} first, or check the path)")
            break
        missing = parent


def check_output_dir(path, what: str = "output folder") -> Path:
    """Refuse, before any work, an output folder that exists as something else.

    Parameters
    ----------
    path : str or Path
        The folder.
    what : str
        What it is for, for messages.

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path} exists and is not a folder; give the {what} another name")
    _check_parents(path)
    return path


@contextlib.contextmanager
def atomic_output(path, what: str = "output"):
    """Yield a temporary path next to ``path``; rename it over ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or Path
        The final file (its parents are created).
    what : str
        What is written, for messages.

    Yields
    ------
    Path
        Where to write. On an exception it is removed and ``path`` is left as it was.

    Raises
    ------
    OutputError
        When the folder cannot be created or written, or the rename fails.
    """
    path = check_output_file(path, what)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:40]}.", suffix=".part", dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the {what} there ({exc.strerror or exc})") from None
    tmp = Path(tmp)
    try:
        yield tmp
        mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write the {what} ({exc.strerror or exc})") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_atomic(path, data, what: str = "output") -> Path:
    """Write ``data`` (str as UTF-8, or bytes) to ``path`` atomically (see :func:`atomic_output`).

    Parameters
    ----------
    path : str or Path
        The file.
    data : str or bytes
        Its content.
    what : str
        What it is, for messages.

    Returns
    -------
    Path
    """
    with atomic_output(path, what) as tmp:
        with open(tmp, "wb") as f:
            f.write(data.encode("utf-8") if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)
