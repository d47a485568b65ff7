"""A native guard in front of pythonfmu's binary in the FMUs of backend ``python``.

pythonfmu 0.7.0's ``binaries/linux64/<model>.so`` ignores the GUID and the FMU type given to
fmi2Instantiate, crashes on a resource location that is not ``file://`` plus a folder holding
``slavemodule.txt`` (or that has a percent-escape other than ``%20``), and answers fmi2OK for
every call a Python method returns from, so uiofmu's slave can only report a refused call by
a log line of status fmi2Error. :func:`guard_fmu` compiles ``c/pythonfmu_guard.c`` for one FMU
(its GUID and model identifier become string literals) and puts it in front: the guard becomes
``binaries/linux64/<model>.so``, pythonfmu's binary moves beside it as ``<model>_pythonfmu.so``.
The guard refuses those instantiations with a log line, decodes the resource location, and
returns fmi2Error (fmi2Discard) from a call during which the slave logged a line of that
status; everything else is forwarded unchanged (see the C file for the details).

Only the linux64 binary is guarded; ``binaries/win64`` stays as pythonfmu built it.
"""

from __future__ import annotations

import platform
import re
import subprocess
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree

from ..runtime.errors import FmuError
from ..runtime.files import atomic_output

#: The guard's source.
SOURCE = Path(__file__).parent / "c" / "pythonfmu_guard.c"
#: Where pythonfmu's binary goes, relative to ``binaries/linux64/`` (``{model}``: the model identifier).
REAL_NAME = "{model}_pythonfmu.so"
#: A GUID as the guard takes it: a UUID, optionally in braces (only these characters reach the C source).
GUID_PATTERN = re.compile(r"(?:\{[0-9A-Fa-f]{8}(?:-[0-9A-Fa-f]{4}){3}-[0-9A-Fa-f]{12}\}"
                          r"|[0-9A-Fa-f]{8}(?:-[0-9A-Fa-f]{4}){3}-[0-9A-Fa-f]{12})")
#: A model identifier: a C identifier (FMI 2.0 asks for one), of reasonable length.
MODEL_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,199}")
#: Largest modelDescription.xml read.
MAX_DESCRIPTION_BYTES = 16 * 2**20
#: Compiler flags (C99, warnings on, only the FMI functions and finalizePythonInterpreter exported).
CFLAGS = ("-std=c99", "-O2", "-Wall", "-Wextra", "-shared", "-fPIC", "-fvisibility=hidden")
LIBS = ("-ldl", "-pthread")


def available() -> bool:
    """Whether FMUs can be guarded here: a linux64 host with a C compiler and the FMI headers.

    Returns
    -------
    bool
        False leaves pythonfmu's binary as it is (the FMU works, without the guard's checks).
    """
    from .c_backend import c_compiler, fmi_headers

    return (platform.system() == "Linux" and platform.machine() in ("x86_64", "AMD64")
            and c_compiler() is not None and (fmi_headers() / "fmi2Functions.h").is_file())


def check_guid(guid: str) -> str:
    """``guid`` when it is a UUID (optionally in braces), the only form compiled into the guard.

    Parameters
    ----------
    guid : str

    Returns
    -------
    str

    Raises
    ------
    FmuError
        For anything else (it would not be a safe C string literal, or not a uuid).
    """
    if not isinstance(guid, str) or not GUID_PATTERN.fullmatch(guid):
        raise FmuError(f"GUID {str(guid)[:80]!r} is not a UUID (8-4-4-4-12 hexadecimal digits, optionally in braces); "
                       "the pythonfmu guard compiles only such a GUID into its binary")
    return guid


def _normal_guid(guid: str) -> str:
    return guid.strip("{}").lower()


def check_model_identifier(model: str) -> str:
    """``model`` when it is a C identifier (at most 200 characters).

    Parameters
    ----------
    model : str

    Returns
    -------
    str

    Raises
    ------
    FmuError
    """
    if not isinstance(model, str) or not MODEL_PATTERN.fullmatch(model):
        raise FmuError(f"model identifier {str(model)[:80]!r} is not a C identifier")
    return model


def compile_guard(guid: str, model: str, out_dir) -> Path:
    """Compile the guard for one FMU.

    Parameters
    ----------
    guid : str
        The FMU's GUID (checked with :func:`check_guid`).
    model : str
        Its model identifier (checked with :func:`check_model_identifier`).
    out_dir : str or Path
        Where ``<model>.so`` is written.

    Returns
    -------
    Path
        The shared library.

    Raises
    ------
    FmuError
        No compiler, or the compiler failed.
    """
    from .c_backend import c_compiler, fmi_headers

    guid, model = check_guid(guid), check_model_identifier(model)
    cc = c_compiler()
    if cc is None:
        raise FmuError("the pythonfmu guard needs a C compiler (cc, gcc or clang) on PATH")
    out = Path(out_dir) / f"{model}.so"
    # The defines are separate arguments (no shell), and both values were checked above.
    cmd = [cc, *CFLAGS, f"-I{fmi_headers()}", f'-DGUARD_GUID="{guid}"', f'-DGUARD_MODEL="{model}"',
           "-o", str(out), str(SOURCE), *LIBS]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise FmuError(f"cannot run the C compiler for the pythonfmu guard ({exc})") from None
    if proc.returncode != 0 or not out.is_file():
        raise FmuError(f"the C compiler failed on pythonfmu_guard.c: {proc.stderr.strip()[:2000]}")
    return out


