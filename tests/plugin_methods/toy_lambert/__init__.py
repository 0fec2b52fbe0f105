"""A test-only method: a Lambertian lobe with a fitted RGB albedo, registered from outside the package."""
from neumat.fit.method import Method, register_method
from neumat.fit.preset import Preset

from toy_lambert.glsl import export_toy_lambert
from toy_lambert.model import ToyLambert
from toy_lambert.train import RECIPE

register_method(Method("toy-lambert", ToyLambert, {"paper": RECIPE, "cpu": RECIPE}, glsl=export_toy_lambert,
                       presets={"recommended": Preset("the only recipe, with a larger learning rate",
                                                      overrides={"recipe.lr": 0.1})},
                       small=dict(albedo=0.3)))
