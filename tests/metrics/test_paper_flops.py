import pytest
import torch
import torch.nn.functional as F

from neumat.core.errors import InputError
from neumat.metrics.flops import paper_flops, paper_flops_of
from neumat.models.registry import build_model
from neumat.core.material import Material
from neumat.fit.footprint_queries import footprint_queries


def test_small_mlp_matches_hand_count():
    """Linear(4, 8) - SiLU - Linear(8, 3): 4*8 + 8*3 multiply-adds (1 each, bias free) + 8 SiLUs (3 each)."""
    mlp = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.SiLU(), torch.nn.Linear(8, 3))
    assert paper_flops_of(mlp, torch.randn(5, 4), batch=5) == 4 * 8 + 8 * 3 + 3 * 8
    # an explicit add and exp: 1 per element each
    assert paper_flops_of(lambda x: torch.exp(mlp(x) + 1), torch.randn(5, 4), batch=5) == 80 + 3 + 3


def test_bilinear_texture_read_costs_four_per_channel():
    tex, grid = torch.randn(1, 6, 8, 8), torch.rand(1, 1, 10, 2) * 2 - 1
    read = lambda t, g: F.grid_sample(t, g, mode="bilinear", align_corners=False)  # noqa: E731
    assert paper_flops_of(read, tex, grid, batch=10) == 4 * 6


@pytest.mark.parametrize("name", ["tripleplane", "multiscale"])
def test_model_count_is_about_half_the_analytic_one(name):
    """The analytic count prices a multiply-add at 2: on these MLP-dominated models the paper's count (without
    the spatial fetch and the batch-independent preconditioning) is near half of it."""
    model = build_model({"type": name, "spatial_size": 16})
    q = footprint_queries(Material())(256, torch.Generator().manual_seed(0), "cpu")
    ratio = paper_flops(model, q) / model.flops()
    assert 0.3 < ratio < 0.8, ratio
    with pytest.raises(InputError, match="batch"):
        paper_flops_of(model.eval, q, batch=0)
