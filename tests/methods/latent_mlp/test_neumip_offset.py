"""NeuMIP's neural offset module (`neumat.methods.latent_mlp.neumip`, Config.offset; registered on as
"neumip-offset")."""
from dataclasses import replace

import pytest
import torch

from neumat.catalog.modelfile import load_model, save_model
from neumat.core.errors import InputError
from neumat.core.query import Query
from neumat.fit.footprint_queries import footprint_queries
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.io.texture_set import TextureSet
from neumat.models.registry import build_model
from neumat.nn import cpu_kernels
from neumat.reflectance.svbrdf import SVBRDF
from neumat.warp.hemisphere import sample_cosine_hemisphere

SMALL = {"spatial_size": 16, "spatial_channels": 4, "hidden": 8, "hidden_layers": 2}


def _queries(n, seed=0, footprint=True):
    g = torch.Generator().manual_seed(seed)
    wi = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    wo = sample_cosine_hemisphere(torch.rand(n, 2, generator=g))
    cov = (torch.eye(2) * 0.02 ** 2).expand(n, 2, 2).contiguous() if footprint else None
    return Query(wi, wo, uv=torch.rand(n, 2, generator=g), footprint=cov)


def _offset_model(**fields):
    torch.manual_seed(0)
    return build_model({"type": "neumip-offset", **SMALL, **fields})


def _perturbed(model):
    """The model with every parameter moved off its initial value (the offset MLP starts at a constant 0)."""
    g = torch.Generator().manual_seed(5)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=g))
    return model


def _set_depth(model, texels):
    """Make the offset MLP output the constant `texels` (finest-level texels)."""
    model.offset_mlp.start_constant(torch.tensor([float(texels)]))


def test_registry_spec_and_option_build_the_same_model():
    a = _offset_model()
    torch.manual_seed(0)
    b = build_model({"type": "neumip", "offset": True, **SMALL})
    assert a.cfg.offset and b.cfg.offset and build_model({"type": "neumip", **SMALL}).offset_mlp is None
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    assert {k.split(".")[0] for k in sa} == {"spatial", "mlp", "offset_texture", "offset_mlp"}


@pytest.mark.parametrize("footprint", [True, False])
def test_zero_depth_equals_plain_neumip_bit_for_bit(footprint):
    """With the offset MLP's output 0 (its start), the model is the plain neumip with the same weights."""
    torch.manual_seed(0)
    plain = _perturbed(build_model({"type": "neumip", **SMALL}))
    model = _offset_model()
    missing = model.load_state_dict(plain.state_dict(), strict=False).missing_keys
    assert missing and all(k.startswith(("offset_texture.", "offset_mlp.")) for k in missing)
    with torch.no_grad():
        for p in model.offset_texture.parameters():
            p.add_(torch.randn(p.shape))  # the offset latent is read but the depth stays 0
    q = _queries(64, footprint=footprint)
    with torch.no_grad(), cpu_kernels.switched_off():  # the same torch operations (plain neumip has a fused kernel)
        assert torch.equal(model.eval(q), plain.eval(q))


@pytest.mark.parametrize("texels", [0.75, -2.5])
def test_constant_depth_shifts_the_lookup_along_the_view_ray(texels):
    """A hand-set depth h = texels / spatial_size (uv) reads z_s at uv + h wo.xy / wo.z, footprint unchanged;
    the grazing factor is clamped at offset_min_cos."""
    model = _perturbed(_offset_model())
    _set_depth(model, texels)
    q = _queries(64)
    q.wo[:4] = torch.nn.functional.normalize(torch.tensor([[1.0, 0.5, 0.02]]), dim=-1).expand(4, 3)  # grazing
    h = texels / SMALL["spatial_size"]
    shifted = q.uv + h * q.wo[:, :2] / q.wo[:, 2:].clamp(min=model.cfg.offset_min_cos)
    assert float((shifted - q.uv).abs().max()) > 0.05  # the shift is well beyond float noise
    with torch.no_grad():
        direct = model.decode(model.spatial(shifted, q.footprint), q)
        torch.testing.assert_close(model.eval(q), direct, rtol=1e-6, atol=0)
        # and not the unshifted lookup
        assert not torch.allclose(model.eval(q), model.decode(model.spatial(q.uv, q.footprint), q))
    # the same with a lod instead of a footprint
    lod = torch.full((64,), 1.5)
    ql = Query(q.wi, q.wo, uv=q.uv, lod=lod)
    with torch.no_grad():
        torch.testing.assert_close(model.eval(ql), model.decode(model.spatial(shifted, None, lod), ql),
                                   rtol=1e-6, atol=0)


def test_offset_latent_is_filtered_at_the_query_footprint():
    """The depth reads the offset pyramid with the query's footprint: MLP_o(T(O, uv, Sigma), wo) / size."""
    model = _perturbed(_offset_model())
    q = _queries(32)
    with torch.no_grad():
        z_o = model.offset_texture(q.uv, q.footprint)
        h = model.offset_mlp(torch.cat([z_o, q.wo], -1)) / SMALL["spatial_size"]
        expected = q.uv + h * q.wo[:, :2] / q.wo[:, 2:].clamp(min=model.cfg.offset_min_cos)
        assert torch.equal(model.offset_uv(q, q.footprint), expected)


