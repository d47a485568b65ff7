"""What ``uiofmu check`` and ``uiofmu design`` print for a fixed set of problems, timings aside.

The set: every problem file of ``examples/`` and ``plants/``, the quarter-car's LTV observer of
the FMU catalogue, reproducers of the robustness campaigns, random problems of the design
robustness sample, and plants next to the edge of double precision (the DC motor whose weak mode
needs gains of millions, a fixed mode next to the unit circle, a plant in badly scaled units).
Each problem gets its check's lines, then its design's lines or its one-line refusal, and the
exit code the command line gives (0, or 2 for a user-fixable problem).

``tests/data/same_answers.txt`` is that text as it must come out under every BLAS kernel and thread
count (``tests/test_same_answers.py``; ``make test-blas`` runs it under each). Run this file to see
the text, ``--write`` to store the text after a deliberate change::

    .venv/bin/python tests/same_answers.py --write
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STORED = ROOT / "tests" / "data" / "same_answers.txt"

DC_MOTOR = {"time": "continuous", "A": [[0.0, 1.0, 0.0], [0.0, -10.0, 1.0], [0.0, -0.02, -2.0]],
            "B": [[0.0], [0.0], [2.0]], "E": [[0.0], [-100.0], [0.0]], "C": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]}
NEAR_UNIT_FIXED_MODE = {"time": "discrete", "dt": 0.1, "A": [[0.0, 1.0], [-0.5, 0.99999]], "B": [[0.0], [1.0]],
                        "E": [[0.2], [0.0]], "C": [[1.0, 0.0]]}
#: Reproducers of the robustness campaigns (tests/test_design_rules.py, tests/test_sampled_data.py).
REPRODUCERS = (("sampled-data", 7000022), ("sampled-data", 11000116), ("sampled-data", 11000042))
#: The start of the design robustness campaign at seed 2024, as tests/test_design_robustness.py draws it.
SAMPLE_SEED, SAMPLE, KNOBS = 2024, 3, {"n_max": 5, "intervals_max": 4}
#: Fresh problems of that generator next to the edge, ``(family, campaign seed, index)``, whose searches or
#: overshoot figures once differed between BLAS kernels: a held figure from an answer CLARABEL stopped short at
#: (ltv-auid 2025/6) or gave none for (ltv-auid 2028/1), the balanced coordinates' own overshoot read in the
#: plant's (lti-uio 2026/6), a margin probe whose second point did not certify (lti-uio 2027/5).
FRESH = (("ltv-auid", 2025, 6), ("lti-uio", 2026, 6), ("lti-uio", 2027, 5), ("ltv-auid", 2028, 1))
#: A fresh problem of that generator whose closed-form design (the observer options given) has noise gains that
#: the rounding of their certificate's ``X`` decided (gain_y 31800 under one kernel, 35000 under another): lti-uio
#: 2026/7's Riccati design at decay 0.5, what its ``decay = "max"`` falls back to where the LMIs certify nothing
#: (Sandybridge's LMIs certify 0.78125 there).
FRESH_CLOSED_FORM = ("lti-uio", 2026, 7, {"decay": 0.5, "method": "riccati"})


def badly_scaled(plant: dict, exponents) -> dict:
    """``plant`` in coordinates ``x = diag(10**exponents) xs``: the same system, other units."""
    import numpy as np

    T = np.diag(10.0 ** np.asarray(exponents, dtype=float))
    Ti = np.linalg.inv(T)
    A, B, E, C = (np.array(plant[k], dtype=float) for k in "ABEC")
    return {**plant, "A": (Ti @ A @ T).tolist(), "B": (Ti @ B).tolist(), "E": (Ti @ E).tolist(),
            "C": (C @ T).tolist()}


def fresh_closed_form() -> dict:
    """The problem of :data:`FRESH_CLOSED_FORM`: the generator's problem with its observer options."""
    from uiofmu.families import random_plants as rpl

    family, seed, index, options = FRESH_CLOSED_FORM
    doc = list(rpl.campaign(family, index + 1, seed, **KNOBS))[index]
    return {**doc, "observer": {**doc["observer"], **options}}


