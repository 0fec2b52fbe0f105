"""The toy method's recipe: Adam on log-cosine-weighted errors."""
from neumat.fit.recipe import Recipe

RECIPE = Recipe(steps=200, batch_size=1024, lr=0.05, loss="log_cos", log_every=20, checkpoint_every=100)
