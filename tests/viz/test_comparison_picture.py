"""`neumat.viz.compare.comparison_picture`: the one-row picture of an image comparison (fit-many, eval --picture)."""
from __future__ import annotations

import numpy as np


def test_comparison_picture_is_one_row_of_the_reference_model_and_both_error_maps():
    """reference | model | the model's FLIP error | the floor's: an exact model's error panel is the floor-free black
    of the colour map, a wrong one's is not; the floor's error panel is the same whatever the model."""
    from neumat.viz.compare import MIN_PANEL_WIDTH, PAD, comparison_picture

    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 0.8, (16, 16, 3)).astype(np.float32)
    floor = np.clip(ref + rng.normal(0, 0.05, ref.shape), 0, 1).astype(np.float32)
    scores = {"flip": 0.0, "ssim": 1.0, "mae": 0.0, "floor_flip": 0.1, "floor_ssim": 0.9, "floor_mae": 0.04}
    exact = comparison_picture((ref, floor), ref, "model", scores)
    wrong = comparison_picture((ref, floor), 1 - ref, "model", scores)
    scale = MIN_PANEL_WIDTH // 16
    assert exact.shape == wrong.shape and exact.shape[1] == 4 * 16 * scale + 5 * PAD
    top = next(y for y in range(exact.shape[0]) if (exact[y, PAD:PAD + 16 * scale] != exact[0, 0]).all())  # panels
    panel = lambda img, k: img[top:top + 16 * scale, PAD + k * (16 * scale + PAD):(k + 1) * (16 * scale + PAD)]
    assert np.array_equal(panel(exact, 0), panel(exact, 1))  # the model is the reference
    assert panel(exact, 2).max() < 10 < panel(wrong, 2).max()  # magma's black where FLIP is 0
    assert np.array_equal(panel(exact, 3), panel(wrong, 3))  # the floor's error does not depend on the model
