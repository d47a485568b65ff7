"""The design card: exact round-trip, and refusal of malformed cards."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uiofmu.runtime.card import card_from_data, read_card
from uiofmu.runtime.errors import CardError


def test_round_trip_is_bit_identical(example1_card, tmp_path):
    card, path = example1_card
    back = read_card(path)
    for name, arr in card.matrices.items():
        assert np.array_equal(arr, back.matrices[name]), name
        assert arr.tobytes() == back.matrices[name].tobytes()
    assert back.to_json() == card.to_json()
    assert json.loads(path.read_text()) == card.data


def test_awkward_floats_survive(example1_card, tmp_path):
    card, _ = example1_card
    data = json.loads(card.to_json())
    weird = [0.1 + 0.2, 1e-310, 2.0 ** -1074, 1.7976931348623157e308, -0.0, 1 / 3]
    data["matrices"]["c"] = weird[:2]
    path = tmp_path / "w.json"
    path.write_text(card_from_data(data).to_json())
    back = read_card(path)
    assert back.matrices["c"].tolist() == weird[:2]
    assert json.loads(back.to_json())["matrices"]["c"] == weird[:2]


@pytest.mark.parametrize("mutate,fragment", [
    (lambda d: d.update(format="other"), 'format" must be "uiofmu.design"'),
    (lambda d: d.pop("matrices"), "missing key(s) matrices"),
    (lambda d: d.update(version=99), "version 99 is not supported"),
    (lambda d: d["certificate"].update(verified=False), "certificate is not verified"),
    (lambda d: d["matrices"].update(N=[[1.0]]), "matrices.N: expected 2 entries on axis 0, found 1"),
    (lambda d: d["dims"].update(n="two"), "dims.n: expected an integer, found the string 'two'"),
    (lambda d: d["schedule"].update(kind="psychic"),
     "schedule.kind: expected one of 'constant', 'interval', 'geometric', 'mode', 'window', 'continuous', found "
     "the string 'psychic'"),
    (lambda d: d["matrices"].pop("Xz"), "matrices: missing Xz"),
])
def test_bad_cards_are_refused(example1_card, mutate, fragment):
    card, _ = example1_card
    data = json.loads(card.to_json())
    mutate(data)
    with pytest.raises(CardError) as info:
        card_from_data(data)
    assert fragment in str(info.value)


def test_unreadable_card(tmp_path):
    path = tmp_path / "x.json"
    path.write_text("{not json")
    with pytest.raises(CardError, match="not valid JSON"):
        read_card(path)
