"""Scratch, validation only: the physics unroller's PSNR (Python mirror, up to 8 instants a sequence,
intra and inter together) at multiples of the estimated contrast and at the simulator's true one
(the mean of c_on and c_off; the second generator's `contrast`). Arguments: sequence folders."""
import os
import sys
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))), 'tools'))
import numpy as np
import physics_numpy as pn
from sequence_data import Sequence, list_sequences
from natural_eval import psnr, kind_of, noise_of
MUL = (0.7, 0.85, 1.0, 1.15, 1.3, 1.5, 1.75, 2.0)
tot = {}
for p in list_sequences(sys.argv[1:]):
    seq = Sequence(p); gamma = pn.meta_gamma(seq)
    c, eps = pn.estimate_physics(seq, None, gamma)
    em = seq.meta['source'].get('settings', {}).get('event_model', {})
    truth = 0.5*(em['c_on']+em['c_off']) if em else seq.meta['source'].get('contrast')
    full = (0, 0, seq.width, seq.height)
    res = np.zeros(len(MUL)+1); n = 0
    for i, (gp, t) in enumerate(seq.gt[:8]):
        k = pn.frame_for_time(seq, list(range(seq.num_frames)), t)
        s, e = seq.row_times(k)
        ev = seq.events_in(np.floor(min(s.min(), t)), np.ceil(max(e.max(), t)) + 1, full)
        sg = pn.exposure_segments(ev, s, e, t, full)
        img, gt = seq.frame(k), seq.gt_image(i)
        for j, cc in enumerate([c*m for m in MUL] + [truth]):
            res[j] += psnr(pn.apply_log_ratio(img, pn.log_ratio_from_segments(sg, cc), gamma, log_offset=eps), gt)
        n += 1
    res /= n
    key = noise_of(seq)
    tot.setdefault(key, []).append(res)
    best = MUL[int(np.argmax(res[:-1]))]
    print(f"{os.path.basename(p):12s} {kind_of(seq):16s} {key:9s} est {c:.3f} eps {eps:g} truth {truth:.3f} ({truth/c:.2f}x) best x{best} "
          + ' '.join(f'{v:.2f}' for v in res), flush=True)
for k, v in tot.items():
    print(k, len(v), ' '.join(f'{x:.2f}' for x in np.mean(v, 0)))
