"""Scilab's ``ui_observer`` next to uiofmu's lti-uio, on the same discrete plants (``tests/test_scilab.py``).

Scilab's ``[UIobs, J, N] = ui_observer(Sys, reject, C1, D1, flag, Alfa, Beta)`` (``modules/cacsd/macros/
ui_observer.sci``) takes ``Sys = syslin("d", A, [E B], C, [F D])`` with the unknown inputs ``reject = 1:q`` and
estimates ``z = C1 x + D1 (d, u)``: here ``C1 = I``, ``D1 = 0``, the whole state. It returns a reduced-order
observer ``xo+ = Ao xo + Bu u + By y``, ``xhat = Co xo + Du u + Dy y`` in the plant's time domain (``UIobs``'s
input is ``(u, y)``). With ``flag = "st"`` (its default) the modes it can move are placed at ``Alfa`` and ``Beta``
(defaults -1, on the unit circle of a discrete plant: :func:`poles` puts them at 0.5 down to 0.25 instead) and
the stable ones it cannot move stay; it prints ``Residual norm`` of its own decoupling equation and raises no
error where that norm is not zero.

:func:`judge` checks an observer in this form without trusting its source: it converges for every initial
state and every ``u``, ``d`` when some ``T`` gives ``xo - T x`` the autonomous dynamics ``Ao``::

    T A - Ao T = By C,   T E = By F,   T B = Bu + By D,
    Co T + Dy C = I,     Dy F = 0,     Du + Dy D = 0,

(``xhat - x = Co (xo - T x)``), and ``Ao`` is Schur stable. ``T`` is the least-squares solution of the four
equations in it. The first three are one equation of ``xo``'s update, ``T [A E B] = Ao T [I 0 0] + By [C F D] +
Bu [0 0 I]``, the last three one of the estimate, ``Co T [I 0 0] + Dy [C F D] + Du [0 0 I] = [I 0 0]``; each
one's residual is taken relative to the norms of its terms, and the larger is the observer's decoupling residual,
exact to :data:`DECOUPLING_RTOL`. Stable means a spectral radius below
``1 - ZERO_MARGIN``, the margin uiofmu's check puts on an invariant zero. uiofmu's lti-uio card is judged by the
same function (``Ao = N``, ``Bu = G``, ``By = L``, ``Co = Xz``, ``Du = Xu``, ``Dy = Xy``; ``T = I + MC``).

Scilab runs once per batch of plants (a start costs a fraction of a second, a design milliseconds); the plants'
matrices reach its script as numeric literals formatted here, never as text from elsewhere. Run this file to
print the comparison table of ``docs/families/lti-uio.md``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from uiofmu.runtime.tolerances import ZERO_MARGIN  # noqa: E402

#: The command line of Scilab without its desktop.
SCILAB = "scilab-cli"
#: Why the comparison does not run where Scilab is absent.
NO_SCILAB = f"{SCILAB} is not installed (Debian: apt-get install scilab-cli); the comparison with Scilab's " \
            "ui_observer needs it"
#: Largest decoupling residual (relative to the norms of each equation's terms) of an exact observer: far above
#: the rounding of Scilab's and numpy's factorisations (measured on the plants of :func:`plants`: at most 3e-15
#: for the observers that decouple, Scilab's and uiofmu's), far below the residuals of those that do not (0.11
#: and more).
DECOUPLING_RTOL = 1e-7
#: Seconds one Scilab run may take.
TIMEOUT = 120.0
#: Marker of the lines the script prints for Python.
MARK = "@@"


def poles(n: int) -> list:
    """Where Scilab places the modes it moves (``Alfa = Beta``): ``n`` distinct poles from 0.5 down, inside the
    unit circle (its default, -1, is on it)."""
    return [0.5 - 0.05 * i for i in range(n)]



@dataclass(frozen=True)
class Plant:
    """A discrete plant ``x+ = A x + B u + E d``, ``y = C x + D u + F d`` (``B``, ``D`` with ``m`` columns, maybe 0)."""

    name: str
    A: np.ndarray
    B: np.ndarray
    E: np.ndarray
    C: np.ndarray
    D: np.ndarray
    F: np.ndarray

    @classmethod
    def from_doc(cls, doc: dict) -> "Plant":
        """The plant of a problem document (``[plant]`` of a discrete plant)."""
        p = doc["plant"]
        A, E, C = (np.asarray(p[k], dtype=float) for k in ("A", "E", "C"))
        n, q, rows = len(A), E.shape[1], len(C)
        B = np.asarray(p["B"], dtype=float) if "B" in p else np.zeros((n, 0))
        D = np.asarray(p["D"], dtype=float) if "D" in p else np.zeros((rows, B.shape[1]))
        F = np.asarray(p["F"], dtype=float) if "F" in p else np.zeros((rows, q))
        return cls(doc["name"], A, B, E, C, D, F)


@dataclass(frozen=True)
class Observer:
    """``xo+ = Ao xo + Bu u + By y``, ``xhat = Co xo + Du u + Dy y``."""

    Ao: np.ndarray
    Bu: np.ndarray
    By: np.ndarray
    Co: np.ndarray
    Du: np.ndarray
    Dy: np.ndarray

    @classmethod
    def from_card(cls, card) -> "Observer":
        """The observer an lti-uio card runs."""
        M = {k: np.asarray(v, dtype=float) for k, v in card.data["matrices"].items() if k in
             ("N", "G", "L", "Xz", "Xy", "Xu")}
        n = len(M["N"])
        Du = M.get("Xu", np.zeros((n, M["G"].shape[1])))
        return cls(M["N"], M["G"], M["L"], M["Xz"], Du, M["Xy"])


@dataclass(frozen=True)
class Verdict:
    """What :func:`judge` found: the decoupling residual, the spectral radius of ``Ao``, and whether the observer
    is valid (decouples to :data:`DECOUPLING_RTOL` and is stable)."""

    residual: float
    radius: float

    @property
    def decouples(self) -> bool:
        return self.residual <= DECOUPLING_RTOL

    @property
    def stable(self) -> bool:
        return self.radius < 1.0 - ZERO_MARGIN

    @property
    def valid(self) -> bool:
        return self.decouples and self.stable

    def why(self) -> str:
        """Why the observer is not valid ('' where it is)."""
        parts = []
        if not self.decouples:
            parts.append(f"decoupling residual {self.residual:.3g} > {DECOUPLING_RTOL:g}")
        if not self.stable:
            parts.append(f"spectral radius {self.radius:.6g} >= 1")
        return ", ".join(parts)


def _norm(X) -> float:
    return float(np.linalg.norm(X, 2)) if np.size(X) else 0.0


def judge(obs: Observer, plant: Plant) -> Verdict:
    """Decoupling residual and spectral radius of ``obs`` on ``plant`` (module docstring)."""
    A, B, E, C, D, F = plant.A, plant.B, plant.E, plant.C, plant.D, plant.F
    n, no = len(A), len(obs.Ao)
    Ao, Bu, By, Co, Du, Dy = obs.Ao, obs.Bu, obs.By, obs.Co, obs.Du, obs.Dy
    radius = float(np.abs(np.linalg.eigvals(Ao)).max()) if no else 0.0
    I_o, I_n = np.eye(no), np.eye(n)
    # vec(T) column-major: vec(X T Y) = (Y' kron X) vec(T)
    blocks = [(np.kron(A.T, I_o) - np.kron(I_n, Ao), By @ C, _norm(A) + _norm(Ao)),
              (np.kron(E.T, I_o), By @ F, _norm(E)),
              (np.kron(B.T, I_o), Bu + By @ D, _norm(B)),
              (np.kron(I_n, Co), I_n - Dy @ C, _norm(Co))]
    if no:
        rows = [(K / max(w, 1e-300), R.ravel(order="F") / max(w, 1e-300)) for K, R, w in blocks if K.size]
        T = np.linalg.lstsq(np.vstack([r[0] for r in rows]), np.concatenate([r[1] for r in rows]),
                            rcond=None)[0].reshape((no, n), order="F")
    else:
        T = np.zeros((0, n))
    # the two equations at once: xo's update  T [A E B] = Ao T [I 0 0] + By [C F D] + Bu [0 0 I],
    # and the estimate  Co T [I 0 0] + Dy [C F D] + Du [0 0 I] = [I 0 0]
    q, m = E.shape[1], B.shape[1]
    plant_ = np.hstack([A, E, B])
    outputs = np.hstack([C, F, D])
    state = np.hstack([I_n, np.zeros((n, q + m))])
    known = np.hstack([np.zeros((m, n + q)), np.eye(m)])
    tn = _norm(T)
    equations = [(T @ plant_ - Ao @ T @ state - By @ outputs - Bu @ known,
                  tn * (_norm(plant_) + _norm(Ao)) + _norm(By) * _norm(outputs) + _norm(Bu)),
                 (Co @ T @ state + Dy @ outputs + Du @ known - state,
                  _norm(Co) * tn + _norm(Dy) * _norm(outputs) + _norm(Du) + 1.0)]
    residual = max((_norm(R) / scale if scale > 0 else 0.0) for R, scale in equations)
    return Verdict(residual, radius)


# -- Scilab ----------------------------------------------------------------------------------------

def available() -> bool:
    """Whether ``scilab-cli`` is on the PATH."""
    return shutil.which(SCILAB) is not None


def literal(X) -> str:
    """A Scilab matrix literal of a float array (``zeros(r, c)`` for an empty one), every number by ``repr``."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    r, c = X.shape
    if X.size == 0:
        return f"zeros({r},{c})"
    if not np.all(np.isfinite(X)):
        raise ValueError("a plant matrix has a non-finite entry")
    return "[" + ";".join(",".join(repr(float(v)) for v in row) for row in X) + "]"


