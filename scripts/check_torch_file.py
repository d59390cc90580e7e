#!/usr/bin/env python3
"""Opens a torch.save-format file the way torch.load(weights_only=True) does, without torch.

Reads the zip archive, unpickles data.pkl refusing every global outside torch's weights-only
allowlist (tensor rebuild, storages, OrderedDict), rebuilds tensors as (dtype, shape, values)
from the archive's storages, and prints a JSON summary: for each tensor its path, dtype, shape
and the sum of its values. Exit status 1 when the file would not load. Standard library only,
so tests run it where Python's torch is absent.

`check_torch_file.py --max-abs-diff A B` instead prints the largest absolute difference between
the tensors of two such files (the same names and shapes, else exit status 1).
"""
import json
import pickle
import struct
import sys
import zipfile

ALLOWED = {
    ("torch._utils", "_rebuild_tensor_v2"),
    ("collections", "OrderedDict"),
}
STORAGES = {"FloatStorage": ("f", 4, "float32"), "DoubleStorage": ("d", 8, "float64"), "LongStorage": ("q", 8, "int64"),
            "IntStorage": ("i", 4, "int32"), "ByteStorage": ("B", 1, "uint8"), "BoolStorage": ("?", 1, "bool"),
            "CharStorage": ("b", 1, "int8"), "ShortStorage": ("h", 2, "int16")}


class Tensor:
    def __init__(self, storage, offset, size, stride):
        fmt, width, self.dtype, data = storage
        self.shape = list(size)
        n = 1
        for s in size:
            n *= s
        values = struct.unpack("<%d%s" % (len(data) // width, fmt), data)
        # Gather by strides (C order of the logical shape).
        out, idx = [], [0] * len(size)
        for _ in range(n):
            out.append(values[offset + sum(i * st for i, st in zip(idx, stride))])
            for d in reversed(range(len(size))):
                idx[d] += 1
                if idx[d] < size[d]:
                    break
                idx[d] = 0
        self.values = out


def load(path):
    z = zipfile.ZipFile(path)
    pkl = [n for n in z.namelist() if n.endswith("/data.pkl")]
    if len(pkl) != 1:
        raise ValueError("no data.pkl: not a torch.save file")
    prefix = pkl[0][: -len("data.pkl")]

    class Unpickler(pickle.Unpickler):
        def find_class(self, module, name):
            if module == "torch" and name in STORAGES:
                return STORAGES[name]
            if (module, name) not in ALLOWED:
                raise pickle.UnpicklingError(f"weights_only load refuses the global {module}.{name}")
            if name == "_rebuild_tensor_v2":
                return lambda storage, offset, size, stride, requires_grad=False, hooks=None, *rest: Tensor(storage, offset, size, stride)
            return dict

        def persistent_load(self, pid):
            kind, storage_type, key, location, numel = pid
            if kind != "storage":
                raise pickle.UnpicklingError(f"unknown persistent id {pid!r}")
            fmt, width, dtype = storage_type
            return (fmt, width, dtype, z.read(prefix + "data/" + key))

    with z.open(pkl[0]) as f:
        return Unpickler(f).load()


def summarize(obj, path="", out=None):
    out = {} if out is None else out
    if isinstance(obj, Tensor):
        out[path] = {"dtype": obj.dtype, "shape": obj.shape, "sum": float(sum(obj.values))}
    elif isinstance(obj, dict):
        for k, v in obj.items():
            summarize(v, f"{path}.{k}" if path else str(k), out)
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            summarize(v, f"{path}[{i}]", out)
    else:
        out[path] = obj
    return out


def tensors(obj, path="", out=None):
    out = {} if out is None else out
    if isinstance(obj, Tensor):
        out[path] = obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            tensors(v, f"{path}.{k}" if path else str(k), out)
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            tensors(v, f"{path}[{i}]", out)
    return out


def max_abs_diff(a_path, b_path):
    a, b = tensors(load(a_path)), tensors(load(b_path))
    if sorted(a) != sorted(b):
        raise ValueError(f"different tensors: {sorted(set(a) ^ set(b))}")
    worst = 0.0
    for k in a:
        if a[k].shape != b[k].shape:
            raise ValueError(f"tensor {k}: shape {a[k].shape} vs {b[k].shape}")
        worst = max([worst] + [abs(x - y) for x, y in zip(a[k].values, b[k].values)])
    return worst


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--max-abs-diff":
        try:
            print(f"{max_abs_diff(sys.argv[2], sys.argv[3]):.3e}")
        except Exception as e:  # noqa: BLE001
            print(f"error: {e}", file=sys.stderr)
            sys.exit(1)
        sys.exit(0)
    try:
        print(json.dumps(summarize(load(sys.argv[1])), indent=1, sort_keys=True))
    except Exception as e:  # noqa: BLE001 - any failure means torch.load would fail too
        print(f"error: {sys.argv[1]}: {e}", file=sys.stderr)
        sys.exit(1)
