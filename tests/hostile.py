"""Hostile inputs for uiofmu, and the oracle that judges what the command line did with them.

This module is the attacker's half of the fuzzing harness (``tests/test_fuzz.py`` runs it
bounded in ``make test``, ``tests/fuzz_campaign.py`` at length in ``make fuzz``). Everything is
deterministic: generators are plain functions of a :class:`random.Random`, or finite lists that
hypothesis samples from.

Four families of hostile input:

(a) problem files: single and compound mutations of the valid example problems (every key
    deleted and retyped, matrices ragged, empty, huge, non-finite; dt and tunables out of range;
    hostile names; deep nesting; unknown keys and families), raw text mutations and random TOML;
(b) design cards: every field of a designed card replaced, retyped, deleted or set out of range,
    JSON ``NaN``/``Infinity`` literals, 100,000-deep JSON, and the known code-injection payloads;
(c) co-simulation arguments: step SPECs, ``file:`` step files, seeds, end times, output folders,
    input tables;
(d) FMUs: archives without their binary, zips that are not FMUs, broken model descriptions,
    hostile ``resources/model.json``.

A :class:`Case` is one command (plus optional follow-up commands on what it produced) with the
files it needs; :func:`run_case` materialises it in a fresh sandbox, runs it (in a subprocess,
or in-process through ``run_cli`` for the commands that load no FMU) and returns an
:class:`Outcome` whose :attr:`Outcome.problems` lists every broken promise of the contract:
an exit code other than 0 or 2, a signal, a hang, a traceback, an exit-2 message that is not one
line ``uiofmu COMMAND: error: ...``, a file created, changed or removed outside the target, an
existing output lost by a failing command, an injection marker file, or (for inputs that are
invalid beyond doubt) a success.
"""

from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import io
import json
import math
import os
import random
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The valid problem files every mutation starts from (key, path).
BASE_PROBLEMS = {
    "ex1": ROOT / "examples" / "seed000_example1.toml",
    "ltv": ROOT / "examples" / "seed000_example1_ltv.toml",
    "building": ROOT / "plants" / "two_room_building" / "problem.toml",
}
#: Which plant FMU drives the observer of each base problem.
PLANT_OF = {"ex1": "ex1", "ltv": "ex1", "building": "building"}
#: A co-simulation end time that keeps each base short (a few dozen steps).
SHORT_T_END = {"ex1": "2", "ltv": "2", "building": "20000"}
#: The steps each base observer accepts.
GOOD_STEPS = {"ex1": "fixed:0.1", "ltv": "fixed:0.1", "building": "choice:600,1200,1800"}
#: Where a sandbox's absolute path is substituted into generated files (see :func:`materialise`).
ROOT_TOKEN = b"@@SANDBOX@@"
#: Every injection payload creates a file whose name contains this.
MARKER = "UIOFMU_MARKER"
#: Size limit of input files in the contract (bytes).
SIZE_LIMIT = 64 * 2**20
#: Families the product knows by name (some of them unsupported by this version).
KNOWN_FAMILIES = ("lti-uio", "ltv-auid", "switched", "sampled-data", "deadbeat-functional", "delayed-uio")
#: Keys a design card must have (SPEC.md plus ``name``, ``schedule``, ``initial``).
CARD_REQUIRED = ("format", "version", "family", "name", "dims", "time", "dt", "schedule", "matrices",
                 "initial", "certificate", "problem")
#: Matrices the observer runtime reads from a card.
RUNTIME_MATRICES = ("N", "L", "G", "c", "Xz", "Xy", "C", "Dy", "Yx", "Yu", "Yc")
NAN, INF = float("nan"), float("inf")


# ---------------------------------------------------------------------------------------------
# hostile values
# ---------------------------------------------------------------------------------------------
class Raw:
    """Text written verbatim into a serialised document (a literal no Python value produces).

    Parameters
    ----------
    text : str
        The literal, e.g. ``"1e400"`` (a float that overflows to infinity when parsed) or
        ``"1" + "0" * 5000`` (an integer longer than Python's int-string limit).
    """

    def __init__(self, text: str):
        self.text = text

    def __repr__(self) -> str:
        return f"Raw({self.text[:40]!r}{'...' if len(self.text) > 40 else ''})"

    def __deepcopy__(self, memo):
        return self


class Deep:
    """A list or table nested ``depth`` levels deep around the number 1.0, written directly as
    text by the serialisers (so that writing it needs no recursion).

    Parameters
    ----------
    kind : {"list", "table"}
    depth : int
    """

    def __init__(self, kind: str, depth: int):
        self.kind, self.depth = kind, depth

    def toml(self) -> str:
        """The TOML text."""
        if self.kind == "list":
            return "[" * self.depth + "1.0" + "]" * self.depth
        return "{a = " * self.depth + "1.0" + "}" * self.depth

    def json(self) -> str:
        """The JSON text."""
        if self.kind == "list":
            return "[" * self.depth + "1.0" + "]" * self.depth
        return '{"a": ' * self.depth + "1.0" + "}" * self.depth

    def __repr__(self) -> str:
        return f"Deep({self.kind!r}, {self.depth})"

    def __deepcopy__(self, memo):
        return self


#: Hostile text: quotes, comment closers, format and template fields, control characters,
#: long and unicode strings, paths and code.
HOSTILE_STRINGS = [
    ("empty", ""),
    ("blank", "   "),
    ("quotes", "a\"b'c"),
    ("comment-closer", "x */ y /* z"),
    ("c-comment-injection", "x **// int y;"),
    ("line-comment", "x // y"),
    ("newline", "a\nb"),
    ("crlf", "a\r\nb"),
    ("backslash", "a\\b\\"),
    ("backslash-newline", "a\\\nb"),
    ("trigraph", "??/ ??= ??'"),
    ("percent-format", "%s%s%n%x%d"),
    ("brace-format", "{0}{name!r}{__class__.__mro__}"),
    ("template-field", "${x}"),
    ("template-dollar", "$x $$ $"),
    ("template-runtime", "${runtime}"),
    ("template-class", "$class_name"),
    ("fmu-description", "FMU_DESCRIPTION"),
    ("runtime-name", "UIOFMU_RT"),
    ("nul", "a\x00b"),
    ("controls", "".join(chr(i) for i in range(1, 32)) + "\x7f"),
    ("escape-sequence", "\x1b[31mred\x1b[0m"),
    ("long-100k", "x" * 100_000),
    ("long-129", "n" * 129),
    ("unicode", "h\u00e9llo-\u4e16\u754c-\U0001f642"),
    ("right-to-left", "\u202eabc"),
    ("zero-width", "a\u200bb"),
    ("combining", "e\u0301\u0301\u0301"),
    ("path-traversal", "../../../../tmp/evil"),
    ("absolute-path", "/etc/passwd"),
    ("dotdot", ".."),
    ("xml", "<a b=\"c\">&amp;</a>]]><!--"),
    ("python-code", "__import__('os').getcwd()"),
    ("shell", "$(true); `true` | true"),
    ("option", "--help"),
    ("keyword", "class"),
    ("max", "max"),
    ("MAX", "MAX"),
    ("number-text", "1e308"),
    ("nan-text", "nan"),
]

#: One value of every type a document can hold, for retyping any key.
TYPE_PROBES = [
    ("string", "x"),
    ("bool-true", True),
    ("bool-false", False),
    ("int-zero", 0),
    ("int-negative", -3),
    ("int-huge", 10**400),
    ("int-2**63", 2**63),
    ("float-nan", NAN),
    ("float-inf", INF),
    ("float-neg-inf", -INF),
    ("float-1e308", 1e308),
    ("float-denormal", 5e-324),
    ("float-negative", -0.5),
    ("list-empty", []),
    ("list-nested", [[["x"]], [1.0]]),
    ("list-deep-500", Deep("list", 500)),
    ("table", {"a": 1.0}),
    ("table-empty", {}),
    ("table-deep-500", Deep("table", 500)),
    ("list-of-tables", [{"kind": "constant", "value": 1.0}]),
    ("string-long-100k", "x" * 100_000),
]
#: Values only TOML holds.
TOML_ONLY_PROBES = [
    ("datetime", _dt.datetime(1979, 5, 27, 7, 32, tzinfo=_dt.timezone.utc)),
    ("date", _dt.date(1979, 5, 27)),
    ("time", _dt.time(7, 32)),
    ("int-5000-digits", Raw("1" + "0" * 5000)),
    ("float-1e400", Raw("1e400")),
    ("float-plus-nan", Raw("+nan")),
    ("float-minus-nan", Raw("-nan")),
]
#: Values only JSON holds (or spells differently).
JSON_ONLY_PROBES = [
    ("null", None),
    ("NaN-literal", Raw("NaN")),
    ("Infinity-literal", Raw("Infinity")),
    ("minus-Infinity-literal", Raw("-Infinity")),
    ("number-1e400", Raw("1e400")),
    ("number-minus-1e400", Raw("-1e400")),
    ("int-5000-digits", Raw("1" + "0" * 5000)),
    ("lone-surrogate", Raw('"\\ud800"')),
    ("minus-zero", Raw("-0")),
    ("list-deep-1000", Deep("list", 1000)),
]
#: Numbers at and beyond the edges, for keys that hold a number.
NUMERIC_EDGES = [
    ("zero", 0.0), ("minus-zero", -0.0), ("negative", -1.0), ("one", 1.0), ("fifty", 50.0),
    ("1e308", 1e308), ("-1e308", -1e308), ("denormal", 5e-324), ("1e-300", 1e-300), ("nan", NAN),
    ("inf", INF), ("-inf", -INF), ("int-huge", 10**400), ("int-2**63", 2**63), ("max", "max"),
    ("MAX", "MAX"), ("true", True), ("number-as-string", "0.5"),
]
#: Integers at and beyond the edges, for keys that hold a count, a seed or a dimension.
INTEGER_EDGES = [
    ("zero", 0), ("negative", -1), ("one", 1), ("three", 3), ("2**31", 2**31), ("2**63", 2**63),
    ("1e9", 10**9), ("1e18", 10**18), ("int-huge", 10**400), ("float", 1.5), ("float-integral", 2.0),
    ("true", True), ("false", False), ("string", "2"), ("nan", NAN),
]
#: Family names: known, unsupported, misspelled and hostile.
FAMILY_VALUES = [(f, f) for f in KNOWN_FAMILIES] + [
    ("unknown", "kalman"), ("upper-case", "LTI-UIO"), ("padded", " lti-uio "), ("nul-suffix", "lti-uio\x00"),
    ("python-class", "A(__import__('os').getcwd() or Fmi2Slave):#"), ("empty-family", ""),
]
#: Keys that hold a number in problem files and cards.
NUMERIC_KEYS = {"dt", "h_prev0", "decay", "alpha", "eta", "mu", "value", "amplitude", "frequency_hz", "omega",
                "phase", "offset", "time", "initial", "std", "mean", "hold", "min", "max", "step_rtol",
                "decay_bound", "overshoot_bound", "spectral_radius_N", "lmi_margin", "rho2", "bound",
                "verify_fraction", "seconds", "total_s", "solver_s", "lmi_assembly_s"}
#: Keys that hold an integer.
INTEGER_KEYS = {"count", "seed", "n", "m", "p", "q", "nz", "version", "solves"}
#: Keys that hold a matrix or a vector.
MATRIX_KEYS = {"A", "B", "E", "C", "D", "w", "x0", "xhat0", "intervals", "N", "L", "G", "c", "Xz", "Xy", "Dy",
               "Yx", "Yu", "Yc", "M", "K", "P", "X"}


def matrix_variants(value) -> list:
    """Hostile replacements for a matrix (list of rows) or a vector (list of numbers).

    Parameters
    ----------
    value : list
        The valid matrix or vector.

    Returns
    -------
    list of (str, object, bool)
        ``(label, replacement, invalid)``: ``invalid`` says a product must refuse it whatever
        the key (ragged, empty, non-finite or non-numeric entries).
    """
    out = []
    if not isinstance(value, list):
        return out
    if value and all(isinstance(r, list) for r in value):
        rows = [list(r) for r in value]
        cols = len(rows[0]) if rows else 0

        def with_entry(x):
            m = copy.deepcopy(rows)
            if m and m[0]:
                m[0][0] = x
            return m
        ragged = copy.deepcopy(rows)
        if len(ragged) >= 2:
            ragged[-1] = ragged[-1] + [0.0]
        else:
            ragged.append([0.0] * (cols + 1))
        out += [
            ("ragged", ragged, True),
            ("empty", [], False),
            ("empty-row", [[]], True),
            ("empty-rows", [[] for _ in rows], True),
            ("transposed", [list(c) for c in zip(*rows)], False),
            ("extra-row", rows + [[0.0] * cols], False),
            ("extra-column", [r + [0.0] for r in rows], False),
            ("huge-rows-5000", [[0.0] * max(cols, 1) for _ in range(5000)], False),
            ("huge-columns-5000", [[0.0] * 5000 for _ in rows], False),
            ("nan-entry", with_entry(NAN), True),
            ("inf-entry", with_entry(INF), True),
            ("neg-inf-entry", with_entry(-INF), True),
            ("1e308-entries", [[1e308] * len(r) for r in rows], False),
            ("huge-int-entry", with_entry(10**400), True),
            ("string-entry", with_entry("1.0"), True),
            ("bool-entry", with_entry(True), True),
            ("nested-entry", with_entry([[0.0]]), True),
            ("table-entry", with_entry({"re": 1.0}), True),
            ("denormal-entries", [[5e-324] * len(r) for r in rows], False),
            ("three-d", [rows, rows], True),
            ("flat", rows[0], False),
            ("scalar", 1.0, False),
            ("row-strings", [",".join(map(str, r)) for r in rows], True),
        ]
    else:
        vec = list(value)

        def at0(x):
            v = copy.deepcopy(vec)
            if v:
                v[0] = x
            return v
        out += [
            ("shorter", vec[:-1], False),
            ("longer", vec + [0.0], False),
            ("empty", [], False),
            ("nan-entry", at0(NAN), True),
            ("inf-entry", at0(INF), True),
            ("huge-int-entry", at0(10**400), True),
            ("string-entry", at0("0"), True),
            ("bool-entry", at0(True), True),
            ("nested", [vec], False),
            ("huge-length-100k", [0.0] * 100_000, False),
            ("negative-entries", [-abs(float(x)) - 1.0 if _finite_number(x) else -1.0 for x in vec], False),
            ("duplicated", vec + vec, False),
            ("reversed", vec[::-1], False),
        ]
    return out


