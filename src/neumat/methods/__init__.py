"""The methods: one folder per method family (model, training, presets, export hooks, NOTES.md), each registering
its `neumat.fit.method.Method`s when imported (`neumat.models.registry.load_all` imports them all)."""
