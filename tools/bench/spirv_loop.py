"""Counts what one K-stage of a compute shader's main loop executes, from optimized SPIR-V text.

The input is `spirv-dis` output of a module whose spec constants are frozen and whose loops of
constant trip count are unrolled (mainloop_report.py prepares it), so that one loop is left around
the GEMM: the K-stage loop, the innermost loop holding the multiply-adds (or cooperative-matrix
MMAs). Its blocks are one stage; every instruction in them is counted once (both sides of a branch:
a static count). Instruction counts are per invocation, a vector instruction counting its lanes
(GPUs issue them lane by lane), except loads and stores (one instruction, its width in bits).
"""
from __future__ import annotations

import re
from collections import Counter, defaultdict
from dataclasses import dataclass, field

# Register renaming, structure and constant-index composites: no instruction once compiled.
FREE = {"OpLabel", "OpLoopMerge", "OpSelectionMerge", "OpBranch", "OpPhi", "OpCompositeExtract",
        "OpCompositeConstruct", "OpCompositeInsert", "OpVectorShuffle", "OpCopyObject", "OpBitcast",
        "OpLine", "OpNoLine", "OpUndef"}
BARRIERS = {"OpControlBarrier", "OpMemoryBarrier"}
CONVERTS = {"OpFConvert", "OpConvertFToU", "OpConvertFToS", "OpConvertSToF", "OpConvertUToF", "OpUConvert",
            "OpSConvert", "OpQuantizeToF16"}
MULS = {"OpFMul", "OpVectorTimesScalar"}
MEMORY_OPS = {"OpLoad", "OpStore", "OpCooperativeMatrixLoadNV", "OpCooperativeMatrixStoreNV", "OpControlBarrier"}
GLOBAL_CLASSES = {"StorageBuffer", "Uniform", "PhysicalStorageBuffer"}

_LINE = re.compile(r"^\s*(?:(%[\w.]+)\s*=\s*)?(Op\w+)\s*(.*)$")


@dataclass
class Inst:
    result: str | None
    op: str
    args: list[str]
    block: str = ""


@dataclass
class Module:
    insts: list[Inst] = field(default_factory=list)
    defs: dict[str, Inst] = field(default_factory=dict)
    blocks: dict[str, list[Inst]] = field(default_factory=dict)  # label -> instructions (main function)
    order: list[str] = field(default_factory=list)
    bindings: dict[str, int] = field(default_factory=dict)  # variable -> binding
    ext_glsl: set[str] = field(default_factory=set)


def parse(text: str) -> Module:
    m = Module()
    block = None
    for line in text.splitlines():
        line = line.split(";", 1)[0].strip()
        g = _LINE.match(line)
        if not g:
            continue
        res, op, rest = g.group(1), g.group(2), g.group(3)
        args = re.findall(r'"[^"]*"|\S+', rest)
        inst = Inst(res, op, args)
        m.insts.append(inst)
        if res:
            m.defs[res] = inst
        if op == "OpDecorate" and len(args) >= 3 and args[1] == "Binding":
            m.bindings[args[0]] = int(args[2])
        if op == "OpExtInstImport" and "GLSL.std.450" in rest:
            m.ext_glsl.add(res)
        if op == "OpLabel":
            block = res
            m.blocks[block] = []
            m.order.append(block)
        if op == "OpFunctionEnd":
            block = None
        if block is not None:
            inst.block = block
            m.blocks[block].append(inst)
    return m


def successors(m: Module, label: str) -> list[str]:
    term = m.blocks[label][-1]
    if term.op == "OpBranch":
        return [term.args[0]]
    if term.op == "OpBranchConditional":
        return [term.args[1], term.args[2]]
    if term.op == "OpSwitch":
        return [a for a in term.args[1:] if a.startswith("%")]
    return []


def loops(m: Module) -> dict[str, set[str]]:
    """Loop header -> its blocks: reachable from the header without leaving through its merge."""
    out = {}
    for label in m.order:
        merge = next((i for i in m.blocks[label] if i.op == "OpLoopMerge"), None)
        if merge is None:
            continue
        body, todo = {label}, [label]
        while todo:
            for s in successors(m, todo.pop()):
                if s != merge.args[0] and s not in body:
                    body.add(s)
                    todo.append(s)
        out[label] = body
    return out