# ---------------------------------------------------------------------------------------------
# serialisers (they write what Python's writers refuse: nan, inf, big integers, raw literals)
# ---------------------------------------------------------------------------------------------
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+\Z")


def toml_string(text: str) -> str:
    """A TOML basic string of ``text`` (control characters as ``\\uXXXX`` escapes).

    Parameters
    ----------
    text : str

    Returns
    -------
    str
    """
    out = ['"']
    for ch in text:
        code = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04X}")
        elif 0xD800 <= code <= 0xDFFF:
            out.append("\\uFFFD")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_key(key) -> str:
    """A TOML key: bare when it can be, else quoted."""
    key = str(key)
    return key if _BARE_KEY.match(key) else toml_string(key)


def toml_value(value) -> str:
    """One TOML value (inline tables for dicts) of any hostile value.

    Parameters
    ----------
    value : object
        bool, int (any size), float (including nan and inf), str, datetime, date, time,
        :class:`Raw`, list or dict.

    Returns
    -------
    str
    """
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, Deep):
        return value.toml()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return toml_string(value)
    if isinstance(value, (_dt.datetime, _dt.date, _dt.time)):
        return value.isoformat()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + "}"
    if value is None:
        return '""'
    raise TypeError(f"no TOML for {type(value).__name__}")


def toml_dumps(doc: dict) -> str:
    """A whole TOML document: top-level values first, then one ``[table]`` per top-level dict.

    Parameters
    ----------
    doc : dict

    Returns
    -------
    str
    """
    lines = [f"{toml_key(k)} = {toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for key, table in doc.items():
        if isinstance(table, dict):
            lines += ["", f"[{toml_key(key)}]"] + [f"{toml_key(k)} = {toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def json_text(value) -> str:
    """JSON of any hostile value: ``NaN``/``Infinity`` literals, big integers, :class:`Raw`.

    Parameters
    ----------
    value : object

    Returns
    -------
    str
    """
    if isinstance(value, Raw):
        return value.text
    if isinstance(value, Deep):
        return value.json()
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))}: {json_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(json_text(v) for v in value) + "]"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return repr(value)
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, (_dt.datetime, _dt.date, _dt.time)):
        return json.dumps(value.isoformat())
    raise TypeError(f"no JSON for {type(value).__name__}")


# ---------------------------------------------------------------------------------------------
# document mutation
# ---------------------------------------------------------------------------------------------
def doc_paths(doc, list_items: int = 1) -> list[tuple]:
    """Every path of a document: each key of every table, and the first and last item of lists.

    Parameters
    ----------
    doc : dict
    list_items : int
        How many leading items of each list to visit (the last one is always visited).

    Returns
    -------
    list of tuple
        Paths of keys and indices, the root excluded.
    """
    out = []

    def walk(value, path):
        if path:
            out.append(path)
        if isinstance(value, dict):
            for key in value:
                walk(value[key], path + (key,))
        elif isinstance(value, list) and value:
            idx = sorted(set(range(min(list_items, len(value)))) | {len(value) - 1})
            for i in idx:
                walk(value[i], path + (i,))
    walk(doc, ())
    return out


def get_path(doc, path):
    """The value at ``path`` (KeyError/IndexError when gone)."""
    for key in path:
        doc = doc[key]
    return doc


class Mutation:
    """One edit of a document.

    Attributes
    ----------
    op : str
        ``"delete"``, ``"set"`` or ``"insert"`` (a new key in the table at ``path``).
    path : tuple
        Where.
    label : str
        What the new value is.
    value : object
        The new value (``"set"``, ``"insert"``).
    key : str
        The new key (``"insert"``).
    invalid : bool
        The product must refuse the result (a success is a broken promise).
    """

    def __init__(self, op: str, path: tuple, label: str = "", value=None, key: str = "", invalid: bool = False):
        self.op, self.path, self.label, self.value, self.key, self.invalid = op, tuple(path), label, value, key, invalid

    def __repr__(self) -> str:
        return f"<Mutation {self.describe()}>"

    def describe(self) -> str:
        """``plant.A[0] := ragged`` and the like."""
        where = "".join(f"[{p}]" if isinstance(p, int) else (f".{p}" if i else str(p))
                        for i, p in enumerate(self.path)) or "<top level>"
        if self.op == "delete":
            return f"{where} deleted"
        if self.op == "insert":
            return f"{where} += {self.key[:30]!r} = {self.label}"
        return f"{where} := {self.label}"

    def apply(self, doc) -> bool:
        """Apply in place; False when the path no longer exists.

        Parameters
        ----------
        doc : dict

        Returns
        -------
        bool
        """
        try:
            if self.op == "insert":
                target = get_path(doc, self.path) if self.path else doc
                if not isinstance(target, dict):
                    return False
                target[self.key] = copy.deepcopy(self.value)
                return True
            parent = get_path(doc, self.path[:-1])
            last = self.path[-1]
            if isinstance(parent, dict) and not isinstance(last, int) or isinstance(parent, list) and \
                    isinstance(last, int):
                if self.op == "delete":
                    del parent[last]
                else:
                    parent[last] = copy.deepcopy(self.value)
                return True
        except (KeyError, IndexError, TypeError):
            pass
        return False


def _key_of(path) -> str:
    for p in reversed(path):
        if isinstance(p, str):
            return p
    return ""


def mutations_at(doc, path, kind: str) -> list[Mutation]:
    """Every hostile edit of one path: deletion, every type, edge values of its key.

    Parameters
    ----------
    doc : dict
        The document.
    path : tuple
        A path of ``doc``.
    kind : {"problem", "card"}
        Selects the probes only its format can carry and what must be refused.

    Returns
    -------
    list of Mutation
    """
    value = get_path(doc, path)
    key = _key_of(path)
    judge_edit = must_refuse_card if kind == "card" else must_refuse_problem

    def invalid(label, v):
        try:
            return judge_edit(path, label, v, doc)
        except (KeyError, IndexError, TypeError, AttributeError, ValueError, OverflowError):
            return False  # a document already too broken to say
    out = [Mutation("delete", path, invalid=invalid("<deleted>", _DELETED))]
    probes = TYPE_PROBES + (TOML_ONLY_PROBES if kind == "problem" else JSON_ONLY_PROBES)
    for label, v in probes:
        out.append(Mutation("set", path, label, v, invalid=invalid(label, v)))
    if isinstance(value, str) or key in ("name", "family", "kind", "time", "step_policy", "format"):
        for label, v in HOSTILE_STRINGS:
            out.append(Mutation("set", path, f"string:{label}", v, invalid=invalid(label, v)))
    if key == "family" and len(path) in (1, 2):
        for label, v in FAMILY_VALUES:
            out.append(Mutation("set", path, f"family:{label}", v, invalid=invalid(label, v)))
    if key in NUMERIC_KEYS and not isinstance(value, (dict, list)):
        for label, v in NUMERIC_EDGES:
            out.append(Mutation("set", path, f"number:{label}", v, invalid=invalid(label, v)))
    if key in INTEGER_KEYS and not isinstance(value, (dict, list)):
        for label, v in INTEGER_EDGES:
            out.append(Mutation("set", path, f"integer:{label}", v, invalid=invalid(label, v)))
    if key in MATRIX_KEYS and isinstance(value, list):
        for label, v, bad in matrix_variants(value):
            out.append(Mutation("set", path, f"matrix:{label}", v, invalid=bad and invalid(label, v)))
    if isinstance(value, dict):
        for label, k in [("unknown", "solver"), ("dunder", "__class__"), ("empty-key", ""), ("dotted", "a.b"),
                         ("nul-key", "k\x00"), ("long-key", "k" * 10_000), ("dollar-key", "${x}")]:
            out.append(Mutation("insert", path, f"unknown-key:{label}", 1.0, key=k,
                                invalid=kind == "problem" and path[:1] in (("plant",), ("observer",), ("signals",))))
    return out


_DELETED = object()


def _raw_value(raw: Raw):
    """What a :class:`Raw` literal parses to (JSON first, then a float), or None."""
    try:
        return json.loads(raw.text)
    except ValueError:
        try:
            return float(raw.text)
        except ValueError:
            return None


def _finite_number(v) -> bool:
    """A number (not a bool) that a float holds finitely (a :class:`Raw` by what it parses to)."""
    if isinstance(v, Raw):
        v = _raw_value(v)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    if isinstance(v, int):
        return abs(v) < 2**1000
    return math.isfinite(v)


def must_refuse_problem(path, label, value, doc) -> bool:
    """Whether a problem file edited this way is invalid beyond doubt (a success is a bug).

    Invalid: a non-finite or non-numeric plant matrix entry, a period that is not a finite
    positive number, an unknown observer family, a value nested beyond the nesting limit.
    """
    if label in ("list-deep-500", "table-deep-500"):
        return True
    if len(path) >= 2 and path[0] == "plant" and path[1] == "dt" and doc.get("plant", {}).get("time") == "discrete":
        return value is _DELETED or not (_finite_number(value) and float(value) > 0)
    if path == ("observer", "family"):
        return value is _DELETED or value not in ("lti-uio", "ltv-auid", "sampled-data")
    if len(path) >= 3 and path[0] == "plant" and path[1] in ("A", "B", "C", "E", "x0", "w"):
        return value is _DELETED or not _same_shape_finite(value, get_path(doc, path))
    return False


def must_refuse_card(path, label, value, doc) -> bool:
    """Whether a design card edited this way is invalid beyond doubt (building it is a bug).

    Invalid: any required key deleted; ``format`` other than ``"uiofmu.design"``; ``version``
    other than the integer 1 (``true`` included); ``certificate.verified`` anything but
    ``true``; a dimension changed (or given as a bool); ``initial.xhat0`` of the wrong length or
    not finite; a runtime matrix with non-finite, non-numeric entries or another shape; a period,
    interval or ``h_prev0`` that is not a finite positive number; ``schedule.alpha`` outside
    (0, 1); an unknown schedule kind or step policy; another family; nesting beyond the limit.
    """
    if value is _DELETED and len(path) == 1:
        return path[0] in CARD_REQUIRED
    if label in ("list-deep-500", "table-deep-500", "list-deep-1000"):
        return True
    head = path[0]
    if head == "format":
        return value != "uiofmu.design"
    if head == "version" and len(path) == 1:
        return not (type(value) is int and value == 1)
    if path == ("certificate",):
        return True
    if path[:2] == ("certificate", "verified"):
        return value is not True
    if head == "dims":
        if len(path) == 1:
            return True
        if len(path) == 2 and path[1] in ("n", "m", "p", "q", "nz"):
            old = doc["dims"][path[1]]
            return value is _DELETED or type(value) is not int or value != old
        return False
    if head == "initial" and len(path) >= 2 and path[1] == "xhat0":
        if len(path) == 2:
            return not (isinstance(value, list) and len(value) == doc["dims"]["n"] and all(map(_finite_number, value)))
        return not _finite_number(value)
    if head == "matrices" and len(path) >= 2 and path[1] in RUNTIME_MATRICES and path[1] in doc["matrices"]:
        if len(path) == 2:
            return value is _DELETED and path[1] in ("N", "L", "G", "c", "Xz", "Xy", "C") or \
                value is not _DELETED and not _same_shape_finite(value, doc["matrices"][path[1]])
        return not _same_shape_finite(value, get_path(doc, path))
    if path in (("dt",), ("schedule", "dt"), ("schedule", "h_prev0")):
        old = get_path(doc, path)
        if old is None:
            return False
        return not (_finite_number(value) and float(value) > 0)
    if path[:2] == ("schedule", "intervals"):
        if len(path) == 2:
            return not (isinstance(value, list) and value and all(_finite_number(v) and v > 0 for v in value))
        return not (_finite_number(value) and float(value) > 0)
    if path == ("schedule", "alpha"):
        return not (_finite_number(value) and 0 < float(value) < 1)
    if path == ("schedule", "kind"):
        return value != get_path(doc, path)
    if path == ("schedule", "step_policy"):
        return value not in ("error", "nearest", "count")
    if path == ("schedule",):
        return True
    if path == ("family",):
        return value != doc["family"]
    return False


def _same_shape_finite(value, like) -> bool:
    """Whether ``value`` has the nested shape of ``like`` with finite numbers only."""
    if isinstance(like, list):
        return isinstance(value, list) and len(value) == len(like) and all(
            _same_shape_finite(v, w) for v, w in zip(value, like))
    return _finite_number(value)


def all_mutations(doc, kind: str, list_items: int = 1) -> list[Mutation]:
    """Every single-edit mutation of a document (every path, every probe).

    Parameters
    ----------
    doc : dict
    kind : {"problem", "card"}
    list_items : int
        Leading items visited in each list (see :func:`doc_paths`).

    Returns
    -------
    list of Mutation
    """
    out = []
    for path in doc_paths(doc, list_items):
        out += mutations_at(doc, path, kind)
    for label, key in [("unknown", "solver"), ("dunder", "__class__"), ("empty-key", ""), ("nul-key", "k\x00"),
                       ("long-key", "k" * 10_000), ("dollar-key", "${x}")]:
        out.append(Mutation("insert", (), f"unknown-key:{label}", 1.0, key=key, invalid=kind == "problem"))
    return out


_POOLS: dict = {}


def mutation_pool(bases: "Bases", kind: str, base: str) -> list[Mutation]:
    """:func:`all_mutations` of a base problem or card, computed once.

    Parameters
    ----------
    bases : Bases
    kind : {"problem", "card"}
    base : str

    Returns
    -------
    list of Mutation
    """
    key = (id(bases), kind, base)
    if key not in _POOLS:
        doc = (bases.problems if kind == "problem" else bases.cards)[base][1]
        _POOLS[key] = all_mutations(doc, kind)
    return _POOLS[key]


