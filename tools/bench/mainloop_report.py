"""Static report of the GPU convs' main loops: what one K-stage executes, per invocation.

Each variant of the GPU conv family (shaders/conv2d_igemm.comp, conv2d_igemm_coopmat.comp) is
compiled as cmake/Shaders.cmake compiles it (glslangValidator -V --target-env vulkan1.1), its spec
constants set to one of the model's convs and frozen, optimized with `spirv-opt -O`, its loops of
constant trip count unrolled (as a driver does after specialization: `--loop-unroll` on every loop,
then -O again), and the loop left around the GEMM counted (tools/bench/spirv_loop.py): FMAs or
MMAs, global and shared loads and stores with their widths, barriers, all other instructions, and
the gather of X per element. Beside them, the cost model's bytes per FMA (kernels/igemm.cpp
igemm_cost, mirrored in igemm_cost below). Peers (llama.cpp's conv2d_mm.comp, ncnn's
convolution_gemm_cm.comp) are compiled the same way from a path given on the command line, in a
temporary folder; their source is never copied here.

    /usr/bin/python3 -m tools.bench.mainloop_report [--tree CHECKOUT] [--llama FILE] [--ncnn FILE]
        [--json OUT.json] [--markdown OUT.md]
"""
from __future__ import annotations

import argparse
import json
import math
import re
import struct
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from tools.bench import spirv_loop

ROOT = Path(__file__).resolve().parents[2]
ACT_LEAKY = 1  # kernels' Activation::leaky_relu (act.glsl ACT 1)


