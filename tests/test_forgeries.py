"""Consistent forgeries: cards whose fields are each valid and jointly false.

Every field a card's problem determines (the plant's matrices the FMU runs, the schedule, the
step, the figures derived from the certificate), the problem's plant itself, a runtime matrix
from another design and a bound from another card: each changed alone, on the tracked card of
every family (the examples' designs), must be refused by the re-check that ``build``, ``cosim``
and ``verify`` run, and by the command line with exit 2 and one line.
"""

from __future__ import annotations

import copy
import json
import random
from pathlib import Path

import pytest

import hostile
import uiofmu
from uiofmu.consistency import DETERMINED
from uiofmu.problem import problem_from_data
from uiofmu.runtime.registry import AVAILABLE
from uiofmu.runtime.card import card_from_data
from uiofmu.runtime.errors import CardError
from uiofmu.synthesis import recheck

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
#: Two designs per family (for matrices and bounds taken from another card), one problem each.
PROBLEMS = {"example1": EXAMPLES / "seed000_example1.toml", "example1-ltv": EXAMPLES / "seed000_example1_ltv.toml",
            "example2": EXAMPLES / "seed000_example2_consistent.toml", "fouka": EXAMPLES / "seed001_example.toml",
            "setup2": EXAMPLES / "seed002_setup2.toml", "three-modes": EXAMPLES / "seed002_three_modes.toml",
            "deadbeat": EXAMPLES / "seed003_example.toml", "needs-theta": EXAMPLES / "seed003_needs_theta.toml",
            "quarter-car": ROOT / "plants" / "quarter_car" / "problem.toml",
            "building": ROOT / "plants" / "two_room_building" / "problem.toml"}


@pytest.fixture(scope="module")
def docs():
    """Every problem designed, plus Example 1 at a fixed decay (a second lti-uio design of the same plant)."""
    out = {name: uiofmu.design(uiofmu.load_problem(path)).data for name, path in PROBLEMS.items()}
    slow = uiofmu.load_problem(PROBLEMS["example1"]).data
    slow["observer"]["decay"] = 0.999
    slow["name"] = "example1-slow"
    out["example1-slow"] = uiofmu.design(problem_from_data(slow)).data
    return out


def _forgeries(docs, name):
    return hostile.consistent_forgeries(docs[name], list(docs.values()), random.Random(name))


def test_the_designs_cover_every_family_twice_and_verify(docs):
    families = [d["family"] for d in docs.values()]
    assert sorted(set(families)) == sorted(AVAILABLE) and all(families.count(f) >= 2 for f in families
                                                              if f != "delayed-uio"), families
    for name, doc in docs.items():
        checks = recheck(card_from_data(doc))
        assert any(c.name.endswith(DETERMINED) for c in checks), name


@pytest.mark.parametrize("name", sorted([*PROBLEMS, "example1-slow"]))
def test_every_consistent_forgery_is_refused(docs, name):
    """Each forgery is refused by the card schema or fails the re-check, naming what was changed
    where the change is a field the problem determines."""
    forged = _forgeries(docs, name)
    kinds = {label.split(" ")[0].split(".")[0] for label, _ in forged}
    assert {"matrices", "schedule", "problem"} <= kinds, kinds          # the generator reaches them all
    accepted = []
    for label, doc in forged:
        try:
            card = card_from_data(doc)
        except CardError:
            continue                       # the card schema refuses it (a shape, a kind, a length)
        try:
            recheck(card)
        except CardError as exc:
            text = str(exc)
            assert "\n" not in text
            if label.endswith(" nudged"):          # named, or a field that must agree with it (mu: tau1)
                assert label.split(" ")[0].split(".")[-1] in text or \
                    "is not what the card's problem determines" in text, (label, text)
            continue
        accepted.append(label)
    assert not accepted, accepted


def test_a_card_for_another_plant_names_the_matrix(docs):
    """The problem's A changed while the card's matrices stay: the certificate is for another plant."""
    doc = json.loads(json.dumps(docs["example1"]))
    doc["problem"]["plant"]["A"][0][0] += 0.01
    with pytest.raises(CardError, match=r"matrices\.A_sampled is not what the card's problem determines"):
        recheck(card_from_data(doc))


