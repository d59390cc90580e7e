#!/usr/bin/env python3
"""Writes the fuzzers' seed corpus from real files: `fuzz_seeds.py REFERENCE_DIR OUT_DIR`.

Reads ../shared/reference (never copied into the repository; this runs at fuzz time) and cuts
its files down to seeds small enough to mutate quickly: the KuBasic OBJ meshes, the MOVi-A
scene's metadata.json and collisions.json cut to their first frames, the normalisation
statistics, small golden .npy arrays, the tdl golden cases' complex.json + operators.json (op
and args only; the `call` and the operators' matrices are dropped) + case.json's domain, and,
when Python's torch is installed, state dicts saved by torch.save (a few tensors of a published
checkpoint, and a small module's state_dict).
"""
import json
import os
import shutil
import sys

ref, out = sys.argv[1], sys.argv[2]
data = os.path.join(ref, "data")


def put(harness, name, content):
    d = os.path.join(out, harness)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(content if isinstance(content, bytes) else content.encode())


kubasic = os.path.join(data, "kubasic")
if os.path.isdir(kubasic):
    for shape in sorted(os.listdir(kubasic)):
        p = os.path.join(kubasic, shape, "collision_geometry.obj")
        if os.path.exists(p) and os.path.getsize(p) < 70000:
            with open(p, "rb") as f:
                put("obj", shape + ".obj", bytes([len(shape) & 1]) + f.read())  # first byte: merge option

scene = os.path.join(data, "movi-a", "8")
if os.path.isdir(scene):
    with open(os.path.join(scene, "metadata.json")) as f:
        meta = json.load(f)
    for frames in (3, 6):
        m = dict(meta)
        m["metadata"] = dict(meta["metadata"], num_frames=frames)
        m["instances"] = [dict(i, positions=i["positions"][:frames], quaternions=i["quaternions"][:frames]) for i in meta["instances"]]
        for k in list(m):
            if k not in ("metadata", "instances"):
                del m[k]
        for i in m["instances"]:
            for k in [k for k, v in i.items() if isinstance(v, list) and len(v) == len(meta["instances"][0]["positions"])]:
                if k not in ("positions", "quaternions"):
                    del i[k]
        put("kubric", "movi-a-8-%dframes.json" % frames, json.dumps(m))
    with open(os.path.join(scene, "collisions.json")) as f:
        coll = json.load(f)
    keys = sorted(coll, key=int)[:6]
    put("collisions", "movi-a-8-first-frames.json", json.dumps({k: coll[k] for k in keys}))

norm = os.path.join(data, "normalization")
if os.path.isdir(norm):
    for n in sorted(os.listdir(norm)):
        shutil.copy(os.path.join(norm, n), os.path.join(out, "stats", n)) if os.path.isdir(os.path.join(out, "stats")) else put("stats", n, open(os.path.join(norm, n), "rb").read())

count = 0
for base in ("golden", "train-golden"):
    for root, _, files in sorted(os.walk(os.path.join(data, base))):
        for n in sorted(files):
            p = os.path.join(root, n)
            if n.endswith(".npy") and os.path.getsize(p) < 4096 and count < 40:
                put("npy", "%s-%d.npy" % (base, count), open(p, "rb").read())
                count += 1

# tdl cases: complex.json NUL operators.json NUL case.json (tests/fuzz/fuzz_tdl.cpp), identical
# inputs once; each also without complex.json's "domain", so case.json's fallback is taken.
cases = os.path.join(ref, "tdl-golden", "cases")
if os.path.isdir(cases):
    seen = set()
    for name in sorted(os.listdir(cases)):
        c = os.path.join(cases, name)
        try:
            with open(os.path.join(c, "complex.json")) as f:
                cx = json.load(f)
            with open(os.path.join(c, "operators.json")) as f:
                ops = {k: {"op": v.get("op"), "args": v.get("args", {})}
                       for k, v in json.load(f).items()}
            with open(os.path.join(c, "case.json")) as f:
                domain = json.load(f).get("domain")
        except (OSError, ValueError, AttributeError):
            continue
        for keep_domain in (True, False):
            x = dict(cx)
            if not keep_domain:
                x.pop("domain", None)
            b = "\0".join([json.dumps(x), json.dumps(ops), json.dumps({"domain": domain})])
            b = b.encode()
            if b not in seen and len(b) < 16384:
                seen.add(b)
                put("tdl", "%s%s.json" % (name, "" if keep_domain else "-case-domain"), b)

try:
    import torch
except ImportError:
    torch = None
if torch is not None:
    import io
    ckpt = os.path.join(data, "checkpoints", "modela_seed2_e39.pt")
    if os.path.exists(ckpt):
        sd = torch.load(ckpt, map_location="cpu", weights_only=True)
        small = {k: v for k, v in list(sd.items())[:6]}
        b = io.BytesIO()
        torch.save(small, b)
        put("checkpoint", "reference-first-tensors.pt", b.getvalue())
    m = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.BatchNorm1d(2))
    b = io.BytesIO()
    torch.save(m.state_dict(), b)
    put("checkpoint", "python-state-dict.pt", b.getvalue())