@dataclass
class Conv:
    """One of the model's convs: what its spec constants and the cost model see."""
    name: str
    k: int
    stride: int
    cin: int
    cout: int
    h: int  # input extent (output = input at stride 1, pad k/2)
    w: int
    leaky: bool = True
    residual: bool = False
    fold_map: int = 0  # InputMap: 0 none, 1 reflect pad, 2 space-to-depth, 3 depth-to-space
    pieces: tuple[int, ...] = ()  # channels of each input piece as the conv sees them

    def out_hw(self) -> tuple[int, int]:
        pad = self.k // 2
        return ((self.h + 2 * pad - self.k) // self.stride + 1, (self.w + 2 * pad - self.k) // self.stride + 1)


# The default model (SelfUnroll at 260x346: G0 96, G 48, 32 event bins; bench_kernels' model_shapes).
CONVS = {
    "SFENet1": Conv("SFENet1 (folded: 4 pieces, space-to-depth)", 5, 1, 396, 96, 130, 173, False, False, 2,
                    (12, 128, 128, 128)),
    "RDB": Conv("RDBs.d.convs.1 (the 48-channel convs)", 3, 1, 144, 48, 130, 173),
    "LFF": Conv("RDBs.d.LFF", 1, 1, 336, 96, 130, 173, False, True),
    "UPNet.0": Conv("UPNet.0", 3, 1, 96, 256, 130, 173, False),
    "UPNet.2": Conv("UPNet.2 (3 channels)", 3, 1, 64, 3, 260, 346, False),
    "flownet.conv1": Conv("flownet.down_path.0.conv1", 3, 1, 32, 32, 288, 352),
    "flownet.head": Conv("flownet.head (folded: 3 pieces, reflect pad)", 3, 1, 67, 32, 288, 352, True, False, 1,
                         (32, 32, 3)),
    "flownet.down3": Conv("flownet.down_path.3.down (split-K)", 3, 2, 256, 512, 36, 44),
}


@dataclass
class Variant:
    """A tile of the family: the shader, its defines and its tile spec constants (Conv2d::igemm_tile,
    coopmat_tile; spec ids as kernels/igemm.cpp igemm_spec lays them out)."""
    name: str
    shader: str
    defines: tuple[str, ...]
    bm: int
    bn: int
    bk: int
    tm: int = 4
    tn: int = 4
    coopmat: dict = field(default_factory=dict)  # lm ln lk fm fn wm wn warp
    partial: bool = False

    def threads(self) -> int:
        c = self.coopmat
        return c["wm"] * c["wn"] * c["warp"] if c else (self.bm // self.tm) * (self.bn // self.tn)

    def x_elements(self) -> int:
        """X values one invocation gathers per stage."""
        if self.coopmat:
            return -(-(self.bk * self.bn // 8) // self.threads()) * 8
        return self.bk * self.bn // self.threads()

    def tile_spec(self) -> dict[int, int]:
        c = self.coopmat
        if c:
            return {6: c["lm"], 7: c["ln"], 8: c["lk"], 9: c["fm"], 10: c["fn"], 12: self.threads(), 14: c["warp"],
                    15: c["wm"], 16: c["wn"]}
        return {6: self.bm, 7: self.bn, 8: self.bk, 9: self.tm, 10: self.tn, 12: self.threads()}


def coopmat_variant(name: str, emulated: bool, ln: int = 8, lk: int = 16) -> Variant:
    c = {"lm": 16, "ln": ln, "lk": lk, "fm": 2, "fn": 32 // ln, "wm": 2, "wn": 2, "warp": 32}
    return Variant(name, "conv2d_igemm_coopmat.comp", ("VKU_COOPMAT_EMULATE",) if emulated else (),
                   c["wm"] * c["fm"] * c["lm"], c["wn"] * c["fn"] * ln, lk, coopmat=c)


def load_variants(tree: Path) -> dict[str, Variant]:
    """The scalar tiles as the checkout's Conv2d::igemm_tile (kernels/conv2d_igemm.cpp) lists them,
    split-K and fp16 forms of igemm_m, and the coopmat forms (coopmat_tile's layout, mirrored)."""
    text = (tree / "kernels" / "conv2d_igemm.cpp").read_text()
    tiles = re.findall(r"case ConvAlgo::(igemm_\w+): return \{(\d+), (\d+), (\d+), (\d+), (\d+)\};", text)
    if not tiles:
        raise SystemExit(f"{tree / 'kernels' / 'conv2d_igemm.cpp'}: no `case ConvAlgo::igemm_x: return {{bm, bn, bk, tm, "
                         "tn}};` lines (Conv2d::igemm_tile) to read the tiles from")
    v = {name: Variant(name, "conv2d_igemm.comp", (), *map(int, t)) for name, *t in tiles}
    m = v["igemm_m"]
    v["igemm_m split-K"] = Variant("igemm_m split-K", m.shader, (), m.bm, m.bn, m.bk, m.tm, m.tn, partial=True)
    v["igemm_m fp16"] = Variant("igemm_m fp16", m.shader, ("VKU_FP16",), m.bm, m.bn, m.bk, m.tm, m.tn)
    v["coopmat emulated"] = coopmat_variant("coopmat emulated", True)
    v["coopmat NV"] = coopmat_variant("coopmat NV", False)
    return v


VARIANTS = load_variants(ROOT)

# (variant, conv): the rows of the report, each variant at the model's conv the GPU choice gives it;
# tiles a checkout lacks are left out (igemm_g: 48 output channels, igemm_t: 1-3, where they exist).
ROWS = [
    ("igemm_l", "UPNet.0"), ("igemm_m", "RDB"), ("igemm_g", "RDB"), ("igemm_m", "LFF"), ("igemm_m", "SFENet1"),
    ("igemm_s", "flownet.conv1"), ("igemm_s", "flownet.head"), ("igemm_n", "UPNet.2"), ("igemm_t", "UPNet.2"),
    ("igemm_m split-K", "flownet.down3"), ("igemm_m fp16", "RDB"), ("coopmat emulated", "RDB"), ("coopmat NV", "RDB"),
]

# The C++ functions mirrored here (coopmat_tile above; igemm_kpad, igemm_cost, igemm_splits and
# kKAlign below), by the SHA-256 of their text in kernels/igemm.cpp:
# tests/python/test_mainloop_report.py fails when they change, so that the mirror follows.
MIRRORED = {"coopmat_tile": "3ce022f36a1683d2", "igemm_kpad": "6ba85c1fa1418e99", "igemm_splits": "2b21ce67efdb0df9",
            "igemm_cost": "14287331972846a7", "kKAlign": "6eb24c343de33618"}


def cpp_function_text(source: str, name: str) -> str:
    """The text of `name`'s definition in kernels/igemm.cpp (a function to its closing brace at column
    0, or a constant's line), whitespace collapsed."""
    if name.startswith("k"):
        m = re.search(rf"constexpr[^\n]*\b{name}\b[^\n]*", source)
    else:
        m = re.search(rf"^[\w:<> ]+\b{name}\((?:.|\n)*?^\}}", source, flags=re.M)
    if not m:
        raise ValueError(f"kernels/igemm.cpp: no definition of {name}")
    return " ".join(m.group(0).split())


def mirrored_digests(tree: Path) -> dict[str, str]:
    import hashlib
    source = (tree / "kernels" / "igemm.cpp").read_text()
    return {n: hashlib.sha256(cpp_function_text(source, n).encode()).hexdigest()[:16] for n in MIRRORED}


def spec_float(f: float) -> int:
    return struct.unpack("<I", struct.pack("<f", f))[0]


def spec_constants(v: Variant, c: Conv) -> dict[int, int]:
    spec = {0: c.k, 1: c.k, 2: c.stride, 3: ACT_LEAKY if c.leaky else 0, 4: spec_float(0.1 if c.leaky else 0.0),
            5: int(c.residual), 11: 0, 13: int(v.partial)}
    spec.update(v.tile_spec())
    pieces = c.pieces or (c.cin,)
    starts = [sum(pieces[:i]) for i in range(1, 5)]
    spec.update({17: c.fold_map, 18: len(pieces)})
    spec.update({19 + i: (starts[i] if i + 1 < len(pieces) else 0xFFFFFFFF) for i in range(4)})
    return spec


def run(cmd: list[str]) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stdout}{r.stderr}")


def optimized_text(source: Path, includes: list[Path], defines: tuple[str, ...], spec: dict[int, int],
                   work: Path, tag: str) -> str:
    """glslang, the spec constants set and frozen, -O, every loop marked Unroll, --loop-unroll, -O."""
    spv = work / f"{tag}.spv"

    run(["glslangValidator", "--quiet", "-V", "--target-env", "vulkan1.1", *[f"-I{i}" for i in includes],
         *[f"-D{d}" for d in defines], "-o", str(spv), str(source)])
    values = " ".join(f"{k}:{v}" for k, v in sorted(spec.items()))
    steps = [["--set-spec-const-default-value", values], ["--freeze-spec-const"], ["--fold-spec-const-op-composite"],
             ["-O"]]
    for i, step in enumerate(steps):
        run(["spirv-opt", "--target-env=vulkan1.1", *step, str(spv), "-o", str(work / f"{tag}.{i}.spv")])
        spv = work / f"{tag}.{i}.spv"
    text = subprocess.run(["spirv-dis", str(spv)], capture_output=True, text=True, check=True).stdout
    text = re.sub(r"OpLoopMerge (%\S+) (%\S+) None", r"OpLoopMerge \1 \2 Unroll", text)
    (work / f"{tag}.marked.txt").write_text(text)
    run(["spirv-as", "--target-env", "vulkan1.1", str(work / f"{tag}.marked.txt"), "-o", str(work / f"{tag}.m.spv")])
    run(["spirv-opt", "--target-env=vulkan1.1", "--loop-unroll", str(work / f"{tag}.m.spv"), "-o", str(work / f"{tag}.u.spv")])
    run(["spirv-opt", "--target-env=vulkan1.1", "-O", str(work / f"{tag}.u.spv"), "-o", str(work / f"{tag}.o.spv")])
    return subprocess.run(["spirv-dis", str(work / f"{tag}.o.spv")], capture_output=True, text=True, check=True).stdout


# kernels/igemm.cpp igemm_cost and igemm_splits, mirrored (tests/python/test_mainloop_report.py
# checks them against the bench rows the C++ wrote).
K_ALIGN, MIN_STAGES_PER_SPLIT, MAX_SPLITS = 16, 4, 16


def kpad(c: Conv, tap_major: bool = True) -> int:
    """Tap-major (since 2026-12-07): k*k taps of cin padded to 16; channel-major before: cin*k*k padded."""
    if tap_major:
        return c.k * c.k * -(-c.cin // K_ALIGN) * K_ALIGN
    return -(-(c.cin * c.k * c.k) // K_ALIGN) * K_ALIGN


def igemm_splits(v: Variant, c: Conv, cores: int, scratch: int = 64 << 20) -> int:
    oh, ow = c.out_hw()
    npix = oh * ow
    stages = kpad(c) // K_ALIGN
    groups = -(-npix // v.bn) * -(-c.cout // v.bm)
    want = min(-(-2 * cores // groups), stages // MIN_STAGES_PER_SPLIT, MAX_SPLITS)
    want = max(1, min(want, scratch // (c.cout * npix * 4)))
    depth = -(-stages // want)
    return -(-stages // depth)


def igemm_cost(v: Variant, c: Conv, splits: int, elem: int, tap_major: bool = True) -> dict[str, float]:
    oh, ow = c.out_hw()
    npix = oh * ow
    groups = -(-npix // v.bn) * -(-c.cout // v.bm)
    kp = kpad(c, tap_major)
    fma = groups * v.bm * v.bn * kp
    global_bytes = groups * kp * (v.bm + v.bn) * elem + c.cout * npix * elem
    if splits > 1:
        global_bytes += 2.0 * 4.0 * splits * c.cout * npix
    cm = v.coopmat
    if cm:
        frags = cm["wm"] * cm["wn"] * (cm["fm"] * cm["lm"] * cm["lk"] + cm["fn"] * cm["lk"] * cm["ln"])
        shared = groups * ((kp / v.bk) * 2.0 * ((v.bm + v.bn) * v.bk + frags) + 8.0 * v.bm * v.bn)
    else:
        shared = groups * kp * 4.0 * ((v.bm + v.bn) + v.threads() * (v.tm + v.tn))
    return {"fma": fma, "global_bytes": global_bytes, "shared_bytes": shared,
            "global_bytes_per_fma": global_bytes / fma, "shared_bytes_per_fma": shared / fma,
            "m_used": c.cout / (-(-c.cout // v.bm) * v.bm)}


def report_row(v: Variant, c: Conv, shaders: Path, work: Path, cores: int) -> dict:
    tag = re.sub(r"\W+", "_", f"{v.name}_{c.name}")
    text = optimized_text(shaders / v.shader, [shaders], v.defines, spec_constants(v, c), work, tag)
    stage = spirv_loop.count_stage(spirv_loop.parse(text), {0, 6, 7, 8, 9}, v.x_elements())
    fp16 = "VKU_FP16" in v.defines or bool(v.coopmat)
    splits = igemm_splits(v, c, cores) if v.partial else 1
    row = {"variant": v.name, "conv": c.name, "shape": f"{c.cin}->{c.cout} k{c.k} s{c.stride} @{c.h}x{c.w}",
           "tile": f"{v.bm}x{v.bn}x{v.bk}", "threads": v.threads(), "splits": splits, **stage,
           "cost": igemm_cost(v, c, splits, 2 if fp16 else 4)}
    return summarize(row)


def summarize(row: dict) -> dict:
    c = row["counts"]
    work = c.get("mma", 0) or c.get("fma", 0)
    rest = sum(c.get(k, 0) for k in ("other", "global_load", "shared_load", "global_store", "shared_store",
                                     "fragment_load", "fragment_store", "barrier"))
    row["non_math_per_op"] = round(rest / work, 2) if work else None
    return row


def temp_copy(source: Path, folder: Path) -> Path:
    """The peer's shader in the temporary folder beside the stand-ins, so that its includes find them
    first; glslc's includes enabled for glslang."""
    text = source.read_text()
    if "GL_GOOGLE_include_directive" not in text:
        text = re.sub(r"^(#version[^\n]*\n)", r"\1#extension GL_GOOGLE_include_directive : require\n", text, flags=re.M)
    copy = folder / source.name
    copy.write_text(text)
    return copy


def peer_row(name: str, source: Path, includes: list[Path], defines: tuple[str, ...], spec: dict[int, int],
             x_bindings: set[int], x_elements: int, work: Path, note: str, cost: dict) -> dict:
    source = temp_copy(source, includes[0])
    try:
        text = optimized_text(source, includes, defines, spec, work, re.sub(r"\W+", "_", name))
        stage = spirv_loop.count_stage(spirv_loop.parse(text), x_bindings, x_elements)
    except (RuntimeError, ValueError) as e:
        lines = [ln for ln in str(e).splitlines() if "ERROR" in ln or "error" in ln] or str(e).splitlines()
        return {"variant": name, "error": " ".join(lines[0].split())[:300], "note": note}
    return summarize({"variant": name, "conv": note, **stage, "cost": cost})


def llama_rows(source: Path, work: Path, conv: Conv) -> list[dict]:
    """llama.cpp's conv2d_mm.comp, its scalar fp32 form (the KHR cooperative-matrix form needs
    GL_KHR_cooperative_matrix, which glslang 12 lacks), with the spec constants ggml-vulkan.cpp gives
    it on NVIDIA since Turing: its tiles K x NPQ x CRS, 256 invocations and TS_K 8 (64x32: 128 and 4),
    no collectives (USE_COLLECTIVES compiled in, as their build does; off by spec constant), SHMEM_PAD 4,
    unrolled. `types.glsl` is a stand-in written in the temporary folder."""
    inc = work / "llama_inc"
    inc.mkdir(exist_ok=True)
    (inc / "types.glsl").write_text("#extension GL_EXT_shader_explicit_arithmetic_types : require\n"
                                    "#define A_TYPE float\n#define B_TYPE float\n#define D_TYPE float\n"
                                    "#define UNROLL [[unroll]]\n")
    pad = conv.k // 2
    rows = []
    for tile, (bk_, npq, crs, wg, tsk) in {"128x128": (128, 128, 16, 256, 8), "64x128": (64, 128, 16, 256, 8),
                                          "64x32": (64, 32, 32, 128, 4)}.items():
        spec = {0: wg, 1: bk_, 2: crs, 3: npq, 4: tsk, 5: 0, 6: 4, 7: conv.stride, 8: conv.stride, 9: pad, 10: pad,
                11: 1, 12: 1, 13: conv.k, 14: conv.k, 15: 0, 16: 0}
        # Our cost model applied to their tile: TS_K x TS_NPQ values per invocation.
        tile_v = Variant(tile, "", (), bk_, npq, crs, tsk, bk_ * npq // wg // tsk)
        rows.append(peer_row(f"llama.cpp conv2d_mm {tile} (fp32)", source, [inc, source.parent], ("USE_COLLECTIVES",),
                             spec, {1}, crs * npq // wg, work, f"{conv.name}: K x NPQ x CRS {bk_}x{npq}x{crs}, "
                             f"{wg} invocations", igemm_cost(tile_v, conv, 1, 4)))
    return rows


def ncnn_rows(source: Path, work: Path, conv: Conv) -> list[dict]:
    """ncnn's convolution_gemm_cm.comp in its GL_NV_cooperative_matrix form (fp16 operands, fp32
    accumulation), with the spec constants ncnn's convolution_vulkan.cpp gives a conv of this shape:
    fragments M x N x K 16 x 8 x 16 (an NV shape; ncnn asks the device for its optimal one), every
    unroll 2, subgroups of 32, elempack 1. ncnn injects macros when it compiles; their stand-ins (and
    the activation include) are written in the temporary folder."""
    inc = work / "ncnn_inc"
    inc.mkdir(exist_ok=True)
    (inc / "vulkan_activation.comp").write_text(
        "layout(local_size_x_id = 233) in;\n#define psc(x) (x == 0 ? p.x : x)\n#define afp float\n"
        "#define afpvec4 vec4\n"
        "vec4 activation_afpvec4(vec4 v, int t, float a, float b) { return t == 1 ? max(v, vec4(0.0)) : v; }\n")
    defines = ("ncnn_VK_NV_cooperative_matrix=1", "ncnn_VK_KHR_cooperative_matrix=0", "NCNN_fp16_arithmetic=0")
    oh, ow = conv.out_hw()
    m, n, k, sg = 16, 8, 16, 2
    spec = {0: conv.k, 1: conv.k, 2: 1, 3: 1, 4: conv.stride, 5: conv.stride, 6: 1, 7: 0, 10: m, 11: n, 12: k,
            13: 32, 14: sg, 15: sg, 16: sg, 17: sg, 18: sg, 19: conv.cin, 20: conv.cout, 21: 1, 22: 1,
            23: conv.w + 2 * (conv.k // 2), 24: conv.h + 2 * (conv.k // 2),
            25: (conv.w + 2 * (conv.k // 2)) * (conv.h + 2 * (conv.k // 2)), 26: ow, 27: oh, 28: ow * oh,
            233: 32 * sg * sg}
    x_elements = -(-(m // 4) * k * sg * sg // (32 * sg)) * 4
    # Our cost model applied to their tile: output channels N x 2 x 2, pixels M x 2 x 2, K x 2 deep.
    cm = {"lm": n, "ln": m, "lk": k * sg, "fm": sg, "fn": sg, "wm": sg, "wn": sg, "warp": 32}
    tile_v = Variant("ncnn", "", (), n * sg * sg, m * sg * sg, k * sg, coopmat=cm)
    return [peer_row("ncnn convolution_gemm_cm (NV coopmat)", source, [inc, source.parent], defines, spec, {0},
                     x_elements, work, f"{conv.name}: fragments 16x8x16, unrolls 2, 4 warps", igemm_cost(tile_v, conv, 1, 2))]


def markdown(rows: list[dict]) -> str:
    head = ("| variant | conv | FMA or MMA per stage | global loads (bits) | shared loads (bits) | shared stores | "
            "barriers | other | non-math per FMA/MMA | gather instr. per X element | cost: global B/FMA, shared "
            "B/FMA, M used |\n" + "| --- " * 11 + "|\n")
    out = [head]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['variant']} | {r.get('note', '')} | not compiled: {r['error']} |" + " |" * 8 + "\n")
            continue
        c, w = r["counts"], r["widths"]
        math_ = f"{c['mma']} MMA" if c.get("mma") else f"{c.get('fma', 0)} FMA"
        fmt = lambda kind: ", ".join(f"{n}x{k.split()[1]}" for k, n in sorted(w.items()) if k.startswith(kind)) or "0"
        shared_loads = " + ".join(x for x in (fmt("shared_load") if c.get("shared_load") else "",
                                              fmt("fragment_load") + " fragments" if c.get("fragment_load") else "") if x)
        g = r["gather"]
        cost = r.get("cost")
        cost_s = (f"{cost['global_bytes_per_fma']:.3f}, {cost['shared_bytes_per_fma']:.3f}, "
                  f"{100 * cost['m_used']:.0f}%") if cost else "n/a"
        out.append(f"| {r['variant']} | {r.get('conv', r.get('note', ''))} | {math_} | {fmt('global_load')} | "
                   f"{shared_loads} | {fmt('shared_store')} | "
                   f"{c.get('barrier', 0)} | {c.get('other', 0)} | {r['non_math_per_op']} | "
                   f"{g.get('per_element', '-')} | {cost_s} |\n")
    return "".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the checkout to report on (its shaders/ and its tiles in kernels/conv2d_igemm.cpp)")
    ap.add_argument("--llama", type=Path, help="path to llama.cpp's conv2d_mm.comp (read, compiled in a temp folder)")
    ap.add_argument("--ncnn", type=Path, help="path to ncnn's convolution_gemm_cm.comp")
    ap.add_argument("--cores", type=int, default=132, help="shader cores for the split-K count (H100: 132)")
    ap.add_argument("--only", help="report the rows whose variant contains this text")
    ap.add_argument("--json", type=Path, help="write every row, raw, here")
    ap.add_argument("--markdown", type=Path, help="write the table here")
    a = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="vkunroll_mainloop_") as tmp:
        work = Path(tmp)
        variants = load_variants(a.tree)
        for vname, cname in ROWS:
            if vname not in variants or (a.only and a.only not in vname):
                continue
            rows.append(report_row(variants[vname], CONVS[cname], a.tree / "shaders", work, a.cores))
        if a.llama:
            rows += llama_rows(a.llama, work, CONVS["RDB"])
        if a.ncnn:
            rows += ncnn_rows(a.ncnn, work, CONVS["RDB"])
    table = markdown(rows)
    print(table)
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1) + "\n")
    if a.markdown:
        a.markdown.write_text(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