_PRELUDE = f"""\
function emit(k, name, M)
    mprintf("{MARK} %d %s %d %d", k, name, size(M, 1), size(M, 2));
    for v = M(:)'
        mprintf(" %.17g", v);
    end
    mprintf("\\n");
endfunction
"""


def script(plants: list) -> str:
    """The Scilab script designing ``ui_observer`` for every plant (``C1 = I``, ``D1 = 0``, ``flag = "st"``,
    :func:`poles`), printing each observer's matrices or Scilab's error on lines starting with :data:`MARK`."""
    parts = [_PRELUDE]
    for k, p in enumerate(plants):
        n, q, m = len(p.A), p.E.shape[1], p.B.shape[1]
        alfa = literal(np.array([poles(n)]))
        parts.append(f"""\
try
    Sys = syslin("d", {literal(p.A)}, [{literal(p.E)}, {literal(p.B)}], {literal(p.C)}, \
[{literal(p.F)}, {literal(p.D)}]);
    [UIobs, J, N] = ui_observer(Sys, 1:{q}, eye({n}, {n}), zeros({n}, {q + m}), "st", {alfa}, {alfa});
    [Ao, Bo, Co, Do] = abcd(UIobs);
    emit({k}, "Ao", Ao); emit({k}, "Bo", Bo); emit({k}, "Co", Co); emit({k}, "Do", Do);
catch
    mprintf("{MARK} %d error %s\\n", {k}, strcat(lasterror(), " "));
end
""")
    return "\n".join(parts)