def width_bits(m: Module, type_id: str) -> int:
    t = m.defs[type_id]
    if t.op in ("OpTypeFloat", "OpTypeInt"):
        return int(t.args[0])
    if t.op == "OpTypeBool":
        return 32
    if t.op in ("OpTypeVector", "OpTypeArray"):
        n = int(t.args[1]) if t.op == "OpTypeVector" else int(m.defs[t.args[1]].args[1])
        return n * width_bits(m, t.args[0])
    if t.op == "OpTypeStruct":
        return sum(width_bits(m, a) for a in t.args)
    if t.op == "OpTypeCooperativeMatrixNV":  # per invocation: the fragment's elements over a 32-wide warp
        rows, cols = (int(m.defs[a].args[1]) for a in t.args[2:4])
        return rows * cols * width_bits(m, t.args[0]) // 32
    return 32


def lanes(m: Module, type_id: str | None) -> int:
    if not type_id or type_id not in m.defs:
        return 1
    t = m.defs[type_id]
    return int(t.args[1]) if t.op == "OpTypeVector" else 1


def value_type_of(m: Module, value: str) -> str | None:
    d = m.defs.get(value)
    return d.args[0] if d is not None and d.op not in ("OpVariable",) else None


def dynamic_index(m: Module, ptr: str) -> bool:
    while ptr in m.defs and m.defs[ptr].op in ("OpAccessChain", "OpInBoundsAccessChain"):
        if any(m.defs.get(a) is None or m.defs[a].op != "OpConstant" for a in m.defs[ptr].args[2:]):
            return True
        ptr = m.defs[ptr].args[1]
    return False


def root_variable(m: Module, ptr: str) -> str:
    while ptr in m.defs and m.defs[ptr].op in ("OpAccessChain", "OpInBoundsAccessChain", "OpPtrAccessChain",
                                                "OpCopyObject"):
        ptr = m.defs[ptr].args[1]
    return ptr


def storage_class(m: Module, var: str) -> str:
    v = m.defs.get(var)
    return v.args[1] if v is not None and v.op == "OpVariable" else "?"


def mul_add_pairs(m: Module, body_insts: list[Inst]) -> tuple[dict[str, int], set[int]]:
    """FMAs: fma() calls, and multiplies whose only use is one add. Returns lanes per instruction id."""
    uses = defaultdict(list)
    for i in body_insts:
        for a in i.args:
            uses[a].append(i)
    fma, paired = {}, set()
    for i in body_insts:
        if i.op == "OpExtInst" and i.args[1] in m.ext_glsl and i.args[2] == "Fma":
            fma[id(i)] = lanes(m, i.args[0])
        elif i.op in MULS and len(uses[i.result]) == 1 and uses[i.result][0].op == "OpFAdd":
            add = uses[i.result][0]
            fma[id(i)] = lanes(m, i.args[0])
            paired.add(id(add))
    return fma, paired


def stage_loop(m: Module) -> set[str]:
    """The main loop: of the innermost loops holding multiply-adds or MMAs (no loop inside them holds
    any), the one holding the most (a peer's remainder loop beside its main loop holds fewer)."""
    def math(body):
        insts = [i for b in body for i in m.blocks[b]]
        fma, _ = mul_add_pairs(m, insts)
        return sum(fma.values()) + sum(i.op == "OpCooperativeMatrixMulAddNV" for i in insts)
    found = [body for body in loops(m).values() if math(body)]
    innermost = [b for b in found if not any(o < b for o in found)]
    if not innermost:
        raise ValueError("no loop holds multiply-adds or MMAs: is the K-stage loop unrolled away?")
    return max(innermost, key=math)


