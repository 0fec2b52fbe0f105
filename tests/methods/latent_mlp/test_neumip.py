import pytest
import torch

from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.method import recipe_for
from neumat.models.registry import build_model, model_class
from neumat.nn.angular_texture import half_difference
from neumat.warp.hemisphere import sample_cosine_hemisphere

SMALL = {"spatial_size": 16, "spatial_channels": 4, "hidden": 8, "hidden_layers": 2}


def _queries(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    cov = (torch.eye(2) * 0.02 ** 2).expand(n, 2, 2).contiguous()
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g), footprint=cov)


@pytest.mark.parametrize("name", ["neumip", "neumip-frame", "nbrdf-uv"])
def test_registered_roundtrip_and_recipe(name):
    torch.manual_seed(0)
    m = build_model({"type": name, **SMALL})
    clone = model_class(name)(config=m.cfg)
    clone.load_state_dict(m.state_dict())
    q = _queries(64)
    f = m.eval(q)
    assert f.shape == (64, 3) and bool((f > 0).all())
    torch.testing.assert_close(clone.eval(q), f)
    assert recipe_for(name).loss == "relative_l2_mix" and recipe_for(name).queries == "footprint"
    with pytest.raises(InputError, match="Query.uv"):
        m.eval(Query(q.wi, q.wo))


def test_mlp_reads_latent_and_directions():
    """neumip: MLP([z_s, wi, wo]); nbrdf-uv: MLP([z_s, h, d]); neumip-frame: a frame, identity at initialisation."""
    torch.manual_seed(1)
    q = _queries(32)
    for name, dirs in (("neumip", torch.cat([q.wi, q.wo], -1)),
                       ("nbrdf-uv", torch.cat(half_difference(q.wi, q.wo), -1)),
                       ("neumip-frame", torch.cat([q.wi, q.wo], -1))):
        m = build_model({"type": name, **SMALL})
        z = m.spatial(q.uv, q.footprint)
        torch.testing.assert_close(m.eval(q), torch.exp(m.mlp(torch.cat([z, dirs], -1))), rtol=1e-5, atol=1e-6)
    assert build_model({"type": "neumip-frame", **SMALL}).frame is not None


def test_default_flops_are_matched_to_the_gated_model():
    gated = build_model({"type": "multiscale", "spatial_size": 16}).flops()
    for name in ("neumip", "neumip-frame", "nbrdf-uv", "tripleplane"):
        assert abs(build_model({"type": name, "spatial_size": 16}).flops() - gated) < 0.1 * gated, name


def test_bad_config_raises():
    with pytest.raises(InputError, match="directions"):
        build_model({"type": "neumip", "directions": "polar"})
    with pytest.raises(InputError, match="power of two"):
        build_model({"type": "neumip-frame", "spatial_size": 12})
    with pytest.raises(InputError, match="frame_weight_scale"):
        build_model({"type": "neumip-frame", "frame_weight_scale": float("nan")})
    assert build_model({"type": "neumip-frame", "spatial_size": 8, "frame_weight_scale": 1.0}).frame.weight_scale == 1.0


@pytest.mark.parametrize("name, default", [("neumip", True), ("neumip-frame", True), ("nbrdf-uv", True),
                                           ("multiscale", True), ("tripleplane", True)])
def test_a_fit_starts_at_the_data_scale(name, default):
    """init_from_data (the default of every latent-texture model): the output biases become log of the median
    target per channel, so the first prediction is the data's scale (at -2 a fit spent up to 450 of 1000 steps
    overpredicting); off: -2 stays."""
    torch.manual_seed(2)
    target = torch.tensor([1e-2, 5e-2, 3.0]) * torch.rand(4096, 3) * 2
    small = SMALL if name.startswith(("neumip", "nbrdf")) else {"spatial_size": 16}
    assert build_model({"type": name, **small}).cfg.init_from_data is default
    m = build_model({"type": name, **small, "init_from_data": True})
    m.init_from_targets(target)
    torch.testing.assert_close(m.mlp.linears()[-1].bias[:3], target.median(0).values.log())
    q = _queries(256)
    ratio = m.eval(q).median(0).values / target.median(0).values
    assert bool((ratio > 0.2).all() and (ratio < 5).all()), ratio
    off = build_model({"type": name, **small, "init_from_data": False})
    off.init_from_targets(target)
    assert bool((off.mlp.linears()[-1].bias == -2.0).all())
    with pytest.raises(InputError, match="expected targets"):
        m.init_from_targets(target[:, :2])
