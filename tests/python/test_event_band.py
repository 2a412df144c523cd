"""tools/physics_numpy.event_band, the post-hoc clamp `natural_eval.py --bands` scores (tried on
validation on 2026-12-04 and not adopted, docs/journal/training.md): each pixel is kept within
lin(phys) * exp(+-w c) in linear intensity + offset, values inside pass unchanged, and the band
widens with w and with the log offset for dark pixels."""
import os

import numpy as np

from tools.model import physics_numpy as pn

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def lin(v, g, eps):
    return np.power(np.maximum(v, 0.0), g) + eps


def test_output_lies_in_the_band_and_inside_values_pass():
    rng = np.random.default_rng(3)
    phys = rng.uniform(0.0, 1.2, (3, 9, 11))
    img = rng.uniform(0.0, 1.0, (3, 9, 11))
    for g, eps, c, w in ((1.0, 0.0, 0.2, 1.0), (2.2, 0.05, 0.25, 2.0), (2.2, 0.0, 0.15, 0.5)):
        out = pn.event_band(img, phys, c, g, eps, w).astype(np.float64)
        ratio = lin(out, g, eps) / lin(phys, g, eps)
        assert np.all(ratio <= np.exp(w * c) * (1 + 1e-5)) and np.all(ratio >= np.exp(-w * c) * (1 - 1e-5))
        inside = np.abs(np.log(lin(img, g, eps) / lin(phys, g, eps))) < w * c * 0.999
        assert inside.any() and np.allclose(out[inside], img[inside], rtol=0, atol=1e-6)
        assert np.any(~inside) and not np.allclose(out[~inside], img[~inside])


def test_the_band_widens_with_its_width_and_the_offset():
    phys = np.full((1, 1, 1), 0.02)
    far = np.full((1, 1, 1), 0.9)
    narrow = pn.event_band(far, phys, 0.2, 1.0, 0.0, 1.0)[0, 0, 0]
    wide = pn.event_band(far, phys, 0.2, 1.0, 0.0, 2.0)[0, 0, 0]
    offset = pn.event_band(far, phys, 0.2, 1.0, 0.1, 1.0)[0, 0, 0]
    assert narrow < wide < 0.9 and narrow < offset < 0.9
