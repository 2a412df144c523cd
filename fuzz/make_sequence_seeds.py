#!/usr/bin/env python3
"""Seeds of fuzz_sequence (fuzz/fuzz_sequence.hpp): `vkunroll simulate` folders packed as blobs
(meta.json, then "\\n@@FILE name\\n" + contents per file), with variants of meta.json.
Usage: make_sequence_seeds.py VKUNROLL OUT_DIR"""
import json
import os
import subprocess
import sys
import tempfile

MARK = b"\n@@FILE "


def pack(meta, files, last=b""):
    blob = json.dumps(meta, separators=(",", ":")).encode()
    for name, body in files:
        blob += MARK + name.encode() + b"\n" + body
    return blob + last


def main(cli, out):
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        seeds = {}
        for tag, extra in [("gray8", ["--gray"]), ("color16", ["--bit-depth", "16", "--readout", "bottom-up"])]:
            d = os.path.join(tmp, tag)
            subprocess.run([cli, "simulate", "--out", d, "--size", "8x6", "--frames", "2", "--gt-per-frame", "1",
                            "--events-format", "txt", "--seed", "3", "--quiet", *extra], check=True)
            meta = json.load(open(os.path.join(d, "meta.json")))
            meta.pop("source")  # provenance only; the loader does not read it
            names = ["events.txt"] + [f["file"] for f in meta["frames"]] + [g["file"] for g in meta["ground_truth"]]
            files = [(n, open(os.path.join(d, n), "rb").read()) for n in names]
            seeds[tag] = pack(meta, files)
            seeds[tag + "_unchecked_sort"] = pack(meta, files, b"\x07")  # last byte: generic, no size check, sort
            per_frame = dict(meta, frames=[dict(f, exposure_us="3000/7") for f in meta["frames"]], line_delay_us="73000/259")
            seeds[tag + "_rational"] = pack(per_frame, files)
            seeds[tag + "_no_gt"] = pack({k: v for k, v in meta.items() if k != "ground_truth"}, files[:3])
        for name, blob in seeds.items():
            with open(os.path.join(out, "seed_" + name), "wb") as f:
                f.write(blob)
    print(f"{len(seeds)} seeds in {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
