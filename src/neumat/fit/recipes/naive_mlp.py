"""Training recipe of the naive MLP baseline (no paper: NeuBRDF-like online fit, NBRDF's loss)."""
from neumat.fit.recipe import Recipe

#: Adam 1e-3 with a cosine decay over 20k steps of 8192 cosine-weighted queries, log(1 + f cos) L1 loss.
RECIPE = Recipe(steps=20_000, batch_size=8192, lr=1e-3, schedule="cosine", lr_min=1e-5,
                loss="log_cos", queries="cosine")