def test_the_delayed_substep_and_rank_bound_are_derived(docs):
    """The red team's 1e-300 substep (cosim would never return) and a raised rank-margin bound."""
    for key, value in (("max_substep", 1e-300), ("sigma_bound", 0.0), ("max_substep", 1.0)):
        doc = json.loads(json.dumps(docs["fouka"]))
        doc["schedule"][key] = value
        with pytest.raises(CardError, match=rf"schedule\.{key} is not what"):
            recheck(card_from_data(doc))


@pytest.mark.parametrize("family", sorted(AVAILABLE))
def test_verify_and_build_refuse_a_forgery_from_the_command_line(docs, family, tmp_path, cli):
    name = next(n for n, d in docs.items() if d["family"] == family)
    label, doc = next((lab, d) for lab, d in _forgeries(docs, name) if lab.startswith("problem.plant"))
    path = tmp_path / "forged.json"
    path.write_text(json.dumps(doc))
    res = cli("verify", path)
    assert res.code == 2 and len(res.err.strip().splitlines()) == 1, (label, res)
    assert "is not what the card's problem determines" in res.err, (label, res.err)
    out = tmp_path / "forged.fmu"
    res = cli("build", path, "-o", out)
    assert res.code == 2 and not out.exists(), (label, res)


def test_validate_names_an_fmu_whose_card_does_not_re_check(docs, tmp_path, cli):
    """An FMU built from a forged card without the command line's re-check (``build_observer``
    directly): ``uiofmu validate`` says its card proves nothing."""
    from uiofmu.fmu.export import build_observer

    doc = json.loads(json.dumps(docs["example1"]))
    doc["problem"]["plant"]["A"][1][1] = 0.5
    fmu = build_observer(card_from_data(doc), tmp_path / "forged.fmu")
    res = cli("validate", fmu)
    assert res.code == 2 and "its design card does not re-check" in res.err, res
    assert "matrices.A_sampled is not what the card's problem determines" in res.err
    good = build_observer(card_from_data(docs["example1"]), tmp_path / "good.fmu")
    assert cli("validate", good).code == 0


