"""The path between two pose-graph nodes through the loops it has closed."""

from __future__ import annotations

import math

import pytest
from scanreg.pipeline.graph_path import path_between

#: Ten nodes one metre apart; node 9 closed a loop back to node 1.
TRAVEL = [float(k) for k in range(10)]
LINKS = {1: [9], 9: [1]}


def test_along_the_chain_it_is_the_travel_between_them() -> None:
    assert path_between(TRAVEL, {}, 8, 2) == pytest.approx(6.0)
    assert path_between(TRAVEL, {}, 2, 8) == pytest.approx(6.0)
    assert path_between(TRAVEL, {}, 4, 4) == 0.0


def test_a_closed_loop_shortens_it_by_its_hop() -> None:
    # 8 → 9 (1 m), the loop to 1, 1 → 2 (1 m): 2 m, not 6.
    assert path_between(TRAVEL, LINKS, 8, 2) == pytest.approx(2.0)
    assert path_between(TRAVEL, LINKS, 8, 2, hop=1.5) == pytest.approx(3.5)
    # A hop dearer than the chain is not taken.
    assert path_between(TRAVEL, LINKS, 8, 2, hop=10.0) == pytest.approx(6.0)


def test_it_stops_at_the_limit() -> None:
    assert path_between(TRAVEL, {}, 9, 0, limit=3.0) == 3.0
    assert path_between(TRAVEL, LINKS, 9, 0, limit=3.0) == pytest.approx(1.0)
    assert path_between(TRAVEL, {}, 9, 0) == pytest.approx(9.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start": 10}, "start"),
        ({"goal": -1}, "goal"),
        ({"start": True}, "start"),
        ({"hop": -1.0}, "hop"),
        ({"hop": math.nan}, "hop"),
        ({"limit": -1.0}, "limit"),
        ({"limit": math.nan}, "limit"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"start": 0, "goal": 1, **kwargs}
    with pytest.raises(ValueError, match=match):
        path_between(TRAVEL, LINKS, **args)  # type: ignore[arg-type]
