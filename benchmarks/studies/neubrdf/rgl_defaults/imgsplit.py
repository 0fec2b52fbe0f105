"""Where the image error of fitted models sits: rim (theta_o > 70 deg) vs centre, linear brightness ratios.
usage: imgsplit.py SRC TAG [TAG...]  (models /tmp/rglexp/TAG.nmat)"""
import sys, json, os
import numpy as np, torch
import neumat
from neumat.render.comparison import comparison_images
from neumat.metrics.image import to_ldr
torch.set_num_threads(1)
src_path, tags = sys.argv[1], sys.argv[2:]
src = neumat.open_material(src_path)
name = os.path.basename(src_path).split('.')[0]
cache = f'/tmp/rglexp/ref_{name}.npy'
if os.path.exists(cache):
    ref = np.load(cache)
else:
    ref = comparison_images({'r': src}, 512, 128, 0)['r'].numpy(); np.save(cache, ref)
H = ref.shape[0]
c = (np.arange(H) + 0.5) / H * 2 - 1
X, Y = np.meshgrid(c, c)
r = np.sqrt(X ** 2 + Y ** 2)
sphere = r < 1
rim = sphere & (r > np.sin(np.radians(70)))
centre = sphere & ~rim
ref_l = to_ldr(ref).astype(np.float64)
out = {}
for tag in tags:
    m = neumat.open_material(f'/tmp/rglexp/{tag}.nmat')
    img = comparison_images({'t': m}, 512, 128, 0)['t'].numpy()
    np.save(f'/tmp/rglexp/img_{tag}.npy', img)
    e = np.abs(to_ldr(img).astype(np.float64) - ref_l).mean(-1)
    res = {'mae': float(e.mean()), 'rim_pixel_frac': float(rim.mean()),
           'mae_share_rim': float(e[rim].sum() / e.sum()), 'mae_share_centre': float(e[centre].sum() / e.sum()),
           'mae_rim': float(e[rim].mean()), 'mae_centre': float(e[centre].mean()),
           'lin_ratio_centre_rgb': [float(img[centre][:, k].sum() / ref[centre][:, k].sum()) for k in range(3)],
           'lin_ratio_rim_rgb': [float(img[rim][:, k].sum() / ref[rim][:, k].sum()) for k in range(3)]}
    out[tag] = res
    print(tag, json.dumps(res), flush=True)
json.dump(out, open(f'/tmp/rglexp/imgsplit_{"_".join(tags)[:80]}.json', 'w'), indent=1)
