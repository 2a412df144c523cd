#!/usr/bin/python3
# Run from the repository root: /usr/bin/python3 docs/eval/validation_2026-12-05/moa_gate.py data/natural/val2,data/natural/val3 8 OUT.json
"""Experiment (not shipped): MOA blend aware of the event gate, scored on validation sequences.
w1 = (1 - g1) + g1 * g2 * m. One mirror pass per GT instant gives both outputs."""
import sys, os, json, tempfile
sys.path.insert(0, "tools")
import numpy as np, torch
import selfunroll_torch as st
import natural_eval as ne
import physics_numpy as pn
from sequence_data import Sequence, list_sequences
from train import unroll_pair, from_model_encoding
from train_data import SeqInfo

stash = {}
_orig_gate = st.event_gate
def gate(ev1, ev2, r):
    g = _orig_gate(ev1, ev2, r); stash["g"] = g; return g
st.event_gate = gate
_orig_blend = st.SelfUnroll.moa_blend
def moa_blend(self, E1, E2, ev1_1, ev1_2, flow1, flow2, fused1, fused2, force_m=None, grad_leak=0.0):
    m, out = _orig_blend(self, E1, E2, ev1_1, ev1_2, flow1, flow2, fused1, fused2, force_m, grad_leak)
    g1, g2 = stash["g"][0:1], stash["g"][1:2]
    w1 = (1 - g1) + g1 * g2 * m
    stash["mgate"] = w1 * fused1 + (1 - w1) * fused2
    return m, out
st.SelfUnroll.moa_blend = moa_blend

data, limit, out_json = sys.argv[1].split(","), int(sys.argv[2]), sys.argv[3]
torch.set_num_threads(2)
net = ne.load_model("models/selfunroll_small_physics.safetensors")
own = net.cfg.physics_gate
rows = []
with tempfile.TemporaryDirectory() as work:
    for p in list_sequences(data):
        seq = Sequence(p, cache_images=True)
        gamma = pn.meta_gamma(seq)
        ph = ne.cli_metrics("build/vkunroll", seq, work, "physics")
        phs = ph["_summary"]["physics"]
        c = float(phs["contrast"])
        net.cfg.physics_gate = ne.auto_gate_radius(phs, own)
        info = SeqInfo(seq); info.gamma = gamma; info.contrast = lambda c=c: c
        gts = list(enumerate(seq.meta.get("ground_truth") or []))
        step = max(1, len(gts) // limit) if limit else 1
        for i, g in gts[::step]:
            t = float(g["t_us"])
            k = pn.frame_for_time(seq, list(range(seq.num_frames)), t)
            if k + 1 >= seq.num_frames:
                continue
            tau = float(g.get("tau", (t - seq.frame_span(k)[0]) / (seq.frame_span(k)[1] - seq.frame_span(k)[0])))
            gt = seq.gt_image(i)
            r = unroll_pair(net, seq, k, t, seq.exposure, net.cfg.N, (0, 0, seq.width, seq.height), info)
            mg = from_model_encoding(stash["mgate"], info.gamma, net.cfg.gamma).cpu()[0].numpy()
            m = [v for tt, v in ph.items() if tt != "_summary" and abs(tt - t) < 0.5][0]
            rows.append({"seq": os.path.basename(p), "kind": ne.kind_of(seq), "noise": ne.noise_of(seq),
                         "intra": 0 <= tau <= 1, "radius": net.cfg.physics_gate,
                         "physics": float(m["psnr"]), "S": ne.psnr(r["s1"][0].numpy(), gt),
                         "M": ne.psnr(r["m"][0].numpy(), gt), "Mgate": ne.psnr(mg, gt)})
        sub = [x for x in rows if x["seq"] == os.path.basename(p)]
        print(os.path.basename(p), ne.kind_of(seq), ne.noise_of(seq), "r", net.cfg.physics_gate,
              " ".join(f"{k}={np.mean([x[k] for x in sub]):.2f}" for k in ("physics", "S", "M", "Mgate")), flush=True)
json.dump(rows, open(out_json, "w"))
import collections
grp = collections.defaultdict(list)
for x in rows:
    grp[(x["kind"], "intra" if x["intra"] else "inter")].append(x)
    grp[("all", "intra" if x["intra"] else "inter")].append(x)
for key in sorted(grp):
    xs = grp[key]
    print(key, len(xs), " ".join(f"{k}={np.mean([x[k] for x in xs]):.2f}" for k in ("physics", "S", "M", "Mgate")))