def _parse(text: str, plants: list) -> list:
    """Per plant: an :class:`Observer`, or Scilab's error message (str)."""
    found: dict = {}
    for line in text.splitlines():
        if not line.startswith(MARK + " "):
            continue
        k, name, rest = line.split(" ", 3)[1], line.split(" ", 3)[2], line.split(" ", 3)[3:]
        entry = found.setdefault(int(k), {})
        if name == "error":
            entry["error"] = rest[0].strip() if rest else ""
            continue
        words = rest[0].split() if rest else []
        r, c = int(words[0]), int(words[1])
        entry[name] = np.array([float(w) for w in words[2:]]).reshape((r, c), order="F")
    out = []
    for k, p in enumerate(plants):
        entry = found.get(k, {"error": "no output"})
        if "error" in entry:
            out.append(entry["error"] or "error without a message")
            continue
        m, no, n, rows = p.B.shape[1], len(entry["Ao"]), len(p.A), len(p.C)
        shapes = {name: entry[name].shape for name in ("Ao", "Bo", "Co", "Do")}
        if shapes["Ao"] != (no, no) or shapes["Co"] != (n, no) or shapes["Do"] != (n, m + rows) or \
                (no and shapes["Bo"] != (no, m + rows)):
            out.append("ui_observer returned matrices of inconsistent sizes: "
                       + ", ".join(f"{k} {r}x{c}" for k, (r, c) in shapes.items()))
            continue
        Bo = entry["Bo"] if no else np.zeros((0, m + rows))
        Do = entry["Do"]
        out.append(Observer(entry["Ao"], Bo[:, :m], Bo[:, m:], entry["Co"], Do[:, :m], Do[:, m:]))
    return out


