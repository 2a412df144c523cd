#!/usr/bin/python3
"""Post hoc, validation only: the model's S and M results averaged with those of the left-right
mirrored inputs (RS frames, event tensors and physics log ratio flipped; rows keep their times),
un-mirrored, in the model's encoding. --model NAME=FILE whose NAME starts with "flip" runs so;
other names run as tools/natural_eval.py does. Arguments: natural_eval.py's."""
import os
import sys

import numpy as np
import torch

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import natural_eval  # noqa: E402
import train  # noqa: E402

unroll_pair = natural_eval.unroll_pair


def ensemble_pair(net, seq, k, t_star, texp, bins, crop, info):
    if not net.eval_name.startswith("flip"):  # natural_eval names each net by its --model NAME
        return unroll_pair(net, seq, k, t_star, texp, bins, crop, info)
    dv = next(net.parameters()).device
    smp = train.make_sample(seq, k, crop, t_star, texp, bins, None, info, net.cfg.gamma, net.cfg.physics_input)
    ev = [torch.from_numpy(np.stack([smp.ev["g1"][i], smp.ev["g2"][i]])).to(dv) for i in range(3)]
    lr = train.stack_lr([smp], ("g1", "g2"), dv)
    rs = torch.from_numpy(np.stack([smp.rs1, smp.rs2])).to(dv)
    back = lambda x: train.from_model_encoding(x, info.gamma, net.cfg.gamma).cpu()  # noqa: E731
    f = lambda x: None if x is None else torch.flip(x, dims=[-1])  # noqa: E731
    outs = []
    with torch.no_grad():
        for mirror in (False, True):
            g = f if mirror else (lambda x: x)
            o = train.run_s(net, g(rs), [g(e) for e in ev], g(lr))
            a, b = train.split(o, 1)
            outs.append({"s1": g(a["fused"]), "s2": g(b["fused"]), "m": g(train.moa(net, a, b))})
    res = {key: back(0.5 * (outs[0][key] + outs[1][key])) for key in outs[0]}
    res["rs1"] = torch.from_numpy(train.crop_img(seq.frame(k), crop))[None]
    res["rs2"] = torch.from_numpy(train.crop_img(seq.frame(k + 1), crop))[None]
    return res


natural_eval.unroll_pair = ensemble_pair
if __name__ == "__main__":
    sys.exit(natural_eval.main())
