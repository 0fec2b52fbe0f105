"""Material.eval(q) on learned models coexists with torch's Module.eval() (inference mode)."""
import pytest
import torch
from torch import nn

from neumat.catalog.open_material import open_material
from neumat.core.material import Material, check_sample_u
from neumat.core.query import Query
from neumat.io.shared_data import shared_data_dir
from neumat.models.registry import build_model, load_all
from neumat.warp.hemisphere import sample_cosine_hemisphere

SMALL = {"multiscale": {"spatial_size": 8}, "tripleplane": {"spatial_size": 8}, "neumip-frame": {"spatial_size": 8},
         "neumip": {"spatial_size": 8}, "nbrdf-uv": {"spatial_size": 8}, "ggx-mipmap": {"spatial_size": 8}}


class Constant(nn.Module, Material):
    def __init__(self):
        super().__init__()
        self.value = nn.Parameter(torch.full((3,), 0.25))

    def eval(self, q: Query) -> torch.Tensor:
        return self.value.expand(len(q.wi), 3)

    def forward(self, q: Query) -> torch.Tensor:
        return self.eval(q)


def test_module_eval_without_query_switches_mode_and_with_query_evaluates():
    m = Constant()
    assert m.training
    assert m.eval() is m and not m.training
    q = Query(wi=torch.tensor([[0.0, 0.0, 1.0]]), wo=torch.tensor([[0.0, 0.0, 1.0]]))
    assert torch.equal(m.eval(q), torch.full((1, 3), 0.25))
    assert torch.equal(m(q), torch.full((1, 3), 0.25))


@pytest.mark.parametrize("name", load_all().names())
def test_every_registered_model_accepts_module_eval(name):
    model = build_model({"type": name, **SMALL.get(name, {})})
    if not isinstance(model, nn.Module):
        pytest.skip(f"{name} is not a torch Module")
    model.train(True)
    assert model.eval() is model
    assert not any(m.training for m in model.modules())


def test_material_device_is_that_of_the_first_module_with_tensors():
    from neumat.core.material import material_device
    from neumat.reflectance.analytic import Lambert

    assert material_device(Lambert(0.5)) == torch.device("cpu")              # plain material: CPU
    meta = Constant().to("meta")
    assert material_device(Lambert(0.5), meta, Constant()) == torch.device("meta")
    buffers_only = nn.Module()
    buffers_only.register_buffer("table", torch.zeros(2, device="meta"))
    assert material_device(buffers_only) == torch.device("meta")

    class Wrapper(Material):                         # a plain Material holding modules declares its device
        device = torch.device("meta")

    assert material_device(Wrapper(), Constant()) == torch.device("meta")


def test_sample_takes_u_of_another_float_dtype_as_the_query_s():
    """A float64 u with a float32 query samples what the float32 u samples, on every kind of material (a texture
    set and a measured table used to refuse it with an error about Query.wo); u that rounds up to 1 in float32 is
    kept below 1."""
    g = torch.Generator().manual_seed(0)
    wi = sample_cosine_hemisphere(torch.rand(64, 2, generator=g))
    u64 = torch.rand(64, 2, generator=g, dtype=torch.float64)
    q = Query(wi, wi)
    specs = ["lambert", "ggx:roughness=0.3", "principled"]
    if shared_data_dir() is not None:  # a measured table (refused the float64 u before)
        specs.append(str(shared_data_dir() / "rgl" / "paper_white_rgb.bsdf"))
    for spec in specs:
        m = open_material(spec)
        a, b = m.sample(Query(wi), u64), m.sample(Query(wi), u64.float())
        assert a.wo.dtype == torch.float32 and torch.equal(a.wo, b.wo), spec
    near_one = torch.full((64, 2), 1 - 1e-12, dtype=torch.float64)
    u = check_sample_u(q, near_one)
    assert u.dtype == torch.float32 and bool((u < 1).all())
