"""What several study modules measure: the simulated stress frames of the reduced protocol, rendered once."""

from __future__ import annotations

from typing import Any

import pytest


@pytest.fixture(scope="session")
def stress_sim_frames() -> list[tuple[Any, list]]:
    """(frame, cases) of the simulated stress protocol at seeds 0-1, 3 and 5 m (``evaluation.core_answers``'
    reduced set): test_core_answers answers them, test_stress measures them with every method."""
    from evaluation.core_answers import SIM_DISTANCES, SIM_SEEDS
    from evaluation.stress_sim import stress_sim_cases

    return stress_sim_cases(SIM_SEEDS, SIM_DISTANCES)
