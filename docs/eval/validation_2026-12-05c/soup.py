#!/usr/bin/python3
"""Scratch, no training: a weighted mean of models of one architecture (a "model soup",
Wortsman et al. 2022), written with the first model's metadata. Usage:
soup.py OUT.safetensors W1=MODEL1 W2=MODEL2 ... (weights normalised to sum 1)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__))))), "tools"))
import safetensors_io  # noqa: E402


def main(out: str, specs) -> None:
    parts = [(float(w), safetensors_io.load(p)) for w, p in (s.split("=", 1) for s in specs)]
    total = sum(w for w, _ in parts)
    first, meta = parts[0][1]
    for w, (t, _) in parts[1:]:
        if sorted(t) != sorted(first) or any(t[k].shape != first[k].shape for k in first):
            raise SystemExit(f"{out}: the models differ in their tensors")
    mixed = {k: (sum(w * t[k].double() for w, (t, _) in parts) / total).to(v.dtype) if v.is_floating_point() else v
             for k, v in first.items()}
    meta = dict(meta)
    meta["training.soup"] = " + ".join(specs)
    safetensors_io.save(out, mixed, meta)
    print(f"{out}: mean of {len(parts)} models")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
