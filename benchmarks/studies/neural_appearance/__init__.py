"""Frozen one-off studies (see README.md); run as modules: python -m benchmarks.studies.<topic>.<script>."""
