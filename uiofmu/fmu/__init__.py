"""What builds FMUs: the two backends (standalone C in ``c/``, pythonfmu with the runtime copied
in) and the native guard in front of pythonfmu's binary.

``from uiofmu.fmu import build_observer, build_plant`` (:mod:`uiofmu.fmu.export`).
"""

from .export import build_observer, build_plant, default_backend  # noqa: F401
