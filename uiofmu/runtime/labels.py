"""Names and units of a plant's states, inputs and outputs (standard library only).

A problem's ``[plant]`` table may name the elements of each channel and give their units
(``states = ["T_room", "T_wall"]``, ``state_units = ["K", "K"]``). They are data from someone else:
:func:`check_labels` refuses a count that is not the channel's dimension, a name that is not an
identifier-like word, a unit outside a conservative character set and a name given twice. They
reach an FMU only as attribute values of ``modelDescription.xml`` (:func:`apply_labels`, through
ElementTree, which escapes them): the variable names stay ``x[1]``, ``xhat[1]``, ...; the name goes
into the variable's ``description`` and the unit into its ``unit`` and ``<UnitDefinitions>``.
"""

from __future__ import annotations

import re

from .text import check_text

#: The channels that can be labelled: (key of the names, key of the units, dimension, what one element is).
CHANNELS = (("states", "state_units", "n", "state"), ("inputs", "input_units", "m", "known input"),
            ("unknown_inputs", "unknown_input_units", "q", "unknown input"), ("outputs", "output_units", "p", "output"))
#: Every key of :data:`CHANNELS` (what a ``[plant]`` table may hold besides its model).
KEYS = tuple(key for channel in CHANNELS for key in channel[:2])
#: Longest name and longest unit (characters).
MAX_LABEL, MAX_UNIT = 64, 32
#: A name: a letter or underscore, then letters, digits and ``_ . - [ ]`` (``T_room``, ``x.cart``, ``q[2]``).
_NAME = re.compile(r"[^\W\d][\w.\[\]-]*\Z")
#: A unit: ASCII letters, digits and ``_ / . * ^ ( ) % -`` (FMI unit names such as ``m/s2``, ``rad/s``, ``1``).
_UNIT = re.compile(r"[A-Za-z0-9_/.*^()%-]+\Z")
#: The channel whose labels each port's elements take (observer and plant ports alike; others have none).
PORT_CHANNELS = {"x0": "states", "x": "states", "xhat0": "states", "xhat": "states", "u": "inputs",
                 "d": "unknown_inputs", "dhat": "unknown_inputs", "y": "outputs", "r": "outputs"}
_UNITS = {names: units for names, units, _, _ in CHANNELS}


def _name(value, key: str, error) -> str:
    check_text(value, key, error, MAX_LABEL)
    if not _NAME.match(value):
        raise error(f"{key}: {value!r} is not a name (a letter or _, then letters, digits and _ . - [ ])")
    return value


def _unit(value, key: str, error) -> str:
    check_text(value, key, error, MAX_UNIT)
    if not _UNIT.match(value):
        raise error(f"{key}: {value!r} is not a unit (ASCII letters, digits and _ / . * ^ ( ) % -, e.g. \"m/s2\", "
                    "\"K\", \"1\")")
    return value


def _count(number: int, one: str, many: str | None = None) -> str:
    return f"{number} {one if number == 1 else many or one + 's'}"


def check_labels(table: dict, dims: dict, prefix: str, error=ValueError) -> dict:
    """The names and units a table holds, checked against the plant's dimensions.

    Parameters
    ----------
    table : dict
        A ``[plant]`` table (other keys are ignored).
    dims : dict
        ``n``, ``m``, ``q``, ``p``.
    prefix : str
        The table's key path, for messages (``"plant"``).
    error : type
        Exception raised.

    Returns
    -------
    dict
        ``{key: list of str}`` for every key of :data:`KEYS` the table holds.

    Raises
    ------
    error
        Naming the key: not a list, a count other than the dimension (both numbers), a name or unit
        that is not one, a name given twice.
    """
    out = {}
    for names, units, dim, what in CHANNELS:
        for key, check in ((names, _name), (units, _unit)):
            if key not in table:
                continue
            value, full = table[key], f"{prefix}.{key}"
            if not isinstance(value, list):
                raise error(f"{full}: expected a list of strings, found {type(value).__name__}")
            if len(value) != dims[dim]:
                raise error(f"{full}: {_count(len(value), 'entry', 'entries')} for {_count(dims[dim], what)} "
                            f"(one per {what})")
            out[key] = [check(v, f"{full}[{i}]", error) for i, v in enumerate(value)]
            twice = next((v for i, v in enumerate(value) if v in value[:i]), None) if key == names else None
            if twice is not None:
                raise error(f"{full}: {twice!r} is given twice (each {what} needs its own name)")
    return out


def element_label(labels: dict, port: str, i: int) -> tuple:
    """The name and unit of element ``i`` (0-based) of ``port``: ``(name or None, unit or None)``."""
    channel = PORT_CHANNELS.get(port)
    if channel is None:
        return None, None
    names, units = labels.get(channel), labels.get(_UNITS[channel])
    return (names[i] if names else None), (units[i] if units else None)


#: What an observer's port is of its channel's element, in a label (``T_room estimate``).
_ROLES = {"xhat": "estimate", "dhat": "estimate", "r": "residual"}


def axis_label(labels: dict, port: str, i: int) -> str:
    """A plot label of element ``i`` (0-based) of ``port``.

    Returns
    -------
    str
        ``T_room [K]`` (``x``), ``T_room estimate [K]`` (``xhat``), ``T_room residual [K]`` (``r``), or
        without a name the FMI name ``xhat[1]``, with the unit when one is given (``xhat[1] [K]``).
    """
    name, unit = element_label(labels, port, i)
    text = f"{name} {_ROLES[port]}" if name and port in _ROLES else name or f"{port}[{i + 1}]"
    return f"{text} [{unit}]" if unit else text


def column_labels(labels: dict, sizes: dict) -> dict:
    """``{FMI name: axis label}`` of every labelled element of the ports ``{name: size}``
    (``{"x[1]": "T_room [K]"}``)."""
    return {f"{port}[{i + 1}]": axis_label(labels, port, i) for port, size in sizes.items() for i in range(size)
            if element_label(labels, port, i) != (None, None)}


def apply_labels(root, ports, labels: dict) -> None:
    """Put the names and units into a ``modelDescription.xml`` tree (``root``, its ElementTree element)
    written from ``ports``.

    Each labelled ``ScalarVariable`` (found by its name ``port[i]``) gets its name before its
    description (``"T_room: state estimate at ..."``) and its unit on its ``<Real>``; the units
    used are declared in ``<UnitDefinitions>`` right after ``<CoSimulation>`` (the order of the
    FMI 2.0 schema). ElementTree escapes every value; nothing else changes.
    """
    from xml.etree.ElementTree import Element       # here: reading a problem or a card needs no XML

    variables = {v.get("name"): v for v in root.iter("ScalarVariable")}
    used = []
    for port in ports:
        for i in range(port.size):
            name, unit = element_label(labels, getattr(port, "key", port.name), i)
            var = variables.get(f"{port.name}[{i + 1}]")
            if var is None:
                continue
            if name:
                var.set("description", f"{name}: {var.get('description', '')}".rstrip(": "))
            real = var.find("Real")
            if unit and real is not None:
                real.set("unit", unit)
                used += [unit] if unit not in used else []
    if used:
        definitions = Element("UnitDefinitions")
        for unit in used:
            definitions.append(Element("Unit", {"name": unit}))
        after = next(i for i, child in enumerate(root) if child.tag == "CoSimulation") + 1
        root.insert(after, definitions)
