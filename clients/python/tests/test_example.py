"""The example controller's pieces: the team it reads, its grid, its braking
and its contact counting (the daemon run is in test_daemon.py)."""

from __future__ import annotations

import numpy as np
from conftest import REPO

from flowopt_client.example import Tally, TeamSpec, brake


def test_the_team_is_read_from_the_daemon_configuration():
    spec, prefix = TeamSpec.from_config(str(REPO / "config/default.toml"), None)
    assert prefix == "flowopt"
    assert (spec.name, spec.dim, spec.robots, spec.radius) == ("default", 2, 16, 0.1)
    assert (spec.workspace_min, spec.workspace_max) == ((-1.0, -1.0), (1.0, 1.0))


def test_the_grid_cells_are_separated_and_inside_the_workspace():
    for spec in (
        TeamSpec(),
        TeamSpec(dim=3, robots=27, half_height=0.15, workspace_min=(-1.5,) * 3, workspace_max=(1.5,) * 3),
    ):
        cells = spec.cells()
        assert cells.shape == (spec.robots, spec.dim)
        assert np.all(cells > spec.workspace_min) and np.all(cells < spec.workspace_max)
        i, j = np.triu_indices(spec.robots, 1)
        assert np.linalg.norm((cells[i] - cells[j]) / spec.separation(), axis=1).min() > 1.0
    np.testing.assert_allclose(TeamSpec().cells()[[0, 1, 4]], [[-0.75, -0.75], [-0.25, -0.75], [-0.75, -0.25]])


def test_braking_stops_each_robot_at_the_acceleration_limit():
    position, velocity = np.zeros((2, 2)), np.array([[1.5, 0.0], [0.0, 0.0]])
    p, v = brake(position, velocity, 0.2, 3.0)
    np.testing.assert_allclose(v, [[0.9, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(p, [[1.5 * 0.2 - 1.5 * 0.04, 0.0], [0.0, 0.0]])
    p, v = brake(p, v, 10.0, 3.0)  # comes to rest at v^2 / 2a from the start: 0.375 m
    np.testing.assert_allclose(v, 0.0)
    np.testing.assert_allclose(p, [[0.375, 0.0], [0.0, 0.0]])


def test_contacts_are_counted_when_they_begin_and_the_closest_approach_kept():
    tally, separation = Tally(), np.array([0.2, 0.2])
    gaps = [0.5, 0.19, 0.15, 0.3, 0.1]  # two contacts begin: at 0.19 and at 0.1
    path = np.array([[[0.0, 0.0], [g, 0.0]] for g in gaps])
    tally.distances(path[:3], separation)
    tally.distances(path[3:], separation)
    assert tally.contacts == 2
    assert tally.closest == 0.5