def compound_mutation(rng, doc, kind: str, count: int | None = None) -> tuple[dict, list[Mutation]]:
    """A copy of ``doc`` with 1 to 3 random edits applied one after the other.

    Parameters
    ----------
    rng : random.Random
    doc : dict
    kind : {"problem", "card"}
    count : int, optional
        Number of edits (default: 1 to 3).

    Returns
    -------
    dict, list of Mutation
        The edited document and the edits that applied.
    """
    new = copy.deepcopy(doc)
    applied = []
    for _ in range(count or rng.randint(1, 3)):
        paths = doc_paths(new)
        if not paths:
            break
        path = rng.choice(paths)
        options = mutations_at(new, path, kind)
        mut = rng.choice(options)
        if mut.apply(new):
            applied.append(mut)
    return new, applied


# ---------------------------------------------------------------------------------------------
# (a) problem files
# ---------------------------------------------------------------------------------------------
def load_base_problems() -> dict:
    """The valid base problems: key -> (text, parsed document)."""
    import tomllib

    out = {}
    for key, path in BASE_PROBLEMS.items():
        text = path.read_text(encoding="utf-8")
        out[key] = (text, tomllib.loads(text))
    return out


def problem_text(doc: dict) -> bytes:
    """A problem document as TOML bytes."""
    return toml_dumps(doc).encode("utf-8")


def deep_toml_texts() -> list[tuple[str, bytes]]:
    """Whole problem files nested far beyond any sane limit (500 levels)."""
    n = 500
    return [
        ("deep-array-500", ("a = " + "[" * n + "]" * n + "\n").encode()),
        ("deep-inline-table-500", ("a = " + "{b = " * n + "1" + "}" * n + "\n").encode()),
        ("deep-dotted-key-500", (".".join(["a"] * n) + " = 1\n").encode()),
        ("deep-table-header-500", ("[" + ".".join(["a"] * n) + "]\nb = 1\n").encode()),
        ("deep-array-in-plant-A", b"[plant]\ntime = \"discrete\"\ndt = 0.1\nA = " + b"[" * n + b"]" * n + b"\n"),
        ("deep-array-5000", ("a = " + "[" * 5000 + "]" * 5000 + "\n").encode()),
    ]


def raw_text_mutations(rng, text: str) -> list[tuple[str, bytes]]:
    """Mutations of a problem file's text that no document edit produces.

    Parameters
    ----------
    rng : random.Random
    text : str
        A valid problem file.

    Returns
    -------
    list of (str, bytes)
    """
    data = text.encode("utf-8")
    lines = text.splitlines(keepends=True)
    pos = rng.randrange(len(data))
    flip = bytearray(data)
    flip[pos] ^= 1 << rng.randrange(8)
    dup = lines[rng.randrange(len(lines))]
    out = [
        ("truncated", data[:pos]),
        ("bit-flip", bytes(flip)),
        ("nul-inserted", data[:pos] + b"\x00" + data[pos:]),
        ("invalid-utf8", data[:pos] + b"\xff\xfe" + data[pos:]),
        ("utf8-bom", b"\xef\xbb\xbf" + data),
        ("utf16", text.encode("utf-16")),
        ("crlf", text.replace("\n", "\r\n").encode()),
        ("cr-only", text.replace("\n", "\r").encode()),
        ("duplicated-line", (text + dup).encode()),
        ("duplicated-file", (text + "\n" + text).encode()),
        ("line-deleted", "".join(lines[:pos % len(lines)] + lines[pos % len(lines) + 1:]).encode()),
        ("garbage-appended", data + bytes(rng.randrange(256) for _ in range(64))),
        ("empty", b""),
        ("whitespace", b"   \n\t\n"),
        ("comment-only", b"# nothing here\n"),
        ("nul-only", b"\x00" * 16),
        ("random-bytes", bytes(rng.randrange(256) for _ in range(256))),
        ("long-line-1M", b"name = \"" + b"x" * 1_000_000 + b"\"\n" + data),
        ("int-5000-digits", re.sub(rb"dt = [0-9.e+-]+", b"dt = 1" + b"0" * 5000, data) if b"dt =" in data
         else b"name = 1" + b"0" * 5000 + b"\n" + data),
        ("float-1e400-in-A", re.sub(rb"A = \[\[[^,\]]+", b"A = [[1e400", data)),
        ("minus-nan-in-A", re.sub(rb"A = \[\[[^,\]]+", b"A = [[-nan", data)),
        ("invalid-unicode-escape", b'name = "\\uD800"\n' + data),
        ("multiline-string-name", re.sub(rb'name = "[^"]*"', b'name = """a\n*/ b\n"""', data)),
        ("literal-string-name", re.sub(rb'name = "[^"]*"', b"name = 'x **// \\\\'", data)),
    ] + deep_toml_texts()
    return out


_VOCAB = ["name", "plant", "observer", "signals", "A", "B", "E", "C", "D", "w", "x0", "dt", "time", "family",
          "decay", "alpha", "eta", "mu", "intervals", "min", "max", "count", "xhat0", "h_prev0", "step_policy",
          "u", "d", "kind", "value", "modes", "scheduling", "theta", "parameters", "mujoco", "x", "__proto__"]


def random_value(rng, depth: int = 0):
    """A random TOML-able value (scalars of every type, lists, tables, matrices).

    Parameters
    ----------
    rng : random.Random
    depth : int
        Current nesting (values stay within 5 levels).

    Returns
    -------
    object
    """
    choice = rng.randrange(12 if depth < 4 else 8)
    if choice == 0:
        return rng.choice(HOSTILE_STRINGS[:20])[1]
    if choice == 1:
        return rng.choice([True, False])
    if choice == 2:
        return rng.choice([0, 1, -1, 2, 12, 10**400, 2**63, rng.randrange(-10**6, 10**6)])
    if choice == 3:
        return rng.choice([0.0, 0.1, -0.5, 1e308, 5e-324, NAN, INF, -INF, rng.uniform(-10, 10)])
    if choice == 4:
        return rng.choice(["continuous", "discrete", "max", "lti-uio", "ltv-auid", "sampled-data", "constant",
                           "sine", "error", "count", "nearest"])
    if choice == 5:
        n, m = rng.randint(0, 4), rng.randint(0, 4)
        return [[rng.choice([0.0, 1.0, -0.5, rng.uniform(-2, 2)]) for _ in range(m)] for _ in range(n)]
    if choice == 6:
        return [rng.uniform(-2, 2) for _ in range(rng.randint(0, 4))]
    if choice == 7:
        return rng.choice([_dt.date(2000, 1, 1), [], {}])
    if choice in (8, 9):
        return [random_value(rng, depth + 1) for _ in range(rng.randint(0, 3))]
    return {rng.choice(_VOCAB): random_value(rng, depth + 1) for _ in range(rng.randint(0, 4))}


def random_toml(rng) -> bytes:
    """A random TOML problem-like document (keys from the problem vocabulary).

    Parameters
    ----------
    rng : random.Random

    Returns
    -------
    bytes
    """
    doc = {}
    for _ in range(rng.randint(0, 5)):
        doc[rng.choice(_VOCAB)] = random_value(rng, 0)
    if rng.random() < 0.7:
        doc["plant"] = {k: random_value(rng, 1) for k in rng.sample(["A", "B", "E", "C", "time", "dt", "x0", "w"],
                                                                   rng.randint(1, 8))}
        doc["observer"] = {k: random_value(rng, 1) for k in rng.sample(["family", "decay", "alpha", "eta", "mu",
                                                                        "intervals", "xhat0"], rng.randint(1, 4))}
    return problem_text(doc)


def random_plant_problem(rng, n: int, family: str = "lti-uio") -> dict:
    """A consistent random discrete problem with ``n`` states (one input, one unknown input,
    ``n - 1`` outputs), to stress sizes rather than parsing.

    Parameters
    ----------
    rng : random.Random
    n : int
    family : str

    Returns
    -------
    dict
    """
    A = [[rng.uniform(-0.3, 0.3) / max(1, n ** 0.5) for _ in range(n)] for _ in range(n)]
    E = [[1.0 if i == 0 else 0.0] for i in range(n)]
    B = [[rng.uniform(-1, 1)] for _ in range(n)]
    C = [[1.0 if j == i else 0.0 for j in range(n)] for i in range(max(n - 1, 1))]
    return {"name": f"random-{n}", "plant": {"time": "discrete", "dt": 0.1, "A": A, "B": B, "E": E, "C": C},
            "observer": {"family": family}}


# ---------------------------------------------------------------------------------------------
# (b) design cards
# ---------------------------------------------------------------------------------------------
def card_text(doc) -> bytes:
    """A card document as JSON bytes (hostile literals allowed)."""
    return json_text(doc).encode("utf-8")


def deep_json_texts() -> list[tuple[str, bytes]]:
    """Design cards nested 100,000 levels deep (whole document, and inside a valid-looking card)."""
    n = 100_000
    return [
        ("deep-list-100k", b"[" * n + b"]" * n),
        ("deep-object-100k", b'{"a":' * n + b"1" + b"}" * n),
        ("deep-in-problem-100k", b'{"format": "uiofmu.design", "version": 1, "problem": ' + b"[" * n + b"]" * n + b"}"),
    ]


def raw_card_mutations(rng, text: str) -> list[tuple[str, bytes]]:
    """Mutations of a card's JSON text that no document edit produces.

    Parameters
    ----------
    rng : random.Random
    text : str
        A valid card.

    Returns
    -------
    list of (str, bytes)
    """
    data = text.encode("utf-8")
    pos = rng.randrange(len(data.rstrip()) - 1)
    flip = bytearray(data)
    flip[pos] ^= 1 << rng.randrange(8)
    return [
        ("truncated", data[:pos]),
        ("bit-flip", bytes(flip)),
        ("nul-inserted", data[:pos] + b"\x00" + data[pos:]),
        ("invalid-utf8", data[:pos] + b"\xff" + data[pos:]),
        ("utf8-bom", b"\xef\xbb\xbf" + data),
        ("utf16", text.encode("utf-16")),
        ("trailing-garbage", data + b"}{"),
        ("duplicate-key", data.replace(b'"version": 1', b'"version": 1, "version": true', 1)),
        ("empty", b""),
        ("null", b"null"),
        ("list", b"[]"),
        ("string", b'"uiofmu.design"'),
        ("number", b"1"),
        ("nul-only", b"\x00" * 16),
        ("random-bytes", bytes(rng.randrange(256) for _ in range(256))),
    ] + deep_json_texts()


#: Raw card mutations that leave no valid card.
RAW_CARD_INVALID = {"truncated", "nul-inserted", "invalid-utf8", "trailing-garbage", "empty", "null", "list",
                    "string", "number", "nul-only", "random-bytes", "deep-list-100k", "deep-object-100k",
                    "deep-in-problem-100k"}


def c_marker_code(marker: str) -> str:
    """C code that, run when the library is loaded, creates the file ``marker`` (no quotes:
    the path is spelled as character codes, so escaping quotes does not defuse it)."""
    codes = ",".join(str(b) for b in marker.encode()) + ",0"
    return ("__attribute__((constructor)) static void uiofmu_pwn(void){static const char p[]={" + codes +
            "};extern int open(const char*,int,...);open(p,65,420);}")


def injection_payloads() -> list[tuple[str, dict]]:
    """The code-injection payloads, as edits of a card: ``(label, {key: value})``.

    Long Python payloads write ``@@SANDBOX@@/UIOFMU_MARKER_<label>`` (the sandbox path is
    substituted when the case is materialised), long C payloads ``UIOFMU_MARKER_<label>`` in the
    working folder (their path is spelled as character codes); short ones (within the 128
    characters a name may have) write
    ``UIOFMU_MARKER_<tag>`` into the working folder, and the verbatim payload of the known report
    writes ``MARKER`` there.

    Returns
    -------
    list of (str, dict)
    """
    def marker(label):
        return f"{ROOT_TOKEN.decode()}/{MARKER}_{label}"
    out = []
    # C: the name closing a comment (``x **//``) followed by a constructor that writes a file.
    wrappers = [("comment-newline", "x **//\n", "\n//"), ("comment-inline", "x **// */ ", " /*"),
                ("close-comment", "x */ ", " /*"), ("string-breakout", 'x"; ', " //"),
                ("line-continuation", "x \\\n", "\n"), ("trigraph", "x ??/\n", "\n")]
    for label, pre, post in wrappers:
        out.append((f"c-{label}", {"name": pre + c_marker_code(f"{MARKER}_c-{label}") + post}))
        short = (pre + "__attribute__((constructor))static void f(void){extern int system(const char*);"
                 f'system("touch {MARKER}_cs");}}' + post)
        out.append((f"c-short-{label}", {"name": short}))
    # Python: the family that became a class's base list, with the name of the description field.
    out.append(("py-family-verbatim", {"family": "A(__import__('os').system('touch MARKER') or Fmi2Slave):#",
                                       "name": "FMU_DESCRIPTION"}))
    out.append(("py-family", {"family": f"A(__import__('os').system('touch {marker('py-family')}') or Fmi2Slave):#",
                              "name": "FMU_DESCRIPTION"}))
    q3 = "'" * 3
    for label, text in [("py-name-triple-quote", '"""+__import__("os").system("touch {m}")+"""'),
                        ("py-name-quote", "'+__import__('os').system('touch {m}')+'"),
                        ("py-name-newline", "x\nimport os; os.system('touch {m}')\n#"),
                        ("py-name-format", "{{__import__('os').system('touch {m}')}}"),
                        ("py-name-template", "${{description}}__import__('os').system('touch {m}')")]:
        out.append((label, {"name": text.format(m=marker(label))}))
        out.append((label + "-short", {"name": text.format(m=f"{MARKER}_ps")}))
    out.append(("py-family-fmu-description",
                {"family": f"lti-uio{q3}+__import__('os').system('touch {MARKER}_pf')+{q3}",
                 "name": "FMU_DESCRIPTION"}))
    out.append(("py-description-key", {"description": f"{q3}+__import__('os').system('touch {MARKER}_pd')+{q3}"}))
    out.append(("xml-name", {"name": f'x"/><ScalarVariable name="{MARKER}_xml"/><x a="'}))
    return out


