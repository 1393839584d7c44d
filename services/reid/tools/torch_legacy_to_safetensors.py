#!/usr/bin/env python3
"""Converts a PyTorch state dict saved in the legacy (pre-1.6, non-zip)
serialization format to safetensors, using only the Python standard library.

The legacy file is a sequence of pickles: a magic number, the protocol
version, system info, the state dict itself (tensors refer to storages by
persistent id), the list of storage keys, then each storage's raw bytes
preceded by its element count as a little-endian int64.

Usage: torch_legacy_to_safetensors.py INPUT.pt OUTPUT.safetensors
"""
import collections
import json
import os
import pickle
import struct
import sys

MAGIC = 0x1950A86A20F9469CFC6C
PROTOCOL = 1001

# storage class name -> (safetensors dtype, bytes per element, struct code)
STORAGES = {
    "FloatStorage": ("F32", 4, "f"),
    "DoubleStorage": ("F64", 8, "d"),
    "HalfStorage": ("F16", 2, "e"),
    "LongStorage": ("I64", 8, "q"),
    "IntStorage": ("I32", 4, "i"),
    "ShortStorage": ("I16", 2, "h"),
    "CharStorage": ("I8", 1, "b"),
    "ByteStorage": ("U8", 1, "B"),
    "BoolStorage": ("BOOL", 1, "?"),
}


class StorageType:
    def __init__(self, name):
        if name not in STORAGES:
            raise ValueError(f"unsupported storage type {name}")
        self.name = name
        self.dtype, self.itemsize, self.code = STORAGES[name]


class StorageRef:
    def __init__(self, key, stype, numel):
        self.key, self.stype, self.numel = key, stype, numel
        self.data = None


class TensorRef:
    def __init__(self, storage, offset, size, stride):
        self.storage, self.offset = storage, offset
        self.size, self.stride = tuple(size), tuple(stride)

    def contiguous_bytes(self):
        item = self.storage.stype.itemsize
        numel = 1
        for s in self.size:
            numel *= s
        expected, acc = [], 1
        for s in reversed(self.size):
            expected.insert(0, acc)
            acc *= s
        buf = self.storage.data
        if numel == 0:
            return b""
        if tuple(expected) == self.stride or numel == 1:
            start = self.offset * item
            return buf[start : start + numel * item]
        # Strided view: gather element by element (rare in state dicts).
        out = bytearray()
        for flat in range(numel):
            idx, rem = 0, flat
            for dim in reversed(range(len(self.size))):
                rem, i = divmod(rem, self.size[dim])
                idx += i * self.stride[dim]
            start = (self.offset + idx) * item
            out += buf[start : start + item]
        return bytes(out)


def rebuild_tensor(storage, offset, size, stride, *_ignored):
    return TensorRef(storage, offset, size, stride)


class LegacyUnpickler(pickle.Unpickler):
    def __init__(self, f, storages):
        super().__init__(f)
        self.storages = storages

    def find_class(self, module, name):
        if module == "collections" and name == "OrderedDict":
            return collections.OrderedDict
        if module == "torch._utils" and name in ("_rebuild_tensor_v2", "_rebuild_tensor"):
            return rebuild_tensor
        if module == "torch" and name in STORAGES:
            return StorageType(name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")

    def persistent_load(self, pid):
        kind, stype, key, _location, numel = pid[:5]
        if kind != "storage":
            raise pickle.UnpicklingError(f"unknown persistent id {kind}")
        if key not in self.storages:
            self.storages[key] = StorageRef(key, stype, numel)
        return self.storages[key]


def load_legacy(path):
    with open(path, "rb") as f:
        if f.read(2) == b"PK":
            raise SystemExit(f"{path} is a zip-format checkpoint, not the legacy format")
        f.seek(0)
        if pickle.load(f) != MAGIC:
            raise SystemExit(f"{path}: bad magic number, not a legacy torch file")
        if pickle.load(f) != PROTOCOL:
            raise SystemExit(f"{path}: unsupported protocol version")
        sys_info = pickle.load(f)
        if not sys_info.get("little_endian", True):
            raise SystemExit(f"{path}: big-endian checkpoints are not supported")
        storages = {}
        state = LegacyUnpickler(f, storages).load()
        keys = pickle.load(f)
        for key in keys:
            (numel,) = struct.unpack("<q", f.read(8))
            ref = storages[key]
            nbytes = numel * ref.stype.itemsize
            ref.data = f.read(nbytes)
            if len(ref.data) != nbytes:
                raise SystemExit(f"{path}: truncated storage {key}")
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    return state


def save_safetensors(tensors, path):
    header, blobs, offset = {}, [], 0
    for name, t in tensors.items():
        data = t.contiguous_bytes()
        header[name] = {
            "dtype": t.storage.stype.dtype,
            "shape": list(t.size),
            "data_offsets": [offset, offset + len(data)],
        }
        blobs.append(data)
        offset += len(data)
    header["__metadata__"] = {"format": "pt"}
    raw = json.dumps(header, separators=(",", ":")).encode()
    raw += b" " * ((8 - len(raw) % 8) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(raw)))
        f.write(raw)
        for b in blobs:
            f.write(b)
    os.replace(tmp, path)


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    state = load_legacy(sys.argv[1])
    tensors = collections.OrderedDict(
        (k[len("module."):] if k.startswith("module.") else k, v)
        for k, v in state.items()
        if isinstance(v, TensorRef)
    )
    save_safetensors(tensors, sys.argv[2])
    print(f"wrote {len(tensors)} tensors to {sys.argv[2]}")


if __name__ == "__main__":
    main()
