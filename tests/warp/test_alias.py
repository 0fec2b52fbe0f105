"""AliasTable: the encoded distribution equals the weights exactly; sampling follows it (chi-square); errors."""
import pytest
import torch

from neumat.core.errors import InputError
from neumat.warp.alias import AliasTable
from neumat.testing.chi2 import chi2_2d


@pytest.mark.parametrize("weights", [
    torch.rand(1000, generator=torch.Generator().manual_seed(0), dtype=torch.float64) ** 8,
    torch.tensor([0.0, 1.0, 0.0, 3.0, 0.5]),
    torch.tensor([1.0, 1e-12, 1e6, 0.0, 2.0]),
    torch.ones(7),
    torch.tensor([5.0]),
    torch.rand(512 * 1024, generator=torch.Generator().manual_seed(1), dtype=torch.float64) ** 6,
])
def test_table_encodes_the_weights_exactly(weights):
    t = AliasTable(weights)
    ref = weights.double() / weights.double().sum()
    # float64 prefix sums over n items round at ~1e-16 n of one bucket's mass
    torch.testing.assert_close(t.probabilities(), ref, rtol=1e-9, atol=1e-7 / len(weights))
    assert bool(((t.keep >= 0) & (t.keep <= 1)).all())
    assert bool((t.keep[weights == 0] == 0).all())  # zero-weight items are never returned


def test_sampling_follows_the_distribution_and_positions_are_uniform():
    g = torch.Generator().manual_seed(2)
    w = torch.rand(6, 10, generator=g, dtype=torch.float64) ** 3
    t = AliasTable(w)

    def sample(u):
        index, fx, fy = t.sample(u.double())
        p = torch.stack([(index % 10 + fx) / 10, (index // 10 + fy) / 6], -1)
        return p.to(u.dtype), torch.ones(len(u), dtype=torch.bool)

    def pdf(p):
        i = (p[:, 1] * 6).long().clamp(0, 5)
        j = (p[:, 0] * 10).long().clamp(0, 9)
        return (w / w.sum() * 60)[i, j].to(p.dtype)

    r = chi2_2d(sample, pdf, n_samples=200_000, res=(30, 30))  # cells align with the 6 x 10 items
    assert r, r.message


def test_bad_weights():
    for bad in (torch.zeros(3), torch.tensor([1.0, -1.0]), torch.tensor([float("nan")]), torch.zeros(0)):
        with pytest.raises(InputError, match="alias table"):
            AliasTable(bad)