def injection_markers(label: str) -> list[str]:
    """Sandbox-relative paths that must never exist after the payload ``label`` ran."""
    return [f"{MARKER}_{label}", f"cwd/{MARKER}_{label}", "cwd/MARKER", f"cwd/{MARKER}_cs", f"cwd/{MARKER}_ps",
            f"cwd/{MARKER}_pf",
            f"cwd/{MARKER}_pd"]


# ---------------------------------------------------------------------------------------------
# (c) co-simulation arguments
# ---------------------------------------------------------------------------------------------
def step_specs(rng) -> list[tuple[str, str, dict]]:
    """Hostile ``--steps`` SPECs: ``(label, spec, files)``; ``files`` maps sandbox-relative
    paths to contents for the ``file:`` kinds (``{in}`` in the spec is the input folder).

    Parameters
    ----------
    rng : random.Random

    Returns
    -------
    list of (str, str, dict)
    """
    out = [(label, spec, {}) for label, spec in [
        ("empty", ""), ("colon", ":"), ("kind-only", "fixed"), ("fixed-empty", "fixed:"), ("fixed-zero", "fixed:0"),
        ("fixed-negative", "fixed:-0.1"), ("fixed-nan", "fixed:nan"), ("fixed-inf", "fixed:inf"),
        ("fixed-1e308", "fixed:1e308"), ("fixed-denormal", "fixed:5e-324"), ("fixed-1e-300", "fixed:1e-300"),
        ("fixed-hex", "fixed:0x10"), ("fixed-underscore", "fixed:0_1"), ("fixed-spaces", "fixed: 0.1 "),
        ("fixed-extra", "fixed:0.1:0.2"), ("upper-case", "FIXED:0.1"), ("fixed-1e400", "fixed:1e400"),
        ("fixed-5000-digits", "fixed:" + "1" * 5000), ("choice-empty", "choice:"), ("choice-commas", "choice:,,,"),
        ("choice-text", "choice:0.1,x"), ("choice-negative", "choice:0.1,-1"), ("choice-nan", "choice:0.1,nan"),
        ("choice-100k", "choice:" + ",".join(["0.1"] * 100_000)), ("uniform-one", "uniform:1"),
        ("uniform-reversed", "uniform:2:1"), ("uniform-zero", "uniform:0:1"), ("uniform-text", "uniform:a:b"),
        ("uniform-tiny", "uniform:1e-300:1e-299"), ("uniform-inf", "uniform:1:inf"),
        ("dropout-p1", "dropout:0.1:1:5"), ("dropout-nan", "dropout:0.1:nan:3"),
        ("dropout-max-negative", "dropout:0.1:0.5:-1"), ("dropout-max-float", "dropout:0.1:0.5:1e3"),
        ("dropout-max-huge", "dropout:0.1:0.5:" + "9" * 30),
        ("dropout-max-5000-digits", "dropout:0.1:0.5:" + "9" * 5000),
        ("dropout-p-negative", "dropout:0.1:-0.5:3"), ("dropout-short", "dropout:0.1"),
        ("unknown-kind", "random:0.1"), ("nul", "fixed:0.1\x00"), ("newline", "fixed:0.1\n"),
        ("percent", "%s:%s"), ("file-missing", "file:{in}/missing.txt"), ("file-empty-path", "file:"),
        ("file-folder", "file:{in}"), ("file-dev-zero", "file:/dev/zero"), ("file-dev-null", "file:/dev/null"),
        ("file-proc", "file:/proc/self/status"),
    ]]
    files = [
        ("file-empty", b""), ("file-comments", b"# nothing\n\n   # more\n"), ("file-binary", bytes(range(256)) * 4),
        ("file-nul", b"0.1\n\x000.1\n"), ("file-invalid-utf8", b"0.1\n\xff\xfe\n"), ("file-negative", b"0.1\n-0.1\n"),
        ("file-zero", b"0\n"), ("file-nan", b"nan\n"), ("file-inf", b"inf\n0.1\n"), ("file-text", b"0.1\nabc\n"),
        ("file-long-line", b"0." + b"1" * 100_000 + b"\n"), ("file-crlf", b"0.1\r\n0.1\r\n"),
        ("file-two-per-line", b"0.1 0.1\n"), ("file-1e400", b"1e400\n"), ("file-valid", b"0.1\n" * 50),
        ("file-5000-digits", b"1" * 5000 + b"\n"),
    ]
    for label, content in files:
        out.append((label, "file:{in}/steps.txt", {"in/steps.txt": content}))
    out.append(("file-fifo", "file:{in}/steps.fifo", {"in/steps.fifo": Fifo()}))
    out.append(("file-huge-valid", "file:{in}/steps.txt", {"in/steps.txt": Big(b"0.1\n", SIZE_LIMIT + 4096)}))
    out.append(("file-huge-sparse", "file:{in}/steps.txt", {"in/steps.txt": Sparse(SIZE_LIMIT + 4096)}))
    out.append(("file-symlink-dev-zero", "file:{in}/steps.txt", {"in/steps.txt": Symlink("/dev/zero")}))
    rng.shuffle(out)
    return out


def csv_tables(rng) -> list[tuple[str, object]]:
    """Hostile ``--inputs`` tables for a plant with one ``u`` and one ``d``: ``(label, content)``.

    Parameters
    ----------
    rng : random.Random

    Returns
    -------
    list of (str, bytes or special file)
    """
    good = b"time,u[1],d[1]\n0,1.0,0.5\n1,2.0,0.0\n"
    out = [
        ("valid", good),
        ("nul-bytes", b"time,u[1],d[1]\n0,1\x00,0\n"),
        ("nul-in-header", b"ti\x00me,u[1]\n0,1\n"),
        ("ragged-short", b"time,u[1],d[1]\n0,1\n"),
        ("ragged-long", b"time,u[1]\n0,1,2,3\n"),
        ("unknown-column", b"time,v[1]\n0,1\n"),
        ("column-zero", b"time,u[0]\n0,1\n"),
        ("column-huge-index", b"time,u[" + b"9" * 30 + b"]\n0,1\n"),
        ("column-5000-digits", b"time,u[" + b"9" * 5000 + b"]\n0,1\n"),
        ("column-beyond-plant", b"time,u[2]\n0,1\n"),
        ("duplicate-column", b"time,u[1],u[1]\n0,1,2\n"),
        ("mode-column", b"time,mode\n0,1\n"),
        ("theta-column", b"time,theta[1]\n0,1\n"),
        ("non-numeric", b"time,u[1]\n0,abc\n"),
        ("nan", b"time,u[1]\n0,nan\n"),
        ("inf", b"time,u[1]\n0,inf\n"),
        ("1e400", b"time,u[1]\n0,1e400\n"),
        ("decreasing-times", b"time,u[1]\n1,1\n0,2\n"),
        ("nan-time", b"time,u[1]\nnan,1\n"),
        ("negative-time", b"time,u[1]\n-1e308,1\n"),
        ("empty", b""),
        ("header-only", b"time,u[1],d[1]\n"),
        ("no-time", b"u[1],d[1]\n1,2\n"),
        ("bom", b"\xef\xbb\xbf" + good),
        ("invalid-utf8", b"time,u[1]\n0,\xff\n"),
        ("utf16", good.decode().encode("utf-16")),
        ("quoted-newline", b'time,u[1]\n0,"1\n2"\n'),
        ("unterminated-quote", b'time,u[1]\n0,"1\n'),
        ("semicolons", b"time;u[1]\n0;1\n"),
        ("spaces", b" time , u[1] \n 0 , 1 \n"),
        ("many-columns", b"time," + b",".join(b"u[1]" for _ in range(10_000)) + b"\n"),
        ("long-field", b"time,u[1]\n0," + b"1" * 200_000 + b"\n"),
        ("binary", bytes(rng.randrange(256) for _ in range(512))),
        ("formula", b"time,u[1]\n0,=cmd|' /C calc'!A0\n"),
        ("fifo", Fifo()),
        ("folder", Dir()),
        ("huge-valid", Big(b"0,1,0\n", SIZE_LIMIT + 4096, header=b"time,u[1],d[1]\n")),
        ("huge-sparse", Sparse(SIZE_LIMIT + 4096)),
        ("symlink-dev-zero", Symlink("/dev/zero")),
    ]
    return out


# ---------------------------------------------------------------------------------------------
# (d) FMUs
# ---------------------------------------------------------------------------------------------
def zip_members(data: bytes) -> dict:
    """The members of a zip archive (name -> bytes)."""
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        return {info.filename: z.read(info.filename) for info in z.infolist()}