def test_gradients_reach_the_offset_texture_and_mlp():
    model = _offset_model()
    # at the start only the last offset layer gets a gradient (the others come after the first step)
    model.eval(_queries(128)).sum().backward()
    last = model.offset_mlp.linears()[-1]
    assert float(last.weight.grad.abs().sum()) > 0
    model.zero_grad()
    _perturbed(model)
    q = _queries(256, footprint=False)
    lod = torch.linspace(0, 4, 256)  # every level of the 16^2 pyramids
    model.eval(Query(q.wi, q.wo, uv=q.uv, lod=lod)).sum().backward()
    for name, p in list(model.offset_texture.named_parameters()) + list(model.offset_mlp.named_parameters()):
        assert p.grad is not None and float(p.grad.abs().sum()) > 0, name


def test_flops_and_bytes_count_the_offset_module():
    """By hand: MLP_o (D_o + 3) -> H -> 1 with SiLU: 2 (D_o + 3) H + 2 H + H FLOPs, plus 8 for the parallax;
    bytes add the offset pyramid (D_o channels, all levels) and MLP_o's weights and biases."""
    plain = build_model({"type": "neumip", **SMALL})
    model = _offset_model(offset_channels=3, offset_hidden=5)
    d, hid = 3, 5
    assert model.flops() - plain.flops() == 2 * (d + 3) * hid + 2 * hid + hid + 8
    texels = sum((16 >> level) ** 2 for level in range(5))
    params = (d + 3) * hid + hid + hid + 1
    assert model.size_bytes("fp32") - plain.size_bytes("fp32") == 4 * (d * texels + params)


def test_defaults_are_near_the_papers_table_5():
    """Table 5 (fp32): NeuMIP's MLPs 5.06 kB; its spatial textures 74100 kB against 44700 kB for 8 channels."""
    model = build_model({"type": "neumip-offset", "spatial_size": 1024})
    mlps = sum(p.numel() for p in model.mlp.parameters()) + sum(p.numel() for p in model.offset_mlp.parameters())
    assert round(4 * mlps / 1000, 2) == 5.06
    textures = model.spatial.num_parameters() + model.offset_texture.num_parameters()
    assert abs(4 * textures / 1000 - 74100) < 0.03 * 74100
    gated = build_model({"type": "multiscale", "spatial_size": 16}).flops()
    assert abs(build_model({"type": "neumip-offset", "spatial_size": 16}).flops() - gated) < 0.1 * gated


def test_save_load_round_trip(tmp_path):
    model = _perturbed(_offset_model())
    loaded = load_model(save_model(model, tmp_path / "m.nmat"))
    assert loaded.name == "neumip-offset" and loaded.cfg == model.cfg
    q = _queries(64)
    with torch.no_grad():
        assert torch.equal(model.eval(q), loaded.eval(q))
    torch.manual_seed(0)
    option = _perturbed(build_model({"type": "neumip", "offset": True, **SMALL}))
    again = load_model(save_model(option, tmp_path / "o.nmat"))
    assert again.name == "neumip" and again.cfg.offset
    with torch.no_grad():
        assert torch.equal(option.eval(q), again.eval(q))


@pytest.mark.parametrize("field, value", [("offset_channels", 0), ("offset_hidden", 0), ("offset_hidden_layers", -1),
                                          ("offset_min_cos", 0.0), ("offset_min_cos", 1.5),
                                          ("offset_min_cos", float("nan"))])
def test_bad_config_names_the_field(field, value):
    with pytest.raises(InputError, match=field):
        build_model({"type": "neumip-offset", field: value})


def test_sampler_features_are_the_unshifted_latent():
    """A learned sampler's query has no wo: its features are z_s at uv without the offset."""
    model = _perturbed(_offset_model())
    _set_depth(model, 3.0)
    q = _queries(32)
    with torch.no_grad():
        expected = model.spatial(q.uv, q.footprint)
        assert torch.equal(model.sampling_features(Query(q.wi, uv=q.uv, footprint=q.footprint)), expected)


def test_sampling_model_refuses_the_offset():
    with pytest.raises(InputError, match="offset"):
        build_model({"type": "neural-appearance", "spatial_size": 8, "offset": True})


def test_short_fit_lowers_the_error():
    """200 steps on a small random texture set (rough dielectric): the error on fixed queries against 32-sample
    targets falls below 75 % of the untrained model's (measured 0.257 -> 0.146; smoke test, not a benchmark)."""
    g = torch.Generator().manual_seed(0)
    ts = TextureSet(color=torch.rand(16, 16, 3, generator=g),
                    normal=torch.tensor([0.0, 0.0, 1.0]).expand(16, 16, 3).contiguous(),
                    roughness=0.6 + 0.3 * torch.rand(16, 16, generator=g), metalness=torch.zeros(16, 16),
                    height=torch.zeros(16, 16))
    source = SVBRDF(ts, samples=4)
    q = footprint_queries(source, None)(1024, torch.Generator().manual_seed(9), "cpu")
    target = SVBRDF(ts, samples=32, seed=3).eval(q)

    def error(m):
        with torch.no_grad():
            return ((m.eval(q) - target).square().sum(-1) / (target.square().sum(-1) + 1e-4)).mean().item()

    model = _offset_model()
    before = error(model)
    recipe = replace(recipe_for("neumip-offset"), steps=200, batch_size=512, lr=1e-2, betas=(0.9, 0.999), ema=0.0,
                     lr_decay_every=0)
    result = fit(model, source, recipe, progress=False)
    assert error(result.model) < 0.75 * before
    assert float(result.model.offset_mlp.linears()[-1].weight.detach().abs().sum()) > 0  # the module trained