def test_cosim_refuses_a_c_fmu_whose_card_is_not_the_one_compiled_in(docs, tmp_path, cli):
    """A C observer built (without the re-check) from a card with another N, the honest card then put
    in its resources/model.json: the card re-checks, but the binary runs other matrices; the GUID the
    binary was built with is the card's, so the swap is refused."""
    import zipfile

    from uiofmu.fmu.export import build_observer

    forged = json.loads(json.dumps(docs["example1"]))
    forged["matrices"]["N"][1][1] = 1.2
    fmu = build_observer(card_from_data(forged), tmp_path / "forged.fmu", backend="c")
    swapped = tmp_path / "swapped.fmu"
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(swapped, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "resources/model.json":
                data = json.dumps({"kind": "observer", "card": docs["example1"]}).encode()
            dst.writestr(item, data)
    plant = tmp_path / "plant.fmu"
    assert cli("plant", PROBLEMS["example1"], "-o", plant).code == 0
    res = cli("cosim", "--plant", plant, "--observer", swapped, "--out", tmp_path / "run", "--no-report")
    assert res.code == 2 and "is not the one its binary was built from" in res.err, res
    honest = build_observer(card_from_data(docs["example1"]), tmp_path / "honest.fmu", backend="c")
    assert cli("cosim", "--plant", plant, "--observer", honest, "--out", tmp_path / "ok", "--no-report").code == 0


@pytest.mark.parametrize("name, key, value, field", [("example1-slow", "decay", 0.995, "decay_bound"),
                                                     ("fouka", "decay", 6.0, "decay_rate"),
                                                     ("example1-ltv", "mu", 80.0, "mu")])
def test_a_card_whose_problem_asks_for_another_fixed_value_is_refused(docs, name, key, value, field):
    """The recorded problem is the one that designed the card: a fixed decay (or mu) it asks for is the
    one the card certifies."""
    doc = json.loads(json.dumps(docs[name]))
    assert doc["problem"]["observer"][key] != value
    doc["problem"]["observer"][key] = value
    with pytest.raises(CardError, match=rf"design card: {field} is not what the card's problem determines"):
        recheck(card_from_data(doc))


# -- what a card lists besides its certificate -------------------------------------------------------------

def _refused(doc) -> str:
    from uiofmu.runtime.errors import CardError

    try:
        recheck(card_from_data(doc))
    except CardError as exc:
        return str(exc)
    return ""


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_the_existence_a_card_lists_is_its_problems(docs, name):
    """Every condition of the card's existence analysis is recomputed without a solver: a verdict flipped, a
    condition dropped or a number of it changed (by half, and by 1e-3: a residual of rounding may change by
    half and stay rounding) is refused by name."""
    doc = docs[name]
    conditions = doc["existence"]["conditions"]
    flipped = copy.deepcopy(doc)
    first = next(i for i, c in enumerate(conditions) if c.get("solver") is not True)
    flipped["existence"]["conditions"][first]["holds"] = not conditions[first]["holds"]
    said = _refused(flipped)              # the flipped verdict, or the claim that an observer exists it decided
    assert f"existence.conditions[{first}].holds (found" in said or "existence.exists (found True" in said, said
    dropped = copy.deepcopy(doc)
    del dropped["existence"]["conditions"][first]
    assert "existence.conditions (" in _refused(dropped)
    with_numbers = [(i, k) for i, c in enumerate(conditions) if c.get("solver") is not True
                    for k, v in c["values"].items() if isinstance(v, float) and v != 0.0]
    for i, key in with_numbers[:3]:
        changed = copy.deepcopy(doc)
        changed["existence"]["conditions"][i]["values"][key] = 1.5 * conditions[i]["values"][key] + 1e-3
        assert f"existence.conditions[{i}].values.{key}" in _refused(changed), (name, i, key)


@pytest.mark.parametrize("name,key", [("example1", "eigenvalues_N"), ("example1", "spectral_radius_N"),
                                      ("example1", "fixed_modes"), ("example1-ltv", "eigenvalues_N_k0"),
                                      ("example1-ltv", "norm_MCE"), ("building", "eigenvalues_L_constant"),
                                      ("building", "sampled_invariant_zeros"), ("building", "lmi_size"),
                                      ("three-modes", "spectral_radius_Phi"), ("deadbeat", "nilpotency_class")])
def test_the_figures_a_card_lists_are_recomputed(docs, name, key):
    """Eigenvalues, zeros, radii and sizes a card lists are recomputed from its matrices and its problem's
    analysis: one halved (or, for an integer, one more) is refused by name."""
    doc = copy.deepcopy(docs[name])

    def change(value):
        if isinstance(value, dict):
            k = sorted(value)[0]
            return {**value, k: change(value[k])}
        if isinstance(value, list):
            return [change(value[0]), *value[1:]] if value else value
        if isinstance(value, bool) or value is None:
            return value
        return value + 1 if isinstance(value, int) else 0.5 * value + 0.25

    doc[key] = change(doc[key])
    assert doc[key] != docs[name][key]
    assert _refused(doc).startswith(f"design card: {key}"), _refused(doc)


def test_a_condition_that_took_a_solve_stays_the_solvers_record(docs):
    """Sampled-data's certificate on ker C (an LMI solve) is not recomputed by verify, which runs no solver; a
    condition the analysis decides itself, marked as a solver's, is recomputed all the same."""
    from uiofmu.families.random_plants import campaign

    doc = next(uiofmu.design(problem_from_data(p)).data for p in campaign("sampled-data", 3, 2024, n_max=5,
                                                                              intervals_max=4)
               if any(c.get("solver") for c in uiofmu.check(problem_from_data(p)).to_data()["conditions"]))
    solved = [i for i, c in enumerate(doc["existence"]["conditions"]) if c.get("solver")]
    assert solved and not _refused(doc)
    edited = copy.deepcopy(doc)
    values = edited["existence"]["conditions"][solved[0]]["values"]
    values["verified"] = not values["verified"]
    assert not _refused(edited)                                  # the solver's word: a record, not a claim
    marked = copy.deepcopy(doc)
    marked["existence"]["conditions"][0]["solver"] = True
    marked["existence"]["conditions"][0]["holds"] = not doc["existence"]["conditions"][0]["holds"]
    said = _refused(marked)
    assert "existence.conditions[0].holds (found" in said or "existence.exists (found True" in said, said
