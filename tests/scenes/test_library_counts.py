"""The node counts that scene docstrings quote are the scenes' own."""

from __future__ import annotations

import pytest
from mpi4py import MPI

from admm_dolfinx.scenes.library import example3

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize("level, nodes, contact", [(0, 198, 44), (1, 1121, 151), (2, 7337, 557)])
def test_example3_counts_match_its_docstring(level, nodes, contact):
    scene = example3(MPI.COMM_WORLD, level=level)
    assert scene.num_nodes == nodes
    assert scene.problem().num_contact_nodes == contact
    assert f"{nodes}/{contact}" in example3.__doc__ or (
        level == 0 and "198 nodes" in example3.__doc__
    )
