"""Real-time neural appearance models (Zeltner et al., TOG 2024) and the proxy sampler they drive; notes in
NOTES.md."""
from neumat.fit.method import Method, register_method
from neumat.methods.latent_mlp.glsl import export_latent_mlp
from neumat.methods.neural_appearance import drjit, proxy_recipe, train
from neumat.methods.neural_appearance.model import NeuralAppearance

register_method(Method("neural-appearance", NeuralAppearance, {"paper": train.RECIPE, "cpu": train.CPU_RECIPE},
                       options=train.Options, phases=train.phases, config_for_source=train.config_for_source,
                       glsl=export_latent_mlp, small=dict(spatial_size=8),
                       drjit=drjit.translate))  # program "neural-appearance": the decoder and its sampler
register_method(Method("proxy-sampler", None, {"paper": proxy_recipe.RECIPE, "cpu": proxy_recipe.CPU_RECIPE},
                       options=proxy_recipe.Options, phases=proxy_recipe.phases))
