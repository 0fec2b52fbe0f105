"""The baselines the papers compare against: a naive MLP and NBRDF (NeuBRDF's tables), a fitted GGX lobe, the
dipole BSSRDF and NeuMIP / a surface BRDF on the object's UV (NeuPreSS's)."""
import torch

from neumat.fit.method import Method, register_method
from neumat.fit.translucent_fit import observation_report
from neumat.methods.baselines import dipole_train, ggx_train, naive_mlp_train, nbrdf_train, neumip_uv_train
from neumat.methods.baselines.dipole_bssrdf import DipoleBSSRDF
from neumat.methods.baselines.drjit import translate_ggx, translate_naive_mlp, translate_nbrdf
from neumat.methods.baselines.ggx import GGXFit
from neumat.methods.baselines.naive_mlp import NaiveMLP
from neumat.methods.baselines.nbrdf import NBRDF
from neumat.methods.baselines.neumip_uv import NeuMIPUV, SurfaceBRDFUV


def _sphere_quadrature(model: DipoleBSSRDF) -> None:
    """A small dipole's surface quadrature (set from the observed object in training): 4 points of a sphere of
    radius 0.5."""
    x = 0.5 * torch.nn.functional.normalize(torch.tensor([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, -1]]), dim=-1)
    model.set_surface(x, 2 * x, torch.full((4,), torch.pi / 4))


register_method(Method("naive-mlp", NaiveMLP, {"paper": naive_mlp_train.RECIPE, "cpu": naive_mlp_train.CPU_RECIPE},
                       small=dict(hidden=8), drjit=translate_naive_mlp))
register_method(Method("nbrdf", NBRDF, {"paper": nbrdf_train.RECIPE, "cpu": nbrdf_train.CPU_RECIPE},
                       drjit=translate_nbrdf))
register_method(Method("ggx", GGXFit, {"paper": ggx_train.RECIPE, "cpu": ggx_train.CPU_RECIPE},
                       options=ggx_train.Options, phases=ggx_train.phases, drjit=translate_ggx))
register_method(Method("dipole-bssrdf", DipoleBSSRDF, {"paper": dipole_train.RECIPE, "cpu": dipole_train.CPU_RECIPE},
                       options=dipole_train.Options, phases=dipole_train.phases,
                       small=dict(samples=4, texture_resolution=2), prepare=_sphere_quadrature,
                       report=observation_report))
for name, model in (("neumip-uv", NeuMIPUV), ("surface-brdf-uv", SurfaceBRDFUV)):
    register_method(Method(name, model, {"paper": neumip_uv_train.RECIPE, "cpu": neumip_uv_train.CPU_RECIPE},
                           options=neumip_uv_train.Options, phases=neumip_uv_train.phases, small=dict(spatial_size=8),
                           report=observation_report))