def _description(z: zipfile.ZipFile, path: Path) -> tuple[str, str]:
    """(GUID, Co-Simulation model identifier) of the FMU's modelDescription.xml."""
    try:
        info = z.getinfo("modelDescription.xml")
    except KeyError:
        raise FmuError(f"{path}: no modelDescription.xml") from None
    if info.file_size > MAX_DESCRIPTION_BYTES:
        raise FmuError(f"{path}: modelDescription.xml has {info.file_size} bytes, more than {MAX_DESCRIPTION_BYTES}")
    try:
        root = ElementTree.fromstring(z.read(info))
    except ElementTree.ParseError as exc:
        raise FmuError(f"{path}: modelDescription.xml is not XML ({exc})") from None
    cs = root.find("CoSimulation")
    if root.tag != "fmiModelDescription" or root.get("fmiVersion") != "2.0" or cs is None:
        raise FmuError(f"{path}: not an FMI 2.0 Co-Simulation FMU")
    return root.get("guid") or "", cs.get("modelIdentifier") or ""


def guard_fmu(fmu_path, guid: str | None = None) -> Path:
    """Put the native guard in front of pythonfmu's linux64 binary in an FMU, in place.

    The FMU is rewritten into a temporary file beside it that then replaces it, so a failure
    leaves it as it was.

    Parameters
    ----------
    fmu_path : str or Path
        An FMU built by pythonfmu (uiofmu's backend ``python``), not guarded yet.
    guid : str, optional
        The GUID the FMU must have; by default the one of its ``modelDescription.xml`` (which
        is what the guard checks the importer's against, and what uiofmu's slave checks its
        resources against).

    Returns
    -------
    Path
        ``fmu_path``.

    Raises
    ------
    FmuError
        Not such an FMU, already guarded, a GUID or model identifier that is not of the
        expected form, a ``guid`` other than the modelDescription's, or no compiler.
    """
    path = Path(fmu_path)
    if not path.is_file():
        raise FmuError(f"{path}: no such FMU")
    try:
        with zipfile.ZipFile(path) as z:
            described, model = _description(z, path)
            check_guid(described)
            check_model_identifier(model)
            if guid is not None and _normal_guid(check_guid(guid)) != _normal_guid(described):
                raise FmuError(f"{path}: its modelDescription.xml has GUID {described}, not {guid}")
            binary = f"binaries/linux64/{model}.so"
            real = f"binaries/linux64/{REAL_NAME.format(model=model)}"
            names = set(z.namelist())
            if binary not in names:
                raise FmuError(f"{path}: no {binary} (not an FMU built by pythonfmu for linux64)")
            if real in names:
                raise FmuError(f"{path}: already guarded ({real} is there)")
            with tempfile.TemporaryDirectory(prefix="uiofmu_guard_") as tmp:
                guard = compile_guard(described, model, tmp).read_bytes()
                with atomic_output(path, "FMU") as part, zipfile.ZipFile(part, "w") as out:
                    for info in z.infolist():
                        data = z.read(info)
                        if info.filename == binary:
                            moved = zipfile.ZipInfo(real, date_time=info.date_time)
                            moved.compress_type, moved.external_attr = info.compress_type, info.external_attr
                            out.writestr(moved, data)
                            mine = zipfile.ZipInfo(binary, date_time=info.date_time)
                            mine.compress_type, mine.external_attr = info.compress_type, info.external_attr
                            out.writestr(mine, guard)
                        else:
                            out.writestr(info, data)
    except (OSError, zipfile.BadZipFile, zipfile.LargeZipFile, RuntimeError, NotImplementedError) as exc:
        raise FmuError(f"{path}: cannot rewrite the FMU ({exc})") from None
    return path


def is_guarded(fmu_path) -> bool:
    """Whether an FMU carries the guard (pythonfmu's binary sits beside it under its new name).

    Parameters
    ----------
    fmu_path : str or Path

    Returns
    -------
    bool
    """
    try:
        with zipfile.ZipFile(fmu_path) as z:
            _, model = _description(z, Path(fmu_path))
            return f"binaries/linux64/{REAL_NAME.format(model=model)}" in z.namelist()
    except (OSError, zipfile.BadZipFile, FmuError):
        return False
