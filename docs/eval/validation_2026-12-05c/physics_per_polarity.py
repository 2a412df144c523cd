"""Scratch, validation only: does a contrast per polarity (c_on, c_off, each the L1 fit of the estimator
on the pixels whose net events have that sign) help the physics unroller? The Python mirror, up to 8
instants a sequence; prints per sequence and the intra / inter means. Arguments: sequence folders."""
import os
import sys
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))), 'tools'))
import numpy as np
import physics_numpy as pn
from sequence_data import Sequence, list_sequences
from natural_eval import psnr, kind_of, noise_of

def fit(seq, gamma):
    """The CLI's (c, eps) and, at that eps, the L1 fit of each polarity's pixels alone."""
    c, eps = pn.estimate_physics(seq, None, gamma)
    la, lb, n = pn.signal_samples(seq, None, gamma)
    d = np.log(lb + eps) - np.log(la + eps)
    on, off = n > 0, n < 0
    c_on = pn._weighted_median((d/n)[on], np.abs(n[on]).astype(float)) if on.sum() > 50 else c
    c_off = pn._weighted_median((d/n)[off], np.abs(n[off]).astype(float)) if off.sum() > 50 else c
    return c, eps, c_on, c_off, int(on.sum()), int(off.sum())

def segs2(ev, s, e, t_star, crop):
    """exposure_segments twice: levels of ON and OFF events separately (same segment boundaries)."""
    t, x, y, p = ev
    sp = pn.exposure_segments(ev, s, e, t_star, crop)  # level F = F_on - F_off
    # every event counted +1: level F_on + F_off, on the same segments
    sa = pn.exposure_segments((t, x, y, np.ones_like(np.asarray(p))), s, e, t_star, crop)
    assert np.array_equal(sp[0], sa[0])
    lvl_on = (sp[2] + sa[2]) / 2.0; lvl_off = (sa[2] - sp[2]) / 2.0
    return sp, lvl_on, lvl_off

def lr_from(segs, lvl_on, lvl_off, c_on, c_off):
    """log_ratio_from_segments with the level c_on F_on - c_off F_off (contrast 1)."""
    seg_pix, log_len, _, T, h, w = segs
    return pn.log_ratio_from_segments((seg_pix, log_len, c_on * lvl_on - c_off * lvl_off, T, h, w), 1.0)

rows = []
for p in list_sequences(sys.argv[1:]):
    seq = Sequence(p); gamma = pn.meta_gamma(seq)
    c, eps, con, coff, non, noff = fit(seq, gamma)
    em = seq.meta['source'].get('settings', {}).get('event_model', {})
    full = (0, 0, seq.width, seq.height)
    gts = seq.gt[:8]
    for i, (gp, t) in enumerate(gts):
        k = pn.frame_for_time(seq, list(range(seq.num_frames)), t)
        s, e = seq.row_times(k)
        ev = seq.events_in(np.floor(min(s.min(), t)), np.ceil(max(e.max(), t)) + 1, full)
        sp, lon, loff = segs2(ev, s, e, t, full)
        img = seq.frame(k); gt = seq.gt_image(i)
        sym = pn.apply_log_ratio(img, pn.log_ratio_from_segments(sp, c), gamma, log_offset=eps)
        asy = pn.apply_log_ratio(img, lr_from(sp, lon, loff, con, coff), gamma, log_offset=eps)
        S, E = seq.frame_span(k); tau = (t - S)/(E - S)
        rows.append((os.path.basename(p), kind_of(seq), noise_of(seq), 0 <= tau <= 1, psnr(sym, gt), psnr(asy, gt)))
    print(os.path.basename(p), kind_of(seq), noise_of(seq), 'c %.3f eps %g  on %.3f (%d) off %.3f (%d) truth on %s off %s' % (c, eps, con, non, coff, noff, em.get('c_on'), em.get('c_off')),
          'sym %.2f asym %.2f' % (np.mean([r[4] for r in rows if r[0]==os.path.basename(p)]), np.mean([r[5] for r in rows if r[0]==os.path.basename(p)])), flush=True)
for part in (True, False):
    for nz in ('clean', None):
        sel = [r for r in rows if r[3] == part and (nz is None or r[2] == nz)]
        if sel: print('intra' if part else 'inter', nz or 'all', len(sel), 'sym %.2f asym %.2f' % (np.mean([r[4] for r in sel]), np.mean([r[5] for r in sel])))
