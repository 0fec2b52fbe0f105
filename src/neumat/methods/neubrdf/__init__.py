"""NeuBRDF (Dou, Zheng et al., CVPR 2024) and its jointly trained multi-material form; notes in NOTES.md."""
from neumat.fit.method import Method, register_method
from neumat.methods.neubrdf import shared_train, train
from neumat.methods.neubrdf.drjit import translate as drjit_translate, translate_shared as drjit_translate_shared
from neumat.methods.neubrdf.glsl import export_neubrdf
from neumat.methods.neubrdf.model import NeuBRDF
from neumat.methods.neubrdf.shared_model import SharedNeuBRDF

register_method(Method("neubrdf", NeuBRDF, {"paper": train.RECIPE, "cpu": train.CPU_RECIPE, **train.NAMED_RECIPES},
                       options=train.Options, phases=train.phases, presets=train.PRESETS, glsl=export_neubrdf,
                       drjit=drjit_translate,
                       small=dict(nside=2, index_bits=2, hidden=4),
                       measured="the default for BRDFs: image MAE at the reference's own noise floor on 25 MERL-like "
                                "tables (NBRDF 1.5x it) and 1.05x the floor on five measured RGL files (NBRDF 2.7x), "
                                "two seeds each (docs/neubrdf.md, the benchmark suite's Table 3)"))
register_method(Method("shared-neubrdf", SharedNeuBRDF, {"paper": shared_train.RECIPE, "cpu": shared_train.CPU_RECIPE},
                       options=shared_train.Options, phases=shared_train.phases,
                       config_for_source=shared_train.config_for_source, presets=shared_train.PRESETS,
                       drjit=drjit_translate_shared,
                       small=dict(num_materials=2, nside=2, index_bits=2, hidden=4)))
