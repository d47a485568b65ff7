"""One TOML table read key by key (:class:`Table`), and the typo a key most likely is (:func:`closest_key`).

Every reader of a problem file, a plant kind's table, a family's options or a campaign file goes
through :class:`Table`: a value is taken with its checks, a required key that is missing is named
(with the key given instead when that is a likely typo of it), and :meth:`Table.done` refuses every
key nobody read. Messages name the key's full path.
"""

from __future__ import annotations

from .runtime.errors import ProblemError
from .runtime.matrices import as_scalar, as_vector

_MISSING = object()
#: How alike a key must be to a known one (difflib's ratio, ignoring case) to be named as its typo.
TYPO_SIMILARITY = 0.75


def closest_key(key, candidates) -> str | None:
    """The candidate ``key`` is most likely a typo of (or the other way round), or None.

    Parameters
    ----------
    key : str
        A key as written.
    candidates : iterable
        Keys to compare it with (non-strings are ignored).

    Returns
    -------
    str or None
        The candidate most alike ``key`` when its similarity (difflib's ratio, ignoring case) is at
        least :data:`TYPO_SIMILARITY`.
    """
    import difflib                                  # here: only a key that is not known needs it

    names = {str(c).lower()[:100]: str(c) for c in candidates if isinstance(c, str) and c != key}
    near = difflib.get_close_matches(str(key).lower()[:100], list(names), n=1, cutoff=TYPO_SIMILARITY)
    return names[near[0]] if near else None
class Table:
    """Read one TOML table key by key; :meth:`done` rejects the keys nobody read.

    Parameters
    ----------
    data : dict
        The table.
    name : str
        Its key path (``"observer"``), used in messages.
    """

    def __init__(self, data, name: str):
        if not isinstance(data, dict):
            raise ProblemError(f"{name}: expected a table, found {type(data).__name__}")
        self.data = data
        self.name = name
        self.used: set[str] = set()

    def key(self, key: str) -> str:
        """Full key path of ``key``."""
        return f"{self.name}.{key}" if self.name else key

    def has(self, key: str) -> bool:
        """Whether the key is present."""
        return key in self.data

    def get(self, key: str, default=_MISSING):
        """The raw value; a missing key without default is an error."""
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            raise self.missing(key)
        return default

    def missing(self, key: str, why: str = "required key is missing") -> ProblemError:
        """The error for a required ``key`` that is absent: it names the key given instead when one
        is a likely typo of it (``observer.famliy: unknown key; did you mean 'family'?``).

        Parameters
        ----------
        key : str
            The key that is required.
        why : str, optional
            What the message says of it (``"required for a discrete plant"``).

        Returns
        -------
        ProblemError
            To raise.
        """
        typo = closest_key(key, set(self.data) - self.used - {key})
        if typo is not None:
            return ProblemError(f"{self.key(typo)[:200]}: unknown key; did you mean {key!r}? "
                                f"{self.key(key)}: {why}")
        return ProblemError(f"{self.key(key)}: {why}")

    def scalar(self, key: str, default=_MISSING, **bounds) -> float:
        """A finite number within bounds (see :func:`~uiofmu.runtime.matrices.as_scalar`)."""
        value = self.get(key, default)
        return value if value is default else as_scalar(value, self.key(key), **bounds)

    def tunable(self, key: str, default=_MISSING, **bounds):
        """A number within bounds, or the string ``"max"`` (search for the best value)."""
        value = self.get(key, default)
        if value == "max":
            return "max"
        if isinstance(value, str):
            raise ProblemError(f'{self.key(key)}: expected a number or "max", found {value!r}')
        return value if value is default else as_scalar(value, self.key(key), **bounds)

    def vector(self, key: str, size: int | None = None, default=_MISSING):
        """A list of numbers."""
        value = self.get(key, default)
        return value if value is default else as_vector(value, self.key(key), size)

    def choice(self, key: str, options: tuple, default=_MISSING) -> str:
        """One of ``options``."""
        value = self.get(key, default)
        if value not in options:
            raise ProblemError(f"{self.key(key)}: expected one of {', '.join(map(repr, options))}, found {value!r}")
        return value

    def done(self, allowed_hint: str = "") -> None:
        """Raise on any key that was not read."""
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            known = ", ".join(sorted(self.used))
            typo = closest_key(unknown[0], self.used)
            raise ProblemError(f"{self.key(unknown[0])[:200]}: unknown key"
                               + (f"; did you mean {typo!r}?" if typo else "")
                               + (f" (known here: {known})" if known else "") + allowed_hint)


__all__ = ["TYPO_SIMILARITY", "Table", "closest_key"]