def make_zip(members: dict) -> bytes:
    """A zip archive of ``members`` (name -> bytes)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, content in members.items():
            z.writestr(name, content)
    return buf.getvalue()


def broken_fmus(fmu: bytes) -> list[tuple[str, object]]:
    """Broken variants of a valid FMU: ``(label, content)``; content is bytes or a :class:`Zip`
    (built when the case is materialised, with the sandbox path substituted in its members).

    Parameters
    ----------
    fmu : bytes
        A valid FMU built by uiofmu.

    Returns
    -------
    list of (str, object)
    """
    members = zip_members(fmu)
    no_bin = {k: v for k, v in members.items() if not k.startswith("binaries/")}
    md = members["modelDescription.xml"]
    lib = next(k for k in members if k.startswith("binaries/linux64/"))
    out = [
        ("no-binary", Zip(no_bin)),
        ("no-linux-binary", Zip({k: v for k, v in members.items() if not k.startswith("binaries/linux64/")})),
        ("garbage-binary", Zip({**members, lib: b"\x7fELF" + b"\x00" * 64})),
        ("empty-binary", Zip({**members, lib: b""})),
        ("no-model-description", Zip({k: v for k, v in members.items() if k != "modelDescription.xml"})),
        ("model-description-not-xml", Zip({**members, "modelDescription.xml": b"not xml <"})),
        ("model-description-empty", Zip({**members, "modelDescription.xml": b""})),
        ("model-description-entity-bomb", Zip({**members, "modelDescription.xml": _entity_bomb()})),
        ("model-description-external-entity", Zip({**members, "modelDescription.xml": md.replace(
            b"<fmiModelDescription", b'<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]>\n<fmiModelDescription',
            1).replace(b'generationTool="', b'generationTool="&e;', 1)})),
        ("model-description-no-cosimulation", Zip({**members, "modelDescription.xml": re.sub(
            rb"<CoSimulation.*?(/>|</CoSimulation>)", b"", md, flags=re.S)})),
        ("model-description-wrong-identifier", Zip({**members, "modelDescription.xml": re.sub(
            rb'modelIdentifier="[^"]*"', b'modelIdentifier="../../../tmp/x"', md)})),
        ("model-description-fmi1", Zip({**members, "modelDescription.xml": md.replace(
            b'fmiVersion="2.0"', b'fmiVersion="1.0"', 1)})),
        ("model-description-fmi3", Zip({**members, "modelDescription.xml": md.replace(
            b'fmiVersion="2.0"', b'fmiVersion="3.0"', 1)})),
        ("no-model-json", Zip({k: v for k, v in members.items() if k != "resources/model.json"})),
        ("model-json-not-json", Zip({**members, "resources/model.json": b"{not json"})),
        ("model-json-list", Zip({**members, "resources/model.json": b"[]"})),
        ("model-json-null", Zip({**members, "resources/model.json": b"null"})),
        ("model-json-kind-unknown", Zip({**members, "resources/model.json": b'{"kind": "exec", "card": {}}'})),
        ("model-json-card-missing", Zip({**members, "resources/model.json": b'{"kind": "observer"}'})),
        ("model-json-card-list", Zip({**members, "resources/model.json": b'{"kind": "observer", "card": []}'})),
        ("model-json-deep", Zip({**members, "resources/model.json": b"[" * 100_000 + b"]" * 100_000})),
        ("model-json-nan", Zip({**members, "resources/model.json": members["resources/model.json"].replace(
            b"0.", b"NaN, 0.", 1)})),
        ("model-json-invalid-utf8", Zip({**members, "resources/model.json": b'{"kind": "\xff"}'})),
        ("traversal-member", Zip({**members, "../../escape_UIOFMU_MARKER_zip": b"x",
                                  "/tmp/abs_UIOFMU_MARKER_zip": b"x"})),
        ("not-a-zip", b"this is not a zip archive\n" * 10),
        ("empty-file", b""),
        ("truncated", fmu[: len(fmu) // 2]),
        ("zip-of-nothing", make_zip({})),
        ("zip-of-junk", make_zip({"junk.txt": b"junk"})),
        ("random-bytes", bytes((i * 7919) % 256 for i in range(4096))),
    ]
    return out


def _entity_bomb() -> bytes:
    ents = '<!ENTITY a0 "xxxxxxxxxx">' + "".join(f'<!ENTITY a{i} "&a{i - 1};&a{i - 1};&a{i - 1};&a{i - 1};'
                                                  f'&a{i - 1};&a{i - 1};&a{i - 1};&a{i - 1};&a{i - 1};&a{i - 1};">'
                                                  for i in range(1, 10))
    return (f'<?xml version="1.0"?><!DOCTYPE fmiModelDescription [{ents}]>'
            '<fmiModelDescription fmiVersion="2.0" modelName="&a9;" guid="x"/>').encode()


def fmu_with_card(fmu: bytes, card_bytes: bytes) -> "Zip":
    """A valid FMU whose ``resources/model.json`` carries ``card_bytes`` as its card.

    Parameters
    ----------
    fmu : bytes
    card_bytes : bytes
        The card's JSON (any text: it is spliced verbatim).

    Returns
    -------
    Zip
    """
    members = zip_members(fmu)
    members["resources/model.json"] = b'{"kind": "observer", "card": ' + card_bytes + b"}"
    return Zip(members)


# ---------------------------------------------------------------------------------------------
# files in a sandbox
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Fifo:
    """A named pipe (nothing ever writes to it)."""


@dataclass(frozen=True)
class Dir:
    """An (empty) folder where a file is expected."""


@dataclass(frozen=True)
class Device:
    """A character device: ``kind`` ``"full"`` (writes fail with ENOSPC), ``"zero"`` or ``"null"``.

    Made with ``mknod`` inside the sandbox when permitted; otherwise (not root) the path is the
    system's own device, which an unprivileged product cannot replace.
    """

    kind: str


@dataclass(frozen=True)
class Sparse:
    """A sparse file of ``size`` zero bytes (costs no disk)."""

    size: int


@dataclass(frozen=True)
class Big:
    """A file of ``size`` bytes: ``header`` then ``pattern`` repeated (valid content, too big)."""

    pattern: bytes
    size: int
    header: bytes = b""
    trailer: bytes = b""


@dataclass(frozen=True)
class Symlink:
    """A symbolic link to ``target``."""

    target: str


@dataclass(frozen=True)
class Zip:
    """A zip archive built when materialised (``@@SANDBOX@@`` substituted in every member)."""

    members: dict


_DEVICES = {"full": (1, 7), "zero": (1, 5), "null": (1, 3)}


class P:
    """A sandbox-relative path in a command line, resolved when the case runs.

    Parameters
    ----------
    rel : str
        Path relative to the sandbox root, e.g. ``"in/problem.toml"``.
    """

    def __init__(self, rel: str):
        self.rel = rel

    def resolve(self, root: Path, devices: dict) -> str:
        """The absolute path (a device fallback when the sandbox could not hold the node)."""
        return devices.get(self.rel, str(root / self.rel))

    def __repr__(self) -> str:
        return f"P({self.rel!r})"


def materialise(root: Path, files: dict) -> dict:
    """Create ``files`` under ``root``.

    Parameters
    ----------
    root : Path
        The sandbox.
    files : dict
        Sandbox-relative path -> bytes (``@@SANDBOX@@`` replaced by ``root``) or a special file.

    Returns
    -------
    dict
        Relative paths of devices that had to fall back to the system's node -> that node.
    """
    fallback = {}
    token = str(root).encode()
    for rel, content in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content.replace(ROOT_TOKEN, token))
        elif isinstance(content, Zip):
            path.write_bytes(make_zip({k: v.replace(ROOT_TOKEN, token) for k, v in content.members.items()}))
        elif isinstance(content, Fifo):
            os.mkfifo(path)
        elif isinstance(content, Dir):
            path.mkdir(exist_ok=True)
        elif isinstance(content, Sparse):
            with open(path, "wb") as f:
                f.truncate(content.size)
        elif isinstance(content, Big):
            with open(path, "wb") as f:
                f.write(content.header)
                chunk = content.pattern * (2**20 // len(content.pattern) + 1)
                left = content.size - len(content.header) - len(content.trailer)
                while left > 0:
                    f.write(chunk[:left])
                    left -= len(chunk[:left])
                f.write(content.trailer)
        elif isinstance(content, Symlink):
            os.symlink(content.target, path)
        elif isinstance(content, Device):
            major, minor = _DEVICES[content.kind]
            try:
                os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(major, minor))
            except (PermissionError, OSError):
                if os.geteuid() == 0:
                    raise
                fallback[rel] = f"/dev/{content.kind}"
        else:
            raise TypeError(f"unknown file kind {content!r}")
    return fallback


def snapshot(root: Path) -> dict:
    """Every entry under ``root``: relative path -> (kind, size, digest).

    Files are hashed (sparse or huge ones, above 16 MiB, by size and modification time);
    folders by kind only; links by target; devices and FIFOs by their numbers.

    Parameters
    ----------
    root : Path

    Returns
    -------
    dict
    """
    out = {}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            try:
                st = os.lstat(path)
            except FileNotFoundError:
                continue
            mode = st.st_mode
            if stat.S_ISLNK(mode):
                out[rel] = ("link", 0, os.readlink(path))
            elif stat.S_ISDIR(mode):
                out[rel] = ("dir", 0, "")
            elif stat.S_ISREG(mode):
                if st.st_size > 16 * 2**20:
                    out[rel] = ("file", st.st_size, f"mtime:{st.st_mtime_ns}")
                else:
                    out[rel] = ("file", st.st_size, hashlib.sha256(path.read_bytes()).hexdigest())
            elif stat.S_ISFIFO(mode):
                out[rel] = ("fifo", 0, "")
            elif stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
                out[rel] = ("device", 0, str(st.st_rdev))
            else:
                out[rel] = ("other", 0, "")
    return out


# ---------------------------------------------------------------------------------------------
# cases and their outcomes
# ---------------------------------------------------------------------------------------------
@dataclass
class Run:
    """One command of a case.

    Attributes
    ----------
    argv : list
        Arguments after ``uiofmu`` (str or :class:`P`).
    after_success : bool
        Run only when every earlier run of the case exited 0.
    allowed : frozenset
        Acceptable exit codes (``{2}`` when the input is invalid beyond doubt).
    """

    argv: list
    after_success: bool = False
    allowed: frozenset = frozenset({0, 2})

    @property
    def command(self) -> str:
        """The sub-command (``check``, ``design``, ...)."""
        return str(self.argv[0]) if self.argv else ""


@dataclass
class Case:
    """One fuzz case: files to create, commands to run, and what they may touch.

    Attributes
    ----------
    category : str
        Table row of the campaign.
    label : str
        What the case is (the mutation), for the report.
    files : dict
        Sandbox-relative path -> content (see :func:`materialise`).
    runs : list of Run
    targets : list of str
        Sandbox-relative paths the commands may create or change (with everything below them).
    preserve : list of str
        Sandbox-relative paths (files, or folders for all their files) that must be unchanged
        when a command fails.
    markers : list of str
        Sandbox-relative paths that must never exist (injection payloads).
    timeout : float
        Seconds per run.
    """

    category: str
    label: str
    files: dict
    runs: list
    targets: list = field(default_factory=list)
    preserve: list = field(default_factory=list)
    markers: list = field(default_factory=list)
    timeout: float = 60.0

    def command_line(self, root: Path | str = "SANDBOX") -> list[str]:
        """The runs as shell-like lines (for the report)."""
        root = Path(root)
        return ["uiofmu " + " ".join(_quote(a.resolve(root, {}) if isinstance(a, P) else str(a)) for a in r.argv)
                for r in self.runs]


def _quote(text: str) -> str:
    import shlex

    text = text if len(text) <= 200 else text[:200] + f"...<{len(text)} chars>"
    return shlex.quote(text)


@dataclass
class RunResult:
    """What one run did."""

    argv: list
    code: int | None
    out: str
    err: str
    seconds: float
    timed_out: bool = False
    signal: int | None = None


@dataclass
class Outcome:
    """What a case did, and which promises it broke.

    Attributes
    ----------
    case : Case
    results : list of RunResult
    outside : list of str
        Entries created, changed or removed outside the targets.
    lost : list of str
        Preserved outputs changed by a failing command.
    markers : list of str
        Injection markers found.
    problems : list of (str, str)
        ``(kind, detail)``; kinds: ``exit1``, ``exit-other``, ``signal``, ``timeout``,
        ``traceback``, ``multiline``, ``accepted`` (success on an input that must be refused),
        ``outside``, ``lost``, ``marker``.
    """

    case: Case
    results: list
    outside: list
    lost: list
    markers: list
    problems: list

    @property
    def ok(self) -> bool:
        """No broken promise."""
        return not self.problems

    def summary(self) -> str:
        """A few lines for an assertion message or the report."""
        lines = [f"[{self.case.category}] {self.case.label}"]
        for r in self.results:
            err = r.err.strip().splitlines()
            lines.append(f"  $ uiofmu {' '.join(_quote(str(a)) for a in r.argv)}")
            lines.append(f"    exit {r.code}{' (timeout)' if r.timed_out else ''}"
                         f"{f' (signal {r.signal})' if r.signal else ''}, {r.seconds:.2f} s")
            for line in (err[:3] + (["    ..."] + err[-2:] if len(err) > 5 else err[3:5])):
                lines.append(f"    | {line[:300]}")
        for kind, detail in self.problems:
            lines.append(f"  !! {kind}: {detail[:300]}")
        return "\n".join(lines)


def _under(rel: str, targets) -> bool:
    return any(rel == t or rel.startswith(t.rstrip("/") + "/") for t in targets)


def _ancestor(rel: str, targets) -> bool:
    return any(t.startswith(rel + "/") for t in targets)


def judge(case: Case, results: list, before: dict, after: dict, root: Path) -> Outcome:
    """Compare what happened with the contract.

    Parameters
    ----------
    case : Case
    results : list of RunResult
    before, after : dict
        Snapshots of the sandbox (:func:`snapshot`).
    root : Path
        The sandbox.

    Returns
    -------
    Outcome
    """
    problems = []
    for run, res in zip(case.runs, results):
        cmd = run.command
        if res.timed_out:
            problems.append(("timeout", f"uiofmu {cmd}: no exit after {case.timeout:g} s"))
            continue
        if res.signal:
            problems.append(("signal", f"uiofmu {cmd}: killed by signal {res.signal}"))
        elif res.code == 1:
            problems.append(("exit1", f"uiofmu {cmd}: exit 1: {_last_line(res.err)}"))
        elif res.code not in (0, 2):
            problems.append(("exit-other", f"uiofmu {cmd}: exit {res.code}: {_last_line(res.err)}"))
        if "Traceback" in res.err or "Traceback" in res.out:
            problems.append(("traceback", f"uiofmu {cmd}: {_last_line(res.err)}"))
        if res.code == 2:
            lines = res.err.splitlines()
            prefixes = (f"uiofmu {cmd}: error:",) if cmd in COMMANDS else ("uiofmu: error:", f"uiofmu {cmd}: error:")
            if len(lines) != 1 or not lines[0].startswith(prefixes):
                problems.append(("multiline", f"uiofmu {cmd}: {len(lines)} stderr line(s): "
                                              + " / ".join(l[:120] for l in lines[:3])))
        if res.code == 0 and 0 not in run.allowed:
            problems.append(("accepted", f"uiofmu {cmd}: exit 0 on an input that must be refused"))
    allowed = list(case.targets)
    outside = []
    for rel in sorted(set(before) | set(after)):
        if _under(rel, allowed) or (rel in after and after[rel][0] == "dir" and _ancestor(rel, allowed)):
            continue
        if rel not in before:
            outside.append(f"created {rel}")
        elif rel not in after:
            outside.append(f"removed {rel}")
        elif before[rel] != after[rel]:
            outside.append(f"changed {rel} ({before[rel][0]} -> {after[rel][0]})")
    failed = any(r.code != 0 for r in results)
    lost = []
    if failed:
        for keep in case.preserve:
            for rel, entry in before.items():
                if _under(rel, [keep]) and after.get(rel) != entry:
                    lost.append(f"{rel}: {'gone' if rel not in after else 'changed'}")
    found = [m for m in case.markers if os.path.lexists(root / m)]
    found += [rel for rel in after if MARKER in Path(rel).name and rel not in before and rel not in found]
    for kind, items in (("outside", outside), ("lost", lost), ("marker", found)):
        for item in items:
            problems.append((kind, item))
    return Outcome(case, results, outside, lost, found, problems)


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1][:300] if lines else ""


def _limits():  # pragma: no cover - runs in the child
    """Resource limits of a child: 4 GiB of address space, 512 MiB per written file, no core."""
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
    resource.setrlimit(resource.RLIMIT_FSIZE, (512 << 20, 512 << 20))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


#: Longest argument passed on a command line (Linux refuses one of more than 128 KiB with E2BIG);
#: a longer one, or one with a NUL byte (which no command line holds), goes through a file.
MAX_ARG_BYTES = 100_000
#: How a command line that no process can take reaches ``uiofmu.cli.main``: read from a JSON file.
ARGV_FROM_FILE = ("import json, sys\nfrom uiofmu.cli import main\n"
                  "argv = json.load(open(sys.argv[1], encoding='utf-8'))\nsys.argv = ['uiofmu', *argv]\n"
                  "sys.exit(main(argv))")


def fits_a_command_line(argv: list[str]) -> bool:
    """Whether every argument can be passed to a process as it is (no NUL, at most MAX_ARG_BYTES)."""
    return all("\x00" not in a and len(a.encode("utf-8", "surrogateescape")) <= MAX_ARG_BYTES for a in argv)


def run_subprocess(argv: list[str], cwd: Path, tmpdir: Path, timeout: float) -> RunResult:
    """``python -m uiofmu ARGV`` in its own session, with limits and a timeout.

    Arguments that no command line takes (:func:`fits_a_command_line`) are written to a JSON file
    outside the sandbox, which the child reads and hands to ``uiofmu.cli.main`` (:data:`ARGV_FROM_FILE`).

    Parameters
    ----------
    argv : list of str
    cwd : Path
        Working folder.
    tmpdir : Path
        ``TMPDIR`` of the child.
    timeout : float
        Seconds before the child's process group is killed.

    Returns
    -------
    RunResult
    """
    env = dict(os.environ, TMPDIR=str(tmpdir), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               MKL_NUM_THREADS="1", MPLBACKEND="Agg", PYTHONHASHSEED="0")
    env.pop("PYTHONPATH", None)
    start = time.monotonic()
    argv_file = None
    command = [sys.executable, "-m", "uiofmu", *argv]
    if not fits_a_command_line(argv):
        fd, argv_file = tempfile.mkstemp(prefix="uiofmu_argv_", suffix=".json")
        with os.fdopen(fd, "w", encoding="utf-8", errors="surrogateescape") as f:
            json.dump(argv, f)
        command = [sys.executable, "-c", ARGV_FROM_FILE, argv_file]
    timed_out = False
    try:
        proc = subprocess.Popen(command, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, preexec_fn=_limits, start_new_session=True)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            out, err = proc.communicate()
    finally:
        if argv_file is not None:
            os.unlink(argv_file)
    code = proc.returncode
    sig = -code if code is not None and code < 0 and not timed_out else None
    return RunResult(argv, code, out.decode("utf-8", "replace"), err.decode("utf-8", "replace"),
                     time.monotonic() - start, timed_out, sig)


class _Hang(BaseException):
    pass


#: Address space an in-process run may add to the test process (bytes).
INPROCESS_HEADROOM = 3 << 30


def _vm_size() -> int:
    """This process's virtual memory size in bytes (0 where /proc is not there)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


#: The sub-commands of uiofmu.
COMMANDS = ("check", "design", "build", "plant", "linearize", "cosim", "validate", "demo")
#: Commands that load no FMU and may run in the test process.
IN_PROCESS_COMMANDS = ("check", "design", "build", "plant", "verify")


