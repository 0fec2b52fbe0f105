"""SparseBTF (Kavoosi et al.): sparse coefficients in an ensemble of 4D dictionaries, and the PCA baseline it is
compared with at equal bytes; notes in NOTES.md."""
from neumat.fit.method import Method, register_method
from neumat.methods.sparse_btf import drjit, pca_train, train
from neumat.methods.sparse_btf.glsl import export_sparse_btf
from neumat.methods.sparse_btf.model import SparseBTF
from neumat.methods.sparse_btf.pca import PCABTF

register_method(Method("sparse-btf", SparseBTF, {"paper": train.RECIPE, "cpu": train.CPU_RECIPE},
                       options=train.Options, phases=train.phases, config_for_source=train.config_for_source,
                       glsl=export_sparse_btf, drjit=drjit.translate,
                       small=dict(patch=5, num_dictionaries=2, tau=[8, 4, 4], tau_train=[8, 4, 4])))
register_method(Method("pca-btf", PCABTF, {"paper": pca_train.RECIPE, "cpu": pca_train.CPU_RECIPE},
                       options=pca_train.Options, phases=pca_train.phases,
                       config_for_source=pca_train.config_for_source))
