"""The true robot: per-effect contributions come from the same perturbations as the pose."""

import numpy as np

from sim_sources.cell import SimulatedCell
from sim_sources.scenarios import get_scenario


def test_contributions_add_up_to_the_total_error_to_first_order():
    cell = SimulatedCell(get_scenario("paper", noise=False), 100, 0)
    cond = cell.conditions()
    total = cell.truth.poses(cond)[:, :3, 3] - cell.model.fk(cond.q)[:, :3, 3]
    parts = sum(c[:, :3] for c in cell.truth.contributions(cond).values())
    assert np.abs(parts - total).max() < 0.05 * np.abs(total).max()
    assert set(cell.truth.contributions(cond)) == set(cell.truth.names)


def test_without_compliance_there_is_no_deflection():
    cell = SimulatedCell(get_scenario("geometric"), 10, 0)
    np.testing.assert_array_equal(cell.truth.deflection(cell.conditions()), 0.0)