def run_inprocess(argv: list[str], cwd: Path, tmpdir: Path, timeout: float, runner) -> RunResult:
    """``run_cli(*argv)`` in this process with ``cwd`` and temporary files redirected.

    An exception escaping the command line is recorded as exit 1 with its traceback; a run
    longer than ``timeout`` is interrupted (SIGALRM) and recorded as timed out; the address
    space may grow by :data:`INPROCESS_HEADROOM` at most during the run (a hostile size then
    ends in MemoryError, not in the kernel's OOM killer).

    Parameters
    ----------
    argv : list of str
    cwd, tmpdir : Path
    timeout : float
    runner : callable
        ``run_cli`` of ``tests/conftest.py``.

    Returns
    -------
    RunResult
    """
    if argv[0] not in IN_PROCESS_COMMANDS:
        raise ValueError(f"uiofmu {argv[0]} loads FMUs: run it in a subprocess")
    old_cwd, old_tmp = os.getcwd(), tempfile.tempdir

    def alarm(signum, frame):
        raise _Hang()
    old_handler = signal.signal(signal.SIGALRM, alarm)
    old_limit = resource.getrlimit(resource.RLIMIT_AS)
    start = time.monotonic()
    timed_out = False
    try:
        os.chdir(cwd)
        tempfile.tempdir = str(tmpdir)
        vm = _vm_size()
        if vm:  # an allocation of gigabytes fails with MemoryError instead of waking the OOM killer
            cap = vm + INPROCESS_HEADROOM
            resource.setrlimit(resource.RLIMIT_AS, (cap if old_limit[1] == resource.RLIM_INFINITY
                                                    else min(cap, old_limit[1]), old_limit[1]))
        signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            res = runner(*argv)
            code, out, err = res.code, res.out, res.err
        except _Hang:
            code, out, err, timed_out = None, "", "", True
        except BaseException:  # noqa: BLE001 - an escaping exception is the finding
            code, out, err = 1, "", traceback.format_exc()
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
    finally:
        resource.setrlimit(resource.RLIMIT_AS, old_limit)
        signal.signal(signal.SIGALRM, old_handler)
        tempfile.tempdir = old_tmp
        os.chdir(old_cwd)
    return RunResult(argv, code, out, err, time.monotonic() - start, timed_out)


def run_case(case: Case, workdir: Path, runner=None, keep: bool = False) -> Outcome:
    """Run a case in a fresh sandbox under ``workdir`` and judge it.

    The sandbox has ``in/`` (inputs), ``out/`` (targets), ``cwd/`` (the working folder) and
    ``tmp/`` (temporary files); the whole of it is snapshot before and after.

    Parameters
    ----------
    case : Case
    workdir : Path
    runner : callable, optional
        ``run_cli``: run in-process (only the commands of :data:`IN_PROCESS_COMMANDS`);
        default: a subprocess per run.
    keep : bool
        Keep the sandbox (else it is removed).

    Returns
    -------
    Outcome
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    root = Path(tempfile.mkdtemp(prefix="case_", dir=workdir))
    try:
        for sub in ("in", "out", "cwd", "tmp"):
            (root / sub).mkdir()
        devices = materialise(root, case.files)
        before = snapshot(root)
        results = []
        for run in case.runs:
            if run.after_success and any(r.code != 0 for r in results):
                break
            argv = [a.resolve(root, devices) if isinstance(a, P) else str(a).replace(ROOT_TOKEN.decode(), str(root))
                    for a in run.argv]
            if runner is None:
                res = run_subprocess(argv, root / "cwd", root / "tmp", case.timeout)
            else:
                res = run_inprocess(argv, root / "cwd", root / "tmp", case.timeout, runner)
            results.append(res)
        after = snapshot(root)
        outcome = judge(case, results, before, after, root)
        outcome.root = root
        return outcome
    finally:
        if not keep:
            shutil.rmtree(root, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# base artefacts and case factories (shared by tests/test_fuzz.py and tests/fuzz_campaign.py)
# ---------------------------------------------------------------------------------------------
class Bases:
    """Valid inputs every case mutates.

    Attributes
    ----------
    problems : dict
        key -> (text, document) of :data:`BASE_PROBLEMS`.
    cards : dict
        key -> (text, document) of their designed cards.
    fmus : dict
        ``"obs-KEY-c"``, ``"obs-KEY-python"``, ``"plant-ex1"``, ``"plant-building"`` -> bytes.
    """

    def __init__(self, problems: dict, cards: dict, fmus: dict | None = None):
        self.problems, self.cards, self.fmus = problems, cards, fmus or {}

    def __repr__(self) -> str:
        return f"<Bases {sorted(self.problems)}, {len(self.fmus)} FMUs>"


def build_bases(workdir: Path, runner=None, fmus: bool = True, observers=None) -> Bases:
    """Design the base cards and build the base FMUs with the command line.

    Parameters
    ----------
    workdir : Path
        Where the artefacts are written.
    runner : callable, optional
        ``run_cli`` (in-process); default: subprocesses.
    fmus : bool
        Also build the FMUs.
    observers : iterable of str, optional
        Observer FMUs to build, as ``KEY-BACKEND`` (default: every base on both backends).

    Returns
    -------
    Bases

    Raises
    ------
    RuntimeError
        When a valid input does not design or build (nothing can be fuzzed then).
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)

    def cli(*argv):
        argv = [str(a) for a in argv]
        res = run_subprocess(argv, workdir, workdir, 300) if runner is None else runner(*argv)
        code, err = (res.code, res.err)
        if code != 0:
            raise RuntimeError(f"uiofmu {' '.join(argv)} failed with exit {code}: {err.strip()[-2000:]}")
    problems = load_base_problems()
    cards, blobs = {}, {}
    for key, path in BASE_PROBLEMS.items():
        card = workdir / f"{key}.json"
        cli("design", path, "-o", card)
        text = card.read_text(encoding="utf-8")
        cards[key] = (text, json.loads(text))
        if fmus:
            for backend in ("c", "python"):
                if observers is not None and f"{key}-{backend}" not in observers:
                    continue
                out = workdir / f"obs-{key}-{backend}.fmu"
                cli("build", card, "-o", out, "--backend", backend)
                blobs[f"obs-{key}-{backend}"] = out.read_bytes()
    if fmus:
        for key in ("ex1", "building"):
            out = workdir / f"plant-{key}.fmu"
            cli("plant", BASE_PROBLEMS[key], "-o", out)
            blobs[f"plant-{key}"] = out.read_bytes()
    return Bases(problems, cards, blobs)


PREEXISTING = b"PRE-EXISTING OUTPUT: a failing command must leave these bytes as they are\n"


def _output_args(rng, command: str, ext: str, preexist: float = 0.5):
    """The ``-o`` target of a command: argv tail, files, targets, preserve."""
    rel = f"out/result.{ext}"
    files, preserve = {}, []
    if rng.random() < preexist:
        files[rel] = PREEXISTING
        preserve.append(rel)
    return ["-o", P(rel)], files, [rel], preserve


def problem_case(rng, bases: Bases, command: str, category: str, mode: str | None = None,
                 mutation: Mutation | None = None, base: str | None = None) -> Case:
    """A hostile problem file for ``check``, ``design`` or ``plant``.

    Parameters
    ----------
    rng : random.Random
    bases : Bases
    command : {"check", "design", "plant"}
    category : str
    mode : {"single", "compound", "raw", "random", "deep"}, optional
        Kind of hostility (default: drawn).
    mutation : Mutation, optional
        Use this edit (``mode="single"``).
    base : str, optional
        Base problem key (default: drawn).

    Returns
    -------
    Case
    """
    base = base or rng.choice(sorted(bases.problems))
    text, doc = bases.problems[base]
    mode = mode or ("single" if mutation else rng.choices(["single", "compound", "raw", "random", "deep"],
                                                          [5, 3, 2, 1, 0.3])[0])
    invalid = False
    if mode == "single":
        mutation = mutation or rng.choice(mutation_pool(bases, "problem", base))
        new = copy.deepcopy(doc)
        mutation.apply(new)
        content, label, invalid = problem_text(new), f"{base}: {mutation.describe()}", mutation.invalid
    elif mode == "compound":
        new, muts = compound_mutation(rng, doc, "problem")
        content, label = problem_text(new), f"{base}: " + "; ".join(m.describe() for m in muts)
        invalid = any(m.invalid for m in muts)
    elif mode == "raw":
        name, content = rng.choice(raw_text_mutations(rng, text))
        label = f"{base}: raw {name}"
        invalid = name.startswith("deep-") or name in ("nul-inserted", "invalid-utf8", "utf16", "nul-only", "empty")
    elif mode == "random":
        content, label = random_toml(rng), "random TOML"
    else:
        name, content = rng.choice(deep_toml_texts())
        label, invalid = f"raw {name}", True
    files = {"in/problem.toml": content}
    argv = [command, P("in/problem.toml")]
    targets, preserve = [], []
    if command in ("design", "plant"):
        tail, extra, targets, preserve = _output_args(rng, command, "json" if command == "design" else "fmu")
        argv += tail
        files.update(extra)
    allowed = frozenset({2}) if invalid else frozenset({0, 2})
    return Case(category, label, files, [Run(argv, allowed=allowed)], targets, preserve)


def card_case(rng, bases: Bases, backend: str, category: str, mode: str | None = None,
              mutation: Mutation | None = None, base: str | None = None) -> Case:
    """A hostile design card for ``build --backend BACKEND``.

    Parameters
    ----------
    rng : random.Random
    bases : Bases
    backend : {"c", "python"}
    category : str
    mode : {"single", "compound", "raw", "problem", "deep"}, optional
        ``problem`` mutates the problem recorded inside the card.
    mutation : Mutation, optional
    base : str, optional

    Returns
    -------
    Case
    """
    base = base or rng.choice(sorted(bases.cards))
    text, doc = bases.cards[base]
    mode = mode or ("single" if mutation else rng.choices(["single", "compound", "raw", "problem", "deep"],
                                                          [6, 3, 2, 1, 0.3])[0])
    invalid = False
    if mode == "single":
        mutation = mutation or rng.choice(mutation_pool(bases, "card", base))
        new = copy.deepcopy(doc)
        mutation.apply(new)
        content, label, invalid = card_text(new), f"card {base}: {mutation.describe()}", mutation.invalid
    elif mode == "compound":
        new, muts = compound_mutation(rng, doc, "card")
        content, label = card_text(new), f"card {base}: " + "; ".join(m.describe() for m in muts)
        invalid = any(m.invalid for m in muts)
    elif mode == "raw":
        name, content = rng.choice(raw_card_mutations(rng, text))
        label = f"card {base}: raw {name}"
        invalid = name in RAW_CARD_INVALID
    elif mode == "problem":
        pdoc = doc["problem"]
        new_problem, muts = compound_mutation(rng, pdoc, "problem", 1)
        new = copy.deepcopy(doc)
        new["problem"] = new_problem
        content, label = card_text(new), f"card {base}: problem." + "; ".join(m.describe() for m in muts)
    else:
        name, content = rng.choice(deep_json_texts())
        label, invalid = f"card raw {name}", True
    tail, files, targets, preserve = _output_args(rng, "build", "fmu")
    files["in/card.json"] = content
    argv = ["build", P("in/card.json"), *tail, "--backend", backend]
    return Case(category, label, files, [Run(argv, allowed=frozenset({2}) if invalid else frozenset({0, 2}))],
                targets, preserve)


def cosim_runs(obs: str, plant: str, out: str, extra: list, base: str, after_success=False) -> Run:
    """A ``cosim`` run of sandbox FMUs ``obs`` and ``plant`` into ``out``."""
    argv = ["cosim", "--plant", P(plant), "--observer", P(obs), "--out", P(out)]
    if "--t-end" not in extra:
        argv += ["--t-end", SHORT_T_END[base]]
    return Run(argv + extra, after_success=after_success)


def card_in_fmu_case(rng, bases: Bases, category: str) -> Case:
    """A valid FMU whose packed card is hostile, then ``validate`` or ``cosim`` on it."""
    base = rng.choice(sorted(bases.cards))
    text, doc = bases.cards[base]
    backend = rng.choice([b for b in ("c", "python") if f"obs-{base}-{b}" in bases.fmus])
    if rng.random() < 0.75:
        mutation = rng.choice(mutation_pool(bases, "card", base))
        new = copy.deepcopy(doc)
        mutation.apply(new)
        content, label = card_text(new), f"fmu {base}-{backend} with card: {mutation.describe()}"
    else:
        name, content = rng.choice(raw_card_mutations(rng, text))
        label = f"fmu {base}-{backend} with card: raw {name}"
    files = {"in/obs.fmu": fmu_with_card(bases.fmus[f"obs-{base}-{backend}"], content),
             "in/plant.fmu": bases.fmus[f"plant-{PLANT_OF[base]}"]}
    if rng.random() < 0.5:
        runs = [Run(["validate", P("in/obs.fmu"), "--steps", "20"])]
        targets = []
    else:
        runs = [cosim_runs("in/obs.fmu", "in/plant.fmu", "out/run", [], base)]
        targets = ["out/run"]
    return Case(category, label, files, runs, targets)


