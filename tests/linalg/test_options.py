"""Options pushed for one set-up leave PETSc's database as the user left it."""

from petsc4py import PETSc

import admm_dolfinx  # noqa: F401  (loads PETSc in the right order)
from admm_dolfinx.linalg.petsc import prefixed_options


def test_a_users_option_is_overridden_inside_and_restored_after():
    database = PETSc.Options()
    database["opt_test_ksp_type"] = "gmres"
    database["opt_test_ksp_monitor"] = None  # a flag
    try:
        with prefixed_options(
            "opt_test_", {"ksp_type": "cg", "ksp_monitor": None, "pc_type": "jacobi"}
        ):
            assert database.getString("opt_test_ksp_type") == "cg"
            assert database.getString("opt_test_pc_type") == "jacobi"
        assert database.getString("opt_test_ksp_type") == "gmres"
        assert database.hasName("opt_test_ksp_monitor")
        assert not database.hasName("opt_test_pc_type")  # ours, and gone
    finally:
        for name in ("opt_test_ksp_type", "opt_test_ksp_monitor"):
            database.delValue(name)


def test_a_numbered_prefix_leaves_no_entry_of_its_own():
    """PETSc finds -mg_levels_key for -mg_levels_3_key: an option pushed under the
    numbered prefix, over the user's generic one, must not stay behind as a copy of it."""
    database = PETSc.Options()
    database["opt_test_mg_levels_ksp_max_it"] = "3"
    try:
        with prefixed_options("opt_test_mg_levels_3_", {"ksp_max_it": 7}):
            assert database.getInt("opt_test_mg_levels_3_ksp_max_it") == 7
        assert "opt_test_mg_levels_3_ksp_max_it" not in database.getAll()
        assert database.getInt("opt_test_mg_levels_ksp_max_it") == 3
    finally:
        database.delValue("opt_test_mg_levels_ksp_max_it")
