"""Spec strings: every material and preset parses, describe() round-trips, every error path is clear."""
import pytest
import torch

from neumat import InputError, Query, UnknownNameError
from neumat.reflectance.analytic import CONDUCTORS, GGX, Lambert, Plastic, Principled
from neumat.reflectance.spec import SPEC_NAMES, parse_spec


def test_spec_names():
    assert SPEC_NAMES == ("lambert", "ggx", "plastic", "principled")


@pytest.mark.parametrize("spec,cls,attrs", [
    ("lambert", Lambert, {"albedo": (0.5, 0.5, 0.5)}),
    ("Lambert: albedo = 0.8/0.5/0.2 ", Lambert, {"albedo": (0.8, 0.5, 0.2)}),
    ("ggx:roughness=0.2,fresnel=dielectric,eta=1.5", GGX, {"alpha_x": 0.2, "alpha_y": 0.2, "eta": 1.5}),
    ("ggx:alpha_x=0.3,alpha_y=0.05,material=gold", GGX,
     {"alpha_x": 0.3, "alpha_y": 0.05, "eta": CONDUCTORS["gold"][0]}),
    ("ggx:eta=0.2/0.9/1.1,k=3.9/2.4/2.1", GGX, {"k": (3.9, 2.4, 2.1)}),
    ("ggx:fresnel=schlick,f0=0.9", GGX, {"f0": (0.9, 0.9, 0.9)}),
    ("ggx:fresnel=none,roughness=0.5", GGX, {"fresnel": "none"}),
    ("plastic:diffuse=0.1/0.3/0.8,roughness=0.1,eta=1.33", Plastic, {"eta": 1.33, "roughness": 0.1}),
    ("principled:base_color=0.9/0.6/0.2,metallic=1,roughness=0.4,anisotropy=0.5", Principled,
     {"metallic": 1.0, "anisotropy": 0.5}),
])
def test_parse(spec, cls, attrs):
    m = parse_spec(spec)
    assert type(m) is cls
    for k, v in attrs.items():
        assert getattr(m, k) == v


@pytest.mark.parametrize("name", sorted(CONDUCTORS))
def test_conductor_presets(name):
    assert parse_spec(f"ggx:roughness=0.2,material={name}").k == CONDUCTORS[name][1]


@pytest.mark.parametrize("spec", ["lambert:albedo=0.3", "ggx",
                                  "ggx:alpha_x=0.1,alpha_y=0.7,fresnel=schlick,f0=0.1/0.2/0.3",
                                  "ggx:eta=0.2/0.9/1.1,k=3.9/2.4/2.1,roughness=0.123456789",
                                  "plastic", "principled:anisotropy=0.3,specular=0.1"])
def test_describe_round_trips(spec):
    m = parse_spec(spec)
    again = parse_spec(m.describe())
    assert again.describe() == m.describe()
    wi = torch.nn.functional.normalize(torch.tensor([[0.3, 0.1, 0.9], [0.0, 0.5, 0.7]]), dim=-1)
    wo = torch.nn.functional.normalize(torch.tensor([[-0.2, 0.1, 0.8], [0.4, -0.5, 0.6]]), dim=-1)
    torch.testing.assert_close(m.eval(Query(wi, wo)), again.eval(Query(wi, wo)), rtol=0, atol=0)


@pytest.mark.parametrize("spec,error,match", [
    ("", InputError, "non-empty"),
    (None, InputError, "non-empty"),
    ("lamber", UnknownNameError, "did you mean lambert"),
    ("velvet", UnknownNameError, "known: lambert, ggx, plastic, principled"),
    ("ggx:rougness=0.2", UnknownNameError, "did you mean roughness"),
    ("ggx:roughness", InputError, "key=value"),
    ("ggx:roughness=", InputError, "key=value"),
    ("ggx:=0.2", InputError, "key=value"),
    ("ggx:roughness=0.2,roughness=0.3", InputError, "twice"),
    ("ggx:roughness=abc", InputError, "expected a number"),
    ("ggx:roughness=0.1/0.2/0.3", InputError, "expected a number"),
    ("ggx:roughness=5", InputError, "roughness"),
    ("lambert:albedo=1/2", InputError, "RGB triple"),
    ("lambert:albedo=a/b/c", InputError, "RGB triple"),
    ("lambert:albedo=0.5/0.5/1.5", InputError, "albedo"),
    ("ggx:fresnel=schlik", UnknownNameError, "did you mean schlick"),
    ("ggx:material=gld", UnknownNameError, "did you mean gold"),
    ("ggx:fresnel=dielectric,k=1", InputError, "do not apply"),
    ("plastic:eta=0.5", InputError, "eta"),
    ("principled:metallic=-1", InputError, "metallic"),
])
def test_errors(spec, error, match):
    with pytest.raises(error, match=match):
        parse_spec(spec)