def problems() -> list[tuple[str, dict]]:
    """``(label, problem document)`` of every problem of the set, in a fixed order."""
    from uiofmu.catalogue import QUARTER_CAR_LTV
    from uiofmu.families import random_plants as rpl

    files = sorted(p for p in (ROOT / "examples").glob("*.toml") if not p.name.startswith("campaign"))
    files += sorted((ROOT / "plants").glob("*/problem.toml"))
    out = [(str(p.relative_to(ROOT)), tomllib.loads(p.read_text(encoding="utf-8"))) for p in files]
    car = tomllib.loads((ROOT / "plants" / "quarter_car" / "problem.toml").read_text(encoding="utf-8"))
    out.append(("plants/quarter_car/problem.toml with the catalogue's LTV observer",
                {**car, "observer": dict(QUARTER_CAR_LTV)}))
    out += [(f"random {family} {seed}", rpl.random_problem(family, seed)) for family, seed in REPRODUCERS]
    for family in ("lti-uio", "ltv-auid", "sampled-data"):
        for doc in rpl.campaign(family, SAMPLE, SAMPLE_SEED, **KNOBS):
            out.append((f"robustness sample {doc['name']}", doc))
    for family, seed, index in FRESH:
        doc = list(rpl.campaign(family, index + 1, seed, **KNOBS))[index]
        out.append((f"fresh {doc['name']}", doc))
    asked = ", ".join(f"{key} {value}" for key, value in FRESH_CLOSED_FORM[3].items())
    out.append((f"fresh {(doc := fresh_closed_form())['name']}, {asked}", doc))
    for decay in (0.3, 0.6, 0.7, 0.98, "max"):
        out.append((f"DC motor, lti-uio at dt = 0.01 s, decay {decay}",
                    {"name": "dc-motor", "plant": DC_MOTOR, "observer": {"family": "lti-uio", "dt": 0.01,
                                                                         "decay": decay}}))
    out.append(("DC motor, sampled-data on 0.01..0.05 s, alpha 0.9",
                {"name": "dc-motor", "plant": DC_MOTOR,
                 "observer": {"family": "sampled-data", "intervals": [0.01, 0.02, 0.03, 0.04, 0.05], "alpha": 0.9}}))
    out.append(("DC motor in units 1e5 apart, sampled-data alpha 0.02",
                {"name": "dc-motor-units", "plant": badly_scaled(DC_MOTOR, [0, 3, -2]),
                 "observer": {"family": "sampled-data", "intervals": [0.01, 0.02], "alpha": 0.02}}))
    out.append(("fixed mode 0.99999 from the unit circle, lti-uio decay max",
                {"name": "near-unit", "plant": NEAR_UNIT_FIXED_MODE, "observer": {"family": "lti-uio",
                                                                                  "decay": "max"}}))
    return out


def answer(label: str, doc: dict) -> str:
    """The text of one problem: its check's lines and its design's summary (or refusal), with exit codes.

    The summary is what ``uiofmu design`` prints, timings and the largest gain's figures aside (read off
    the solver's point, not an optimal value, they differ between kernels; the warning stays), and the digits
    of an overshoot the card marks as not determined by the problem (its words stay).
    """
    import uiofmu
    from uiofmu.certificate import UNDETERMINED_NOTE
    from uiofmu.cli import _one_line, check_summary, design_summary
    from uiofmu.problem import problem_from_data
    from uiofmu.runtime.errors import UserError

    lines = [f"## {label}"]
    try:
        problem = problem_from_data(doc)
        report = uiofmu.check(problem)
        lines += ["check:"] + check_summary(report)
        card = uiofmu.design(problem)
        # an overshoot the problem does not determine says so; its digits (the solver's point's) are not compared
        summary = [re.sub(rf"\S+ {re.escape(UNDETERMINED_NOTE)}", f"* {UNDETERMINED_NOTE}", line)
                   for line in design_summary(card, timing=False)]
        lines += ["design: exit 0"] + summary
    except UserError as exc:
        lines += [f"design: exit 2: {_one_line(exc)}"]
    return "\n".join(lines)


def text() -> str:
    """The whole text, one block per problem."""
    return "\n\n".join(answer(label, doc) for label, doc in problems()) + "\n"


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    have = text()
    if "--write" in sys.argv[1:]:
        STORED.parent.mkdir(parents=True, exist_ok=True)
        STORED.write_text(have, encoding="utf-8")
        print(f"wrote {STORED.relative_to(ROOT)}")
    else:
        sys.stdout.write(have)