def count_stage(m: Module, x_bindings: set[int], x_elements: int | None = None) -> dict:
    """What one stage executes; `x_bindings`: the bindings the gathered operand X is read from;
    `x_elements`: X values an invocation gathers per stage (default: its loads of X, which counts a
    value read from one of several pieces once per piece)."""
    body = stage_loop(m)
    insts = [i for b in m.order if b in body for i in m.blocks[b]]
    fma, paired = mul_add_pairs(m, insts)
    c = Counter()
    loads, by_op = Counter(), Counter()
    x_loads, x_stores = [], []
    for i in insts:
        if i.op in FREE or id(i) in paired:
            continue
        if id(i) in fma:
            c["fma"] += fma[id(i)]
            continue
        if i.op == "OpCooperativeMatrixMulAddNV":
            c["mma"] += 1
        elif i.op in ("OpLoad", "OpCooperativeMatrixLoadNV", "OpStore", "OpCooperativeMatrixStoreNV"):
            store = i.op in ("OpStore", "OpCooperativeMatrixStoreNV")
            var = root_variable(m, i.args[0] if store else i.args[1])
            cls = storage_class(m, var)
            kind = "global" if cls in GLOBAL_CLASSES else "shared" if cls == "Workgroup" else \
                "push" if cls == "PushConstant" else "local"
            value_type = value_type_of(m, i.args[1]) if store else i.args[0]
            bits = width_bits(m, value_type) if value_type in m.defs else 32
            if kind == "push":  # a uniform register on every GPU: an operand, not a load
                continue
            if kind == "local":  # a private array: registers where every index is constant
                kind = "local" if dynamic_index(m, i.args[0] if store else i.args[1]) else "register"
            name = f"{kind}_{'store' if store else 'load'}"
            if i.op.startswith("OpCooperativeMatrix"):
                name = f"fragment_{'store' if store else 'load'}"
            loads[f"{name} {bits}b"] += 1
            c[name] += 1
            if kind == "global" and not store and m.bindings.get(var) in x_bindings:
                x_loads.append(i)
        elif i.op in BARRIERS:
            c["barrier"] += 1
        elif i.op in ("OpAccessChain", "OpInBoundsAccessChain"):
            n = sum(1 for a in i.args[2:] if a not in m.defs or m.defs[a].op != "OpConstant")
            c["other"] += n
            by_op[i.op] += n
        else:
            n = lanes(m, i.args[0] if i.result else None)
            c["other"] += n
            by_op[i.op] += n
            if i.op in CONVERTS:
                c["convert"] += n
    c["x_loads"] = len(x_loads)
    gather = gather_instructions(m, insts, body, x_loads, x_elements or len(x_loads))
    return {"counts": dict(c), "widths": dict(loads), "other_by_op": dict(by_op.most_common()),
            "gather": gather, "blocks": len(body)}


def gather_instructions(m: Module, insts: list[Inst], body: set[str], x_loads: list[Inst], n: int) -> dict:
    """The instructions that exist only to gather X: the address and bounds arithmetic of its loads
    (their backward slice and the branches that guard them, less what any other work also uses), and
    what converts or packs the loaded values on their way to shared memory."""
    if not x_loads:
        return {"elements": 0}
    inside = {i.result: i for i in insts if i.result}
    users = defaultdict(list)
    for i in insts:
        for a in i.args:
            if a in inside:
                users[a].append(i)
    guard = selection_guards(m, body, {i.block for i in x_loads}, {id(i) for i in x_loads})
    seeds = [i.args[1] for i in x_loads] + [g.args[0] for g in guard]
    sliced, todo = set(), list(seeds)
    while todo:
        v = todo.pop()
        if v in sliced or v not in inside or inside[v].op == "OpPhi":
            continue
        sliced.add(v)
        todo.extend(a for a in inside[v].args if a in inside)
    ends = {id(i) for i in x_loads} | {id(g) for g in guard}
    changed = True
    while changed:  # keep only what nothing outside the gather uses
        changed = False
        for v in list(sliced):
            if any(u.result not in sliced and id(u) not in ends for u in users[v]):
                sliced.discard(v)
                changed = True
    # Forward: from the loaded values to the stores, what converts, packs or selects them.
    forward, todo = set(), [i.result for i in x_loads]
    while todo:
        for u in users[todo.pop()]:
            if u.result and u.result not in forward and u.op not in ("OpStore",) and id(u) not in ends:
                forward.add(u.result)
                todo.append(u.result)
    cost = lambda ids: sum(0 if inside[v].op in FREE else lanes(m, inside[v].args[0]) for v in ids)
    address = cost(sliced) + len(guard)
    convert = cost(forward - sliced)
    return {"elements": n, "address_and_bounds": address, "convert_and_pack": convert,
            "per_element": round((address + convert) / n, 2)}


def selection_guards(m: Module, body: set[str], blocks: set[str], own: set[int]) -> list[Inst]:
    """Conditional branches in `body` whose selection region holds one of `blocks` and no memory
    access but those in `own` (a branch around the whole next-stage load is not the gather's)."""
    out = []
    for label in body:
        insts = m.blocks[label]
        if len(insts) < 2 or insts[-2].op != "OpSelectionMerge" or insts[-1].op != "OpBranchConditional":
            continue
        merge = insts[-2].args[0]
        region, todo = set(), [insts[-1].args[1], insts[-1].args[2]]
        while todo:
            b = todo.pop()
            if b == merge or b in region or b not in body:
                continue
            region.add(b)
            todo.extend(successors(m, b))
        memory = [i for b in region for i in m.blocks[b] if i.op in MEMORY_OPS]
        if region & blocks and all(id(i) in own for i in memory):
            out.append(insts[-1])
    return out
