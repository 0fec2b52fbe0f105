"""The catalog: the one place that turns a name or a path into a Material or a model.

`open_material(name)` looks the file suffix (or the folder / analytic-spec kind) up in the `SOURCES` registry
(`neumat.catalog.sources`); `.nmat` model files are saved and loaded by `neumat.catalog.modelfile`.
"""
