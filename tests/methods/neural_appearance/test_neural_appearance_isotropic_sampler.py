"""The isotropic-lobe ablation of neural-appearance's sampler (Zeltner et al. 2024, Sec. 6.3, Fig. 11): two
outputs (diffuse weight, one roughness), a centred isotropic GGX and an untilted cosine lobe; its sampling
matches its density (chi-square), it is saved with the model, bad values are refused."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from neumat import InputError, Query
from neumat.catalog.modelfile import load_model, save_model
from neumat.export.glsl import export_glsl
from neumat.fit.method import recipe_for
from neumat.fit.trainer import fit
from neumat.methods.neural_appearance.model import NeuralAppearance
from neumat.methods.neural_appearance.proxy_train import fit_sampler
from neumat.methods.neural_appearance.proxy_sampler import ProxySampler, SampledMaterial
from neumat.reflectance.analytic import GGX
from neumat.reflectance.procedural_texture import procedural_texture_set
from neumat.reflectance.svbrdf import SVBRDF
from neumat.testing.chi2 import chi2_material
from neumat.warp.hemisphere import sample_cosine_hemisphere
from neumat.warp.uniform import uniform

SIZE = 16


@pytest.fixture(scope="module")
def isotropic() -> NeuralAppearance:
    torch.manual_seed(0)
    source = SVBRDF(procedural_texture_set("bumps", SIZE, seed=0), samples=4)
    model = NeuralAppearance(spatial_size=SIZE, sampler_lobes="isotropic")
    fit(model, source, replace(recipe_for("neural-appearance"), steps=200, batch_size=512), progress=False)
    return model.train(False)


def _queries(n: int, seed: int) -> Query:
    u = uniform(n, 4, torch.Generator().manual_seed(seed), "cpu")
    return Query(sample_cosine_hemisphere(u[:, :2]), uv=u[:, 2:])


def test_isotropic_lobes_are_centred_and_isotropic(isotropic):
    assert isotropic.sampler.mlp.linears()[-1].out_features == 2
    assert NeuralAppearance(spatial_size=SIZE).sampler.mlp.linears()[-1].out_features == 9   # the paper's default
    with torch.no_grad():
        lobes = isotropic.lobes(_queries(2000, 1))
    assert torch.equal(lobes.mu_d, torch.zeros_like(lobes.mu_d))          # untilted cosine lobe
    assert torch.equal(lobes.mu_s, torch.zeros_like(lobes.mu_s))          # centred GGX
    assert torch.equal(lobes.rho, torch.zeros_like(lobes.rho))
    assert torch.equal(lobes.alpha[:, 0], lobes.alpha[:, 1])              # isotropic
    # trained away from the starting constants (w_d = alpha = 0.5)
    assert float((lobes.w_d - 0.5).abs().min()) > 0.1


def test_isotropic_sampler_and_density_agree(isotropic):
    template = Query(torch.tensor([[0.3, 0.2, 0.9327379]], dtype=torch.float64),
                     uv=torch.tensor([[0.3, 0.7]]).double())
    r = chi2_material(isotropic.double(), template.wi[0], n_samples=1_000_000, template=template, sphere=True,
                      quad=16)
    isotropic.float()
    assert r, r.message


def test_isotropic_proxy_learns_a_specular_lobe_and_its_sampling_matches_its_density():
    """On a rough conductor (GGX 0.15) the isotropic proxy puts most weight in its GGX lobe (the trained model
    above is almost all cosine lobe), so this checks the specular half of its sampler."""
    torch.manual_seed(0)
    ggx = GGX(0.15)
    sampler = fit_sampler(ggx, ProxySampler(lobes="isotropic"), steps=300, batch=1024, progress=False).sampler
    sampled = SampledMaterial(ggx, sampler)
    wi = torch.tensor([0.6427876, 0.0, 0.7660444])                       # 40 degrees
    with torch.no_grad():
        lobes = sampled.lobes(Query(wi[None]))
    assert float(lobes.w_d) < 0.2 and 0.05 < float(lobes.alpha[0, 0]) < 0.4, lobes
    r = chi2_material(sampled, wi.double(), n_samples=1_000_000, sphere=True, quad=16)
    assert r, r.message


def test_isotropic_sampler_is_saved_with_the_model(isotropic, tmp_path):
    q = _queries(64, 2)
    s = isotropic.sample(q, uniform(64, 2, torch.Generator().manual_seed(3), "cpu"))
    back = load_model(save_model(isotropic, tmp_path / "iso.nmat"))
    assert back.cfg.sampler_lobes == "isotropic" and back.sampler.cfg.lobes == "isotropic"
    torch.testing.assert_close(back.pdf(q.with_wo(s.wo)), s.pdf)
    torch.testing.assert_close(back.eval(q.with_wo(s.wo)), isotropic.eval(q.with_wo(s.wo)))


def test_bad_lobe_family_is_refused(isotropic):
    with pytest.raises(InputError, match="sampler_lobes"):
        NeuralAppearance(spatial_size=SIZE, sampler_lobes="elliptical")
    with pytest.raises(InputError, match="lobes"):
        ProxySampler(lobes="gaussian")
    with pytest.raises(InputError, match="sampler_lobes"):
        export_glsl(isotropic)
