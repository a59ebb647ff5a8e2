"""Stiffness priors: the paper's Table 5 by name, the researcher's own numbers, and the errors."""

import numpy as np
import pytest

from vtestbed.design.priors import NAMED_PRIORS, PAPER_TABLE5, stiffness_prior
from vtestbed.errors import OutOfRangeError, UnknownNameError

# Gao et al. 2023, Table 5 [N*mm/rad], typed from the paper.
TABLE5_NMM = np.array([2.1977e9, 8.9939e8, 1.1118e9, 6.4449e7, 2.5362e7, 1.9978e7])


def test_paper_table5_by_name_is_the_published_values_in_si():
    np.testing.assert_allclose(stiffness_prior("paper_table5", 6), TABLE5_NMM / 1000.0, rtol=1e-15)
    np.testing.assert_allclose(PAPER_TABLE5.stiffness, TABLE5_NMM * 1e-3, rtol=1e-15)
    assert NAMED_PRIORS["paper_table5"] is PAPER_TABLE5


def test_own_numbers_are_taken_as_given():
    own = [2.2e6, 9e5, 1.1e6, 6.4e4, 2.5e4, 2e4]
    k = stiffness_prior(own, 6)
    assert k.dtype == float and np.array_equal(k, np.array(own))
    assert np.array_equal(stiffness_prior((1, 2, 3), 3), [1.0, 2.0, 3.0])


def test_unknown_name_lists_the_priors_and_names_the_field():
    with pytest.raises(UnknownNameError, match="unknown campaign.prior 'table5'; valid names: paper_table5"):
        stiffness_prior("table5", 6, "campaign.prior")


@pytest.mark.parametrize(
    "value", [[1e6] * 5, [1e6] * 5 + [0.0], [1e6] * 5 + [-1.0], [1e6] * 5 + [np.nan], [1e6] * 5 + [np.inf]]
)
def test_numbers_must_be_dof_positive_finite_values(value):
    with pytest.raises(OutOfRangeError, match=r"prior must be 6 positive stiffness values \[N\*m/rad\]"):
        stiffness_prior(value, 6, "prior")


def test_a_named_prior_for_another_robot_size_is_refused():
    with pytest.raises(OutOfRangeError, match="must be 7 positive stiffness values"):
        stiffness_prior("paper_table5", 7)
