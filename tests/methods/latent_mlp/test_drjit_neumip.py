"""Parity of the Dr.Jit runtime programs "neumip" (neumip, neumip-offset, neumip-frame, nbrdf-uv, neural-appearance's
eval: its decoder with 2 frames, the albedo outputs left out) and "ggx-mipmap"
(`neumat.export.drjit.neumip`) with the torch models, on random queries with uv (tiled, outside [0, 1) too) and
random anisotropic footprints (up to 30:1, 16 probes) or none (the finest level), fp32 compute: within 1e-4
relative. As for the multi-scale family (tests/methods/latent_mlp/test_drjit_multiscale.py), a learned shading
frame's lift z = sqrt(1 - x^2 - y^2) amplifies last-ulp differences near its horizon: queries with a local |z| < 0.01
in any frame are left out for neumip-frame; for the GGX mip-map, whose texel normal decides whether a query is above
its shading horizon (0 below), those within 0.01 of it."""
from __future__ import annotations

import copy

import pytest
import torch

from test_drjit_multiscale import _dirs, _footprints, _runtime_eval

from neumat.core.frames import to_local
from neumat.core.query import Query
from neumat.methods.latent_mlp.ggx_mipmap import GGXMipmap
from neumat.methods.latent_mlp.nbrdf_uv import NBRDFUV
from neumat.methods.latent_mlp.neumip import NeuMIP
from neumat.methods.latent_mlp.neumip_frame import NeuMIPFrame
from neumat.methods.latent_mlp.neumip_offset import NeuMIPOffset
from neumat.methods.neural_appearance.model import NeuralAppearance

pytestmark = pytest.mark.mitsuba  # Dr.Jit's LLVM backend needs the LLVM that neumat.core.llvm finds
N = 12000


@pytest.fixture(scope="module")
def drjit_llvm():
    from mitsuba_util import mitsuba_or_skip
    mitsuba_or_skip()
    import drjit as dr
    return dr


def _model(cls, **config):
    torch.manual_seed(0)
    model = cls(**{"spatial_size": 64, **config})
    with torch.no_grad():
        if isinstance(model, GGXMipmap):  # texels that differ: normals, roughness, anisotropy, colours
            for p in model.spatial.raw:
                p.add_(torch.randn_like(p) * 0.5)
            return model.train(False)
        for layer in model.mlp.linears():  # outputs that vary with the latent and the directions (log f std ~1)
            layer.weight.normal_(0, 1.5 / layer.in_features ** 0.5)
        if model.frame is not None:  # a frame that turns: trained ones do
            model.frame.decode.weight.normal_(0, 1.0)
        if model.offset_mlp is not None:  # depths of a few texels (start_constant made them 0)
            last = model.offset_mlp.linears()[-1]
            last.weight.normal_(0, 1.0)
            last.bias.fill_(1.0)
    return model.train(False)


def _keep(model, q: Query) -> torch.Tensor:
    """Queries away from a learned frame's horizon (module docstring)."""
    keep = torch.ones(len(q.wi), dtype=torch.bool)
    if isinstance(model, GGXMipmap):
        p = model.parameters_at(q)
        n, t = p["normal"], p["tangent"]
        b = torch.cross(n, t, dim=-1)
        for w in (q.wi, q.wo):
            keep &= to_local(w, t, b, n)[:, 2].abs() > 0.01
    elif getattr(model, "frame", None) is not None:
        z = model.spatial_latent(q)
        for k in range(model.frame.frames):
            t, b, n = model.frame.frame(z, k)
            keep &= ((q.wi * n).sum(-1).abs() > 0.01) & ((q.wo * n).sum(-1).abs() > 0.01)
    return keep


def _parity(model, footprint: bool, source=None) -> float:
    g = torch.Generator().manual_seed(1)
    wi, wo = _dirs(N, g), _dirs(N, g)
    uv = torch.rand(N, 2, generator=g) * 3 - 1
    fp = _footprints(N, g) if footprint else None
    got = _runtime_eval(model, wi, wo, uv, fp, source)
    q = Query(wi, wo, uv=uv, footprint=fp)
    with torch.no_grad():
        ref = model.eval(q).double()
        keep = _keep(model, q) & (ref.abs().amax(-1) > 0)
    assert int(keep.sum()) > 0.8 * N
    # where the reference is 0 (below a shading horizon) the runtime must be 0 too
    assert float(got[(ref == 0).all(-1) & _keep(model, q)].abs().sum()) == 0.0
    with torch.no_grad():  # the same model in fp64: the runtime is closer to it than torch's fp32 is
        ref64 = copy.deepcopy(model).double().eval(Query(wi.double(), wo.double(), uv=uv.double(),
                                                         footprint=None if fp is None else fp.double()))
    return tuple(float(((got - r).abs() / r.abs().clamp(min=1e-30))[keep].max()) for r in (ref, ref64))


CASES = [(NeuMIP, {}), (NeuMIPOffset, {}), (NeuMIPFrame, {}), (NeuMIPFrame, {"frames": 2}), (NBRDFUV, {}),
         (NeuMIP, {"level_selection": "roulette"}), (NeuMIPOffset, {"level_selection": "roulette"}),
         (NBRDFUV, {"shading_frame": True}), (GGXMipmap, {}), (NeuralAppearance, {"spatial_size": 64}),
         (NeuralAppearance, {"spatial_size": 64, "albedo": True, "level_selection": "roulette"})]
IDS = ["neumip", "neumip-offset", "neumip-frame", "neumip-frame 2 frames", "nbrdf-uv", "neumip roulette",
       "neumip-offset roulette", "nbrdf-uv frame", "ggx-mipmap",
       "neural-appearance eval", "neural-appearance albedo roulette"]


@pytest.mark.parametrize("footprint", [False, True], ids=["finest level", "footprint"])
@pytest.mark.parametrize("cls, config", CASES, ids=IDS)
def test_runtime_matches_torch(drjit_llvm, cls, config, footprint):
    fp32, fp64 = _parity(_model(cls, **config), footprint)
    assert fp32 < 1e-4 and fp64 < 4e-5


def test_export_files_round_trip_and_refusal(drjit_llvm, tmp_path):
    from neumat.core.errors import InputError
    from neumat.export.drjit.format import export_drjit
    model = _model(NeuMIPOffset, spatial_size=16, max_probes=4, shading_frame=True)
    written = export_drjit(model, "fp32").write(tmp_path / "drjit")
    assert _parity(model, True, source=written)[0] < 1e-4

    class Decoded(NeuMIP):  # a subclass that decodes differently
        def decode_outputs(self, z_s, q):
            return 2 * super().decode_outputs(z_s, q)
    with pytest.raises(InputError, match="no Dr.Jit runtime"):
        export_drjit(Decoded(spatial_size=8))
