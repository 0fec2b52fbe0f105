"""Real-time neural appearance models (Zeltner et al., TOG 2024) and the proxy sampler they drive; notes in
NOTES.md."""
from neumat.fit.method import Method, register_method
from neumat.fit.preset import Preset
from neumat.methods.latent_mlp.glsl import export_latent_mlp
from neumat.methods.neural_appearance import drjit, proxy_recipe, train
from neumat.methods.neural_appearance.model import NeuralAppearance

#: the `recommended` preset on a CPU: the latents phase at 1e-2, the encoder phase at the recipe's 3e-3 (session 67,
#: the neural-appearance suite's protocol on the six 256^2 sets, seed 0: image FLIP 0.68-0.94x that of 3e-3 in both
#: phases; 1e-2 in both killed the network on Metal027: NOTES.md, "learning rate")
CPU_RATES = {"recipe.lr": 1e-2, "option.encoder_lr_scale": 0.3}
RECOMMENDED = Preset("the paper's model and its CPU-sized recipe, the latents phase at learning rate 1e-2 instead of "
                     "3e-3 on a CPU (a lower image FLIP on every set measured; the encoder phase keeps 3e-3)",
                     by_recipe={"cpu": CPU_RATES})

register_method(Method("neural-appearance", NeuralAppearance, {"paper": train.RECIPE, "cpu": train.CPU_RECIPE},
                       options=train.Options, phases=train.phases, config_for_source=train.config_for_source,
                       glsl=export_latent_mlp, small=dict(spatial_size=8), presets={"recommended": RECOMMENDED},
                       drjit=drjit.translate))  # program "neural-appearance": the decoder and its sampler
register_method(Method("proxy-sampler", None, {"paper": proxy_recipe.RECIPE, "cpu": proxy_recipe.CPU_RECIPE},
                       options=proxy_recipe.Options, phases=proxy_recipe.phases))