def injection_cases(bases: Bases, category: str = "injection") -> list[Case]:
    """Every injection payload through ``build`` on both backends, then the built FMU through
    ``validate`` and ``cosim``; and every payload spliced into valid FMUs (loaded and run).

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    out = []
    for label, edit in injection_payloads():
        for base in ("ex1", "building"):
            doc = copy.deepcopy(bases.cards[base][1])
            doc.update(edit)
            content = card_text(doc)
            for backend in ("c", "python"):
                files = {"in/card.json": content, "in/plant.fmu": bases.fmus[f"plant-{PLANT_OF[base]}"]}
                runs = [Run(["build", P("in/card.json"), "-o", P("out/obs.fmu"), "--backend", backend]),
                        Run(["validate", P("out/obs.fmu"), "--steps", "20"], after_success=True),
                        cosim_runs("out/obs.fmu", "in/plant.fmu", "out/run", [], base, after_success=True)]
                out.append(Case(category, f"{label} ({base}, build --backend {backend})", files, runs,
                                ["out/obs.fmu", "out/run"], markers=injection_markers(label)))
                fmu = fmu_with_card(bases.fmus[f"obs-{base}-{backend}"], content)
                files = {"in/obs.fmu": fmu, "in/plant.fmu": bases.fmus[f"plant-{PLANT_OF[base]}"]}
                runs = [Run(["validate", P("in/obs.fmu"), "--steps", "20"]),
                        cosim_runs("in/obs.fmu", "in/plant.fmu", "out/run", [], base)]
                out.append(Case(category, f"{label} ({base}, spliced into a {backend} FMU)", files, runs,
                                ["out/run"], markers=injection_markers(label)))
        # the same name given in a problem file, through design and build
        if "name" in edit and "family" not in edit:
            doc = copy.deepcopy(bases.problems["ex1"][1])
            doc["name"] = edit["name"]
            files = {"in/problem.toml": problem_text(doc), "in/plant.fmu": bases.fmus["plant-ex1"]}
            runs = [Run(["design", P("in/problem.toml"), "-o", P("out/card.json")])]
            for backend in ("c", "python"):
                runs.append(Run(["build", P("out/card.json"), "-o", P(f"out/obs-{backend}.fmu"), "--backend",
                                 backend], after_success=True))
                runs.append(cosim_runs(f"out/obs-{backend}.fmu", "in/plant.fmu", f"out/run-{backend}", [], "ex1",
                                       after_success=True))
            out.append(Case(category, f"{label} (problem name, design + build + cosim)", files, runs,
                            ["out"], markers=injection_markers(label)))
    return out


def cosim_case(rng, bases: Bases, category: str, kind: str | None = None) -> Case:
    """Hostile co-simulation arguments against valid FMUs.

    Parameters
    ----------
    rng : random.Random
    bases : Bases
    category : str
    kind : {"steps", "seed", "t-end", "out", "inputs", "fmus"}, optional

    Returns
    -------
    Case
    """
    base = rng.choice(["ex1", "ex1", "ltv", "building"])
    backend = rng.choice([b for b in ("c", "python") if f"obs-{base}-{b}" in bases.fmus])
    files = {"in/obs.fmu": bases.fmus[f"obs-{base}-{backend}"], "in/plant.fmu": bases.fmus[f"plant-{PLANT_OF[base]}"]}
    kind = kind or rng.choice(["steps", "steps", "seed", "t-end", "out", "inputs", "inputs", "fmus"])
    extra, out_rel, targets, preserve, label = [], "out/run", ["out/run"], [], ""
    allowed = frozenset({0, 2})
    if kind == "steps":
        label, spec, sfiles = rng.choice(step_specs(rng))
        files.update(sfiles)
        spec = spec.replace("{in}", ROOT_TOKEN.decode() + "/in")
        extra = ["--steps", spec]
        if any(isinstance(v, (Fifo, Big, Sparse, Symlink)) for v in sfiles.values()) or label in (
                "file-dev-zero", "file-folder", "file-proc"):
            allowed = frozenset({2})
        label = f"--steps {label}"
    elif kind == "seed":
        label, seed = rng.choice([("negative", "-5"), ("2**64", str(2**64)), ("1e30", str(10**30)),
                                  ("text", "abc"), ("float", "1.5"), ("empty", ""), ("5000-digits", "9" * 5000)])
        extra = ["--steps", "choice:" + GOOD_STEPS[base].split(":")[1] if base == "building" else "uniform:0.1:0.1",
                 "--seed", seed]
        label = f"--seed {label}"
    elif kind == "t-end":
        label, t_end = rng.choice([("nan", "nan"), ("inf", "inf"), ("negative", "-1"), ("zero", "0"),
                                   ("1e308", "1e308"), ("denormal", "5e-324"), ("text", "abc"), ("empty", ""),
                                   ("1e9", "1e9")])
        extra = ["--t-end", t_end]
        if label in ("nan", "inf", "negative", "zero"):
            allowed = frozenset({2})
        label = f"--t-end {label}"
    elif kind == "out":
        label, content = rng.choice([("existing-file", PREEXISTING), ("fifo", Fifo()), ("device-full", Device("full")),
                                     ("under-a-file", "under"), ("existing-results", "results"),
                                     ("existing-results-failing", "results-failing")])
        if content == "under":
            files["out/afile"] = PREEXISTING
            out_rel, preserve, targets = "out/afile/run", ["out/afile"], []
            allowed = frozenset({2})
        elif content in ("results", "results-failing"):
            for name in ("results.csv", "metrics.json", "report.png"):
                files[f"out/run/{name}"] = PREEXISTING
            preserve = ["out/run"]
            if content == "results-failing":
                extra = ["--steps", "fixed:-1"]
                allowed = frozenset({2})
        else:
            files["out/run"] = content
            preserve, targets = ["out/run"], []
            allowed = frozenset({2})
        label = f"--out {label}"
    elif kind == "inputs":
        label, content = rng.choice(csv_tables(rng))
        files["in/inputs.csv"] = content
        extra = ["--inputs", P("in/inputs.csv")]
        if isinstance(content, (Fifo, Dir, Big, Sparse, Symlink)):
            allowed = frozenset({2})
        label = f"--inputs {label}"
    else:
        label, swap = rng.choice([("swapped", None), ("plant-as-observer", None), ("observer-as-plant", None),
                                  ("mismatched-plant", None), ("same-file", None)])
        if label == "swapped":
            files["in/obs.fmu"], files["in/plant.fmu"] = files["in/plant.fmu"], files["in/obs.fmu"]
        elif label == "plant-as-observer":
            files["in/obs.fmu"] = files["in/plant.fmu"]
        elif label == "observer-as-plant":
            files["in/plant.fmu"] = files["in/obs.fmu"]
        elif label == "mismatched-plant":
            files["in/plant.fmu"] = bases.fmus["plant-building" if PLANT_OF[base] == "ex1" else "plant-ex1"]
        else:
            files["in/plant.fmu"] = files["in/obs.fmu"]
        label = f"fmus {label}"
    argv = ["cosim", "--plant", P("in/plant.fmu"), "--observer", P("in/obs.fmu"), "--out", P(out_rel)]
    if "--t-end" not in extra:
        argv += ["--t-end", SHORT_T_END[base]]
    runs = [Run(argv + [P(a.rel) if isinstance(a, P) else a for a in extra], allowed=allowed)]
    return Case(category, f"{base}-{backend}: {label}", files, runs, targets, preserve, timeout=90)


def output_cases(bases: Bases, category: str = "outputs") -> list[Case]:
    """Every command writing where it must not: an existing folder, a full device, a FIFO, a
    path under a file, a name without the right suffix; and an existing output kept when the
    command fails.

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    out = []
    problem = bases.problems["ex1"][0].encode()
    infeasible = problem.replace(b'decay = "max"', b"decay = 0.5")
    card = bases.cards["ex1"][0].encode()
    bad_card = card.replace(b'"verified": true', b'"verified": false')
    targets = {"folder": Dir(), "device-full": Device("full"), "fifo": Fifo()}
    commands = [
        ("design", ["design", P("in/problem.toml")], {"in/problem.toml": problem}, "json"),
        ("build-c", ["build", P("in/card.json"), "--backend", "c"], {"in/card.json": card}, "fmu"),
        ("build-python", ["build", P("in/card.json"), "--backend", "python"], {"in/card.json": card}, "fmu"),
        ("plant", ["plant", P("in/problem.toml")], {"in/problem.toml": problem}, "fmu"),
    ]
    for name, argv, files, ext in commands:
        for tname, content in targets.items():
            rel = f"out/target.{ext}"
            out.append(Case(category, f"{name} -o {tname}", {**files, rel: content},
                            [Run(argv + ["-o", P(rel)], allowed=frozenset({2}))], [], [rel], timeout=30))
        out.append(Case(category, f"{name} -o under a file", {**files, "out/afile": PREEXISTING},
                        [Run(argv + ["-o", P(f"out/afile/x.{ext}")], allowed=frozenset({2}))], [], ["out/afile"]))
        out.append(Case(category, f"{name} -o existing file (success replaces it)",
                        {**files, f"out/x.{ext}": PREEXISTING},
                        [Run(argv + ["-o", P(f"out/x.{ext}")], allowed=frozenset({0}))], [f"out/x.{ext}"],
                        [f"out/x.{ext}"]))
        out.append(Case(category, f"{name} -o in new folders", files,
                        [Run(argv + ["-o", P(f"out/a/b/c/x.{ext}")])], [f"out/a/b/c/x.{ext}"]))
    # failing commands over an existing output
    fails = [
        ("design infeasible", ["design", P("in/problem.toml")], {"in/problem.toml": infeasible}, "json"),
        ("design malformed", ["design", P("in/problem.toml")], {"in/problem.toml": b"[plant\n"}, "json"),
        ("build unverified c", ["build", P("in/card.json"), "--backend", "c"], {"in/card.json": bad_card}, "fmu"),
        ("build unverified python", ["build", P("in/card.json"), "--backend", "python"], {"in/card.json": bad_card},
         "fmu"),
        ("plant malformed", ["plant", P("in/problem.toml")], {"in/problem.toml": b"[plant]\nA = 1\n"}, "fmu"),
        ("build nan card", ["build", P("in/card.json")],
         {"in/card.json": card.replace(b'"N": [', b'"N": [[NaN, 0.0], ', 1)},
         "fmu"),
    ]
    for name, argv, files, ext in fails:
        rel = f"out/x.{ext}"
        out.append(Case(category, f"{name} over an existing output", {**files, rel: PREEXISTING},
                        [Run(argv + ["-o", P(rel)], allowed=frozenset({2}))], [rel], [rel]))
    out.append(Case(category, "build -o not-an-fmu-suffix over existing",
                    {"in/card.json": card, "out/x.txt": PREEXISTING},
                    [Run(["build", P("in/card.json"), "-o", P("out/x.txt")], allowed=frozenset({2}))],
                    ["out/x.txt"], ["out/x.txt"]))
    out.append(Case(category, "design -o the problem file itself fails", {"in/problem.toml": infeasible},
                    [Run(["design", P("in/problem.toml"), "-o", P("in/problem.toml")], allowed=frozenset({2}))],
                    ["in/problem.toml"], ["in/problem.toml"]))
    out.append(Case(category, "build -o the card itself (replacing it is what -o asks)", {"in/card.fmu": card},
                    [Run(["build", P("in/card.fmu"), "-o", P("in/card.fmu")])], ["in/card.fmu"], ["in/card.fmu"]))
    return out


def input_file_cases(bases: Bases, category: str = "input-files") -> list[Case]:
    """Every command given an input that is not a regular file of sane size: FIFO, device,
    folder, symlink to ``/dev/zero``, a sparse or valid file above 64 MiB, empty, missing.

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    problem = bases.problems["ex1"][0].encode()
    card = bases.cards["ex1"][0].encode()
    kinds = [("fifo", Fifo(), True), ("device-zero", Device("zero"), True), ("device-null", Device("null"), True),
             ("symlink-dev-zero", Symlink("/dev/zero"), True), ("folder", Dir(), True),
             ("sparse-above-limit", Sparse(SIZE_LIMIT + 1), True), ("empty", b"", True),
             ("missing", None, True), ("proc-file", Symlink("/proc/self/status"), True)]
    big_problem = Big(b"#" * 63 + b"\n", SIZE_LIMIT + 1024, header=problem)
    big_card = Big(b" ", SIZE_LIMIT + 1024, header=card.rstrip()[:-1], trailer=b"}\n")
    out = []
    slots = [
        ("check", lambda p: ["check", p], "in/problem.toml", big_problem, []),
        ("design", lambda p: ["design", p, "-o", P("out/card.json")], "in/problem.toml", big_problem,
         ["out/card.json"]),
        ("plant", lambda p: ["plant", p, "-o", P("out/plant.fmu")], "in/problem.toml", big_problem, ["out/plant.fmu"]),
        ("build", lambda p: ["build", p, "-o", P("out/obs.fmu")], "in/card.json", big_card, ["out/obs.fmu"]),
        ("validate", lambda p: ["validate", p], "in/obs.fmu", None, []),
        ("cosim --observer", lambda p: ["cosim", "--plant", P("in/plant.fmu"), "--observer", p, "--out",
                                        P("out/run"), "--t-end", "1"], "in/obs2.fmu", None, ["out/run"]),
        ("cosim --plant", lambda p: ["cosim", "--plant", p, "--observer", P("in/obs.fmu"), "--out", P("out/run"),
                                     "--t-end", "1"], "in/plant2.fmu", None, ["out/run"]),
    ]
    fmus = {"in/obs.fmu": bases.fmus["obs-ex1-c"], "in/plant.fmu": bases.fmus["plant-ex1"]}
    for slot, make, rel, big, targets in slots:
        variants = list(kinds) + ([("valid-above-limit", big, True)] if big is not None else [])
        for kname, content, must in variants:
            files = dict(fmus) if slot.startswith(("validate", "cosim")) else {}
            if slot == "validate":
                files.pop("in/obs.fmu")
            if content is not None:
                files[rel] = content
            out.append(Case(category, f"{slot} given {kname}", files,
                            [Run(make(P(rel)), allowed=frozenset({2}) if must else frozenset({0, 2}))], targets,
                            timeout=30))
    # a problem given as a plants/NAME-like folder whose problem.toml is hostile
    for kname, content, _ in kinds[:4]:
        out.append(Case(category, f"check given a folder whose problem.toml is {kname}",
                        {"in/plantdir/problem.toml": content} if content is not None else {"in/plantdir": Dir()},
                        [Run(["check", P("in/plantdir")], allowed=frozenset({2}))], [], timeout=30))
    return out


def fmu_level_cases(bases: Bases, category: str = "fmu-level") -> list[Case]:
    """Broken FMUs through ``validate`` and ``cosim`` (as observer and as plant), and FMUs given
    to commands that expect a problem or a card.

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    out = []
    for key in ("obs-ex1-c", "obs-ex1-python"):
        for label, content in broken_fmus(bases.fmus[key]):
            files = {"in/x.fmu": content, "in/plant.fmu": bases.fmus["plant-ex1"], "in/obs.fmu": bases.fmus[key]}
            out.append(Case(category, f"{key} {label}: validate", files,
                            [Run(["validate", P("in/x.fmu"), "--steps", "10"])], [], timeout=60))
            out.append(Case(category, f"{key} {label}: cosim --observer", files,
                            [Run(["cosim", "--plant", P("in/plant.fmu"), "--observer", P("in/x.fmu"), "--out",
                                  P("out/run"), "--t-end", "1"])], ["out/run"], timeout=60))
    for label, content in broken_fmus(bases.fmus["plant-ex1"]):
        files = {"in/x.fmu": content, "in/obs.fmu": bases.fmus["obs-ex1-c"]}
        out.append(Case(category, f"plant-ex1 {label}: cosim --plant", files,
                        [Run(["cosim", "--plant", P("in/x.fmu"), "--observer", P("in/obs.fmu"), "--out", P("out/run"),
                              "--t-end", "1"])], ["out/run"], timeout=60))
    fmu = bases.fmus["obs-ex1-c"]
    for cmd in (["check"], ["design"], ["plant"], ["build"]):
        tail = [] if cmd[0] == "check" else ["-o", P("out/x." + ("json" if cmd[0] == "design" else "fmu"))]
        out.append(Case(category, f"{cmd[0]} given an FMU", {"in/x.fmu": fmu},
                        [Run(cmd + [P("in/x.fmu")] + tail, allowed=frozenset({2}))], ["out"]))
    return out