def run(plants: list, timeout: float = TIMEOUT) -> list:
    """Scilab's ``ui_observer`` on every plant, in one Scilab run: per plant an :class:`Observer` or Scilab's
    error message."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "compare.sce"
        path.write_text(script(plants))
        done = subprocess.run([SCILAB, "-nwni", "-nb", "-quit", "-f", str(path)], capture_output=True, text=True,
                              timeout=timeout, check=False)
    return _parse(done.stdout, plants)


# -- the comparison --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Row:
    """One plant compared: uiofmu's check and design, Scilab's observer and the verdicts on both."""

    plant: Plant
    plant_class: str
    exists: bool
    why_none: str
    ours: Verdict | None
    certified: bool
    decay_bound: float | None
    scilab: Verdict | None
    scilab_error: str

    @property
    def scilab_valid(self) -> bool:
        return self.scilab is not None and self.scilab.valid

    @property
    def outcome(self) -> str:
        """How the two compare (the table's rows)."""
        if self.exists and self.scilab_valid:
            return "both valid"
        if not self.exists and self.scilab_error:
            return "no observer exists; Scilab errors"
        if not self.exists:
            return f"no observer exists; Scilab returns one silently ({self.scilab.why()})"
        if self.scilab_error:
            return "an observer exists; Scilab errors"
        return f"an observer exists; Scilab's is not valid ({self.scilab.why()})"


def plants(count: int, seed: int = 0) -> list:
    """``count`` seeded discrete lti-uio problems (:mod:`uiofmu.families.random_plants`), with their class: one
    in four of a class without observer (rank-deficient, unstable-zero), at most 5 states; every third one with
    a known-input feedthrough ``D``, every fifth an unknown-input feedthrough ``F``."""
    from uiofmu.families import random_plants as rpl

    classes = list(rpl.CLASSES)
    out = []
    for i in range(count):
        klass = rpl.NO_OBSERVER_CLASSES[(i // 4) % 2] if i % 4 == 3 else classes[i % 6]
        item = rpl.draw("lti-uio", seed + i, time="discrete", plant_class=klass, n_max=5)
        doc = item.doc
        if i % 3 == 2 and "B" in doc["plant"]:
            rng = np.random.default_rng([seed + i, 7])
            doc["plant"]["D"] = rng.standard_normal((len(doc["plant"]["C"]), len(doc["plant"]["B"][0]))).tolist()
        if i % 5 == 4:
            rng = np.random.default_rng([seed + i, 11])
            doc["plant"]["F"] = rng.standard_normal((len(doc["plant"]["C"]), len(doc["plant"]["E"][0]))).tolist()
        out.append((doc, klass))
    return out


def compare(items: list, timeout: float = TIMEOUT) -> list:
    """Check and design each problem document with uiofmu, run Scilab on the same plants, judge both."""
    import uiofmu
    from uiofmu.problem import problem_from_data
    from uiofmu.runtime.errors import InfeasibleError, NoObserverError

    ps = [Plant.from_doc(doc) for doc, _ in items]
    theirs = run(ps, timeout)
    rows = []
    for (doc, klass), p, s in zip(items, ps, theirs):
        problem = problem_from_data(doc)
        existence = uiofmu.check(problem)
        exists = existence.exists
        why, ours, certified, bound = "", None, False, None
        if not exists:
            why = "; ".join(c.message for c in existence.failures)
        else:
            try:
                card = uiofmu.design(problem)
                ours = judge(Observer.from_card(card), p)
                certified = all(c.holds for c in uiofmu.verify(card)) and ours.radius < card.data["decay_bound"] < 1
                bound = card.data["decay_bound"]
            except (NoObserverError, InfeasibleError) as exc:
                why = str(exc)
        scilab, error = (None, s) if isinstance(s, str) else (judge(s, p), "")
        rows.append(Row(p, klass, exists, why, ours, certified, bound, scilab, error))
    return rows


def table(rows: list) -> str:
    """The counts of :attr:`Row.outcome` (by kind), as a Markdown table."""
    kinds = {}
    for r in rows:
        kind = r.outcome.split(" (")[0]
        kinds[kind] = kinds.get(kind, 0) + 1
    lines = ["| uiofmu / Scilab | plants |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in kinds.items()]
    return "\n".join(lines)


def main() -> int:
    if not available():
        print(NO_SCILAB)
        return 1
    rows = compare(plants(COUNT, SEED))
    for r in rows:
        print(f"{r.plant.name} [{r.plant_class}]: {r.outcome}; ours: "
              f"{'certified' if r.certified else r.why_none[:80]}"
              + (f", residual {r.ours.residual:.2g}, decay_bound {r.decay_bound:.6g}" if r.ours else "")
              + (f"; Scilab: residual {r.scilab.residual:.2g}, radius {r.scilab.radius:.6g}" if r.scilab else
                 f"; Scilab: {r.scilab_error[:100]}"))
    print(table(rows))
    return 0


#: The comparison's plants: how many, and the first seed.
COUNT, SEED = 24, 0

if __name__ == "__main__":
    sys.exit(main())
