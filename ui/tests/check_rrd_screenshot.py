"""Checks a headless rerun viewer's screenshot of a facesim recording (tests/rrd.rs): the face
fills the 3D view the default blueprint puts on the left three quarters of the window, seen
from the front.

Usage: check_rrd_screenshot.py SCREENSHOT.png
Prints "ok" or fails with the measured share of face pixels.
"""

import sys

import numpy as np
from PIL import Image  # pillow comes with rerun-sdk

image = np.asarray(Image.open(sys.argv[1]).convert("RGB")).astype(int)
height, width, _ = image.shape
# The 3D view's area at --window-size 1200x800 (below the top bar, left of the plots).
view = image[int(0.065 * height) : int(0.686 * height), int(0.166 * width) : int(0.604 * width)]
# The skin's base colour, lit: bright, red over green over blue (the background and grid are
# dark or green-tinted; the eyes and the mouth's inside are not counted).
r, g, b = view[..., 0], view[..., 1], view[..., 2]
skin = (r > 120) & (r > g) & (g > b) & (r - b > 25)
share = skin.mean()
# Upright and large: 36 % on the sample (the whole head); seen from below in a small view it
# was 5 %.
assert share > 0.2, f"the face covers {share:.1%} of the 3D view's area (expected > 20 %)"
# From the front, the silhouette is its own mirror image about its centre column: the overlap
# of the two (intersection over union) is 0.93 on the sample, 0.71 in rerun's default
# three-quarter view.
columns = np.arange(skin.shape[1])
mirror_of = np.round(2 * skin.nonzero()[1].mean() - columns).astype(int)
inside = (mirror_of >= 0) & (mirror_of < skin.shape[1])
mirrored = np.zeros_like(skin)
mirrored[:, inside] = skin[:, mirror_of[inside]]
symmetry = (skin & mirrored).sum() / (skin | mirrored).sum()
assert symmetry > 0.85, f"the face is not seen from the front (mirror overlap {symmetry:.2f})"
print(f"ok: the face covers {share:.1%} of the 3D view, mirror overlap {symmetry:.2f}")