def tamper_cases(bases: Bases, category: str = "card-tamper") -> list[Case]:
    """Cards whose matrices or certificate were altered while ``certificate.verified`` stays
    true, and the :func:`consistent_forgeries` of every base card: a product that re-checks
    everything a card claims refuses them (``verify`` and ``build`` exit 2, no FMU).

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    out = []
    for base in ("ex1", "ltv", "building"):
        doc = bases.cards[base][1]

        def scaled(factor, name="N"):
            new = copy.deepcopy(doc)

            def scale(v):
                return [scale(x) for x in v] if isinstance(v, list) else v * factor
            new["matrices"][name] = scale(new["matrices"][name])
            return new
        variants = [("N x 10", scaled(10.0)), ("N x -3", scaled(-3.0)), ("L x 1000", scaled(1000.0, "L")),
                    ("Xz x 0", scaled(0.0, "Xz"))]
        for label, new in variants:
            for backend in ("c", "python"):
                out.append(Case(category, f"card {base}: {label} with verified = true (build --backend {backend})",
                                {"in/card.json": card_text(new)},
                                [Run(["build", P("in/card.json"), "-o", P("out/obs.fmu"), "--backend", backend],
                                     allowed=frozenset({2}))], ["out/obs.fmu"]))
    docs = [doc for _, doc in bases.cards.values()]
    for base, (_, doc) in sorted(bases.cards.items()):
        for label, new in consistent_forgeries(doc, docs, random.Random(base)):
            out.append(Case(category, f"card {base}: consistent forgery, {label} (build and verify)",
                            {"in/card.json": card_text(new)},
                            [Run(["verify", P("in/card.json")], allowed=frozenset({2})),
                             Run(["build", P("in/card.json"), "-o", P("out/obs.fmu")], allowed=frozenset({2}))],
                            ["out/obs.fmu"]))
    return out


def argument_cases(bases: Bases, category: str = "arguments") -> list[Case]:
    """Malformed command lines (unknown options, missing or mistyped values): argparse's errors.

    Parameters
    ----------
    bases : Bases
    category : str

    Returns
    -------
    list of Case
    """
    lines = [["check"], ["design"], ["build", P("in/x.json"), "--backend", "fortran"],
             ["cosim", "--plant", P("in/p.fmu")], ["cosim", "--plant", P("in/p.fmu"), "--observer", P("in/o.fmu"),
                                                   "--out", P("out/r"), "--seed", "abc"],
             ["cosim", "--plant", P("in/p.fmu"), "--observer", P("in/o.fmu"), "--out", P("out/r"), "--t-end", "x"],
             ["validate", P("in/o.fmu"), "--steps", "-1"], ["validate", P("in/o.fmu"), "--steps", "0"],
             ["validate", P("in/o.fmu"), "--seed", "-5"], ["frobnicate"], ["check", "--bogus", P("in/x")], []]
    files = {"in/o.fmu": bases.fmus["obs-ex1-c"], "in/p.fmu": bases.fmus["plant-ex1"]}
    out = []
    for argv in lines:
        out.append(Case(category, "uiofmu " + " ".join(a.rel if isinstance(a, P) else a for a in argv), files,
                        [Run(argv, allowed=frozenset({2}))], ["out"], timeout=60))
    return out


MUJOCO_PLANT = ROOT / "plants" / "quarter_car"


def mujoco_case(rng, category: str = "mujoco-spec", mutation: Mutation | None = None) -> Case:
    """A MuJoCo plant folder whose ``mujoco.toml`` is hostile, through ``plant`` or ``linearize``.

    Parameters
    ----------
    rng : random.Random
    category : str
    mutation : Mutation, optional
        Use this edit (default: a random single or compound edit, or a raw text mutation).

    Returns
    -------
    Case
    """
    import tomllib

    text = (MUJOCO_PLANT / "mujoco.toml").read_text(encoding="utf-8")
    doc = tomllib.loads(text)
    model = (MUJOCO_PLANT / "model.xml").read_bytes()
    mode = "single" if mutation else rng.choice(["single", "single", "compound", "raw", "model"])
    files = {}
    if mode == "single":
        mutation = mutation or rng.choice(all_mutations(doc, "problem"))
        new = copy.deepcopy(doc)
        mutation.apply(new)
        spec, label = problem_text(new), f"mujoco.toml: {mutation.describe()}"
    elif mode == "compound":
        new, muts = compound_mutation(rng, doc, "problem")
        spec, label = problem_text(new), "mujoco.toml: " + "; ".join(m.describe() for m in muts)
    elif mode == "raw":
        name, spec = rng.choice(raw_text_mutations(rng, text))
        label = f"mujoco.toml: raw {name}"
    else:
        name, xml = rng.choice([
            ("include-passwd", model.replace(b"<worldbody>", b'<include file="/etc/passwd"/><worldbody>', 1)),
            ("include-traversal", model.replace(b"<worldbody>", b'<include file="../../../../etc/hostname"/>'
                                                                b"<worldbody>", 1)),
            ("entity-bomb", _entity_bomb()), ("empty", b""), ("not-xml", b"<mujoco"),
            ("huge-sparse", Sparse(SIZE_LIMIT + 1)), ("fifo", Fifo()),
        ])
        spec, label = text.encode(), f"model.xml: {name}"
        files["in/plant/model.xml"] = xml
    files.setdefault("in/plant/model.xml", model)
    files["in/plant/mujoco.toml"] = spec
    if rng.random() < 0.5:
        argv = ["plant", P("in/plant"), "-o", P("out/plant.fmu")]
        target = "out/plant.fmu"
    else:
        argv = ["linearize", P("in/plant"), "-o", P("out/problem.toml")]
        target = "out/problem.toml"
    return Case(category, label, files, [Run(argv)], [target], timeout=120)


# -- consistent forgeries ------------------------------------------------------------------------
def _largest(value) -> float:
    """The largest finite magnitude in a nested list of numbers (0 for none)."""
    if isinstance(value, list):
        return max((_largest(v) for v in value), default=0.0)
    return abs(value) if isinstance(value, float) and math.isfinite(value) else 0.0


def _nudge(value, rng, scale: float | None = None):
    """``value`` changed by a little (one number by 1e-3 of the largest in its matrix, or a
    different text, integer, flag), keeping its type and shape: a forgery each field's own
    validation accepts."""
    if isinstance(value, float) and scale:
        return value + 1e-3 * scale
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * (1 + 1e-3) + 1e-3 if math.isfinite(value) else 1.0
    if isinstance(value, str):
        return value + " (edited)"
    if value is None:
        return [[1.0]]
    if isinstance(value, list) and value:
        out = copy.deepcopy(value)
        i = rng.randrange(len(out))
        out[i] = _nudge(out[i], rng, scale or _largest(value) or None)
        return out
    if isinstance(value, dict) and value:
        out = copy.deepcopy(value)
        key = rng.choice(sorted(out))
        out[key] = _nudge(out[key], rng, scale)
        return out
    return value


#: The certificates' Lyapunov matrices: any one that satisfies the LMIs proves the decay, so one from
#: another design of the same plant may be true; the re-check judges it like any other.
LYAPUNOV = {"lti-uio": ("X",), "ltv-auid": ("X",), "sampled-data": ("Pl",), "switched": ("S",),
            "delayed-uio": ("Q",), "deadbeat-functional": ()}


def consistent_forgeries(doc: dict, others: list, rng) -> list[tuple[str, dict]]:
    """Cards whose fields are each valid and that are jointly false, from one designed card ``doc``.

    - every field the card's problem determines (``uiofmu.consistency``: the plant's matrices
      the FMU runs, the schedule, the step, the derived figures) changed a little;
    - the problem's own plant changed while the card's matrices stay (a certificate for another plant);
    - each matrix (but the Lyapunov matrices :data:`LYAPUNOV`) taken from another card ``others`` of
      the same family where it has the same shape and differs by more than rounding (a matrix from
      another design), and each bound from another card where it claims what no certificate of
      this card can prove (:func:`_false_below`).

    Returns
    -------
    list of (label, dict)
        Each forgery with what was changed; every one must be refused by ``build`` and ``verify``.
    """
    import numpy as np

    from uiofmu.consistency import DETERMINED
    from uiofmu.runtime.card import card_from_data
    from uiofmu.synthesis import verify

    out = []
    paths = [c.name[:-len(DETERMINED)] for c in verify(card_from_data(doc)) if c.name.endswith(DETERMINED)]
    for path in paths:
        new = copy.deepcopy(doc)
        parent, last = _locate(new, path)
        before = parent[last] if isinstance(parent, list) else parent.get(last)
        # an existence figure may move by up to eigen_rtol(n) <= 7e-3 (n <= 6) of its condition's size between
        # machines: nudged by 3e-2 of that size (and of 1), beyond it
        wide = 30.0 * max([abs(x) for x in _floats_of(before)] + [1.0]) if path.startswith("existence.") else None
        parent[last] = _nudge(before, rng, wide)
        if parent[last] != before:
            out.append((f"{path} nudged", new))
    for key, value in (("decay_bound", 0.5), ("overshoot_bound", 1.0)):
        if key in doc and doc[key] is None:                     # a bound the family does not certify
            new = copy.deepcopy(doc)
            new[key] = value
            out.append((f"{key} {value} claimed where the family certifies none", new))
    for key in ("r", "K"):                                      # the dead-beat figures its window follows from
        if isinstance(doc.get(key), int):
            new = copy.deepcopy(doc)
            new[key] = doc[key] + 1
            out.append((f"{key} changed", new))
    plant = doc["problem"]["plant"]
    for key in ("A", "E", "C", "D0"):
        if isinstance(plant.get(key), list) and plant[key]:
            new = copy.deepcopy(doc)
            new["problem"]["plant"][key] = _nudge(plant[key], rng)
            out.append((f"problem.plant.{key} changed, matrices kept", new))
    for other in others:
        if other["family"] != doc["family"] or other["name"] == doc["name"]:
            continue
        for key, value in doc["matrices"].items():
            theirs = other["matrices"].get(key)
            if key in LYAPUNOV[doc["family"]] or theirs is None or np.shape(theirs) != np.shape(value):
                continue
            mine, theirs_ = np.asarray(value, dtype=float), np.asarray(theirs, dtype=float)
            if np.abs(mine - theirs_).max() > 1e-6 * max(np.abs(mine).max(), 1e-300):   # another matrix, not rounding
                new = copy.deepcopy(doc)
                new["matrices"][key] = copy.deepcopy(theirs)
                out.append((f"matrices.{key} from {other['name']}", new))
        for key, floor in _false_below(doc).items():
            mine, theirs = doc.get(key), other.get(key)
            if isinstance(mine, float) and isinstance(theirs, float) and theirs < floor:
                new = copy.deepcopy(doc)
                new[key] = theirs
                out.append((f"{key} {theirs:.4g} from {other['name']} (the card's is {mine:.4g})", new))
    return out


def _floats_of(value) -> list:
    """Every float of a JSON value."""
    if isinstance(value, dict):
        return [x for v in value.values() for x in _floats_of(v)]
    if isinstance(value, list):
        return [x for v in value for x in _floats_of(v)]
    return [value] if isinstance(value, float) and math.isfinite(value) else []


def _locate(doc: dict, path: str) -> tuple:
    """The container and the key (or index) of a check's card path (``existence.conditions[2].values``;
    what a check's name adds after the path, `` (...)``, is left out)."""
    steps = []
    for part in path.split(" (")[0].split("."):
        key, *indices = part.split("[")
        steps += [key] + [int(i.rstrip("]")) for i in indices]
    parent = doc
    for step in steps[:-1]:
        parent = parent[step]
    return parent, steps[-1]


def _false_below(doc: dict) -> dict:
    """The bounds below which a card's claim is false beyond doubt, whatever its certificate: a
    decay below the spectral radius of a step matrix ``N`` the runtime applies (every constant
    sequence of steps decays no faster), an overshoot below ``sqrt(cond)`` of its Lyapunov matrices
    (what its certificate proves; the family's re-check may accept no less)."""
    import numpy as np

    m, out = doc["matrices"], {}
    if doc["family"] in ("lti-uio", "sampled-data", "switched"):
        n = doc["dims"]["n"]
        N = np.asarray(m["N"], dtype=float).reshape(-1, n, n)
        out["decay_bound"] = float(max(np.abs(np.linalg.eigvals(x)).max() for x in N))
    keys = [k for k in LYAPUNOV[doc["family"]] if k in m]
    if keys and doc.get("overshoot_bound") is not None:
        P = np.asarray(m[keys[0]], dtype=float)
        eig = np.linalg.eigvalsh(P.reshape(-1, *P.shape[-2:]))
        out["overshoot_bound"] = float(np.sqrt(eig.max() / eig.min()))
    return out
