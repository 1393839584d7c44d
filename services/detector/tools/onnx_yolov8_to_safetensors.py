#!/usr/bin/env python3
"""Converts an ultralytics YOLOv8 detection model exported to ONNX
(`yolo export model=best.pt format=onnx`) into the detector's files:

  OUT.safetensors   the convolution weights and biases under the detector's
                    candle names (float32; float16 exports are widened once here)
  OUT.names.yaml    the class names from the export's metadata, in ultralytics'
                    `names:` form, plus an optional `coco:` mapping to COCO ids
  OUT.onnx          (with --reference) the same model with the head's three
                    raw per-level outputs exposed, for the reference tests

ultralytics exports fold batch norm into the convolutions, so the initializers
are `model.N.*.conv.{weight,bias}` (and the head's final `*.2.{weight,bias}`);
the detector loads folded convolutions as they are.

Needs the `onnx` and `numpy` packages.

Usage: onnx_yolov8_to_safetensors.py MODEL.onnx OUT_STEM [--coco 0=person,1=person] [--reference]
"""
import argparse
import ast
import json
import os
import sys

import numpy as np
import onnx
from onnx import numpy_helper

# ultralytics' module index in yolov8.yaml -> the detector's candle prefix
# (services/detector/src/yolov8.rs). 10, 11, 13, 14, 17, 20 are Upsample and Concat.
BLOCKS = {
    0: "net.b1.0", 1: "net.b1.1", 2: "net.b2.0", 3: "net.b2.1", 4: "net.b2.2",
    5: "net.b3.0", 6: "net.b3.1", 7: "net.b4.0", 8: "net.b4.1", 9: "net.b5.0",
    12: "fpn.n1", 15: "fpn.n2", 16: "fpn.n3", 18: "fpn.n4", 19: "fpn.n5",
    21: "fpn.n6", 22: "head",
}


def candle_name(onnx_name):
    """`model.2.m.0.cv1.conv.weight` -> `net.b2.0.bottleneck.0.cv1.conv.weight`; None for non-weights."""
    parts = onnx_name.split(".")
    if len(parts) < 3 or parts[0] != "model" or not parts[1].isdigit():
        return None
    block = int(parts[1])
    if block not in BLOCKS:
        raise SystemExit(f"{onnx_name}: module model.{block} is not part of a YOLOv8 detection model")
    rest = parts[2:]
    if rest[0] == "m" and block != 22:
        rest = ["bottleneck"] + rest[1:]
    return BLOCKS[block] + "." + ".".join(rest)


def write_safetensors(path, tensors, metadata):
    header = {"__metadata__": metadata}
    offset = 0
    blobs = []
    for name in sorted(tensors):
        a = np.ascontiguousarray(tensors[name], dtype="<f4")
        blob = a.tobytes()
        header[name] = {"dtype": "F32", "shape": list(a.shape), "data_offsets": [offset, offset + len(blob)]}
        offset += len(blob)
        blobs.append(blob)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(len(text).to_bytes(8, "little"))
        f.write(text)
        for b in blobs:
            f.write(b)
    os.replace(tmp, path)


def yaml_scalar(s):
    """A class name as a YAML scalar (quoted when it could be read as something else)."""
    plain = s and all(c.isalnum() or c in " _-" for c in s) and not s[0].isdigit() and s.strip() == s
    if plain and s.lower() not in ("yes", "no", "true", "false", "null", "on", "off", "y", "n"):
        return s
    return json.dumps(s)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("onnx_file")
    ap.add_argument("out_stem", help="output path without extension, e.g. models/yolov8/mymodel")
    ap.add_argument("--coco", default="", help="class -> COCO mapping, e.g. 0=person,1=0 (index or name = COCO name or id)")
    ap.add_argument("--reference", action="store_true", help="also write OUT.onnx with the raw head outputs exposed")
    args = ap.parse_args()

    model = onnx.load(args.onnx_file)
    meta = {p.key: p.value for p in model.metadata_props}
    if meta.get("task", "detect") != "detect":
        raise SystemExit(f"{args.onnx_file}: task {meta['task']!r}; only detection models are supported")
    tensors = {}
    for init in model.graph.initializer:
        name = candle_name(init.name)
        if name is None:
            continue
        a = numpy_helper.to_array(init)
        if a.dtype not in (np.float16, np.float32, np.float64):
            raise SystemExit(f"{init.name}: unexpected dtype {a.dtype}")
        tensors[name] = a.astype(np.float32)
    if "head.dfl.conv.weight" not in tensors:
        raise SystemExit(f"{args.onnx_file}: no model.22.dfl.conv.weight; not a YOLOv8 detection export")
    if any(k.endswith(".bn.running_mean") for k in tensors):
        raise SystemExit("unfolded batch norm in an ONNX export is unexpected")
    nc = tensors["head.cv3.0.2.weight"].shape[0]

    names = {}
    if "names" in meta:
        names = {int(k): str(v) for k, v in ast.literal_eval(meta["names"]).items()}
    else:
        names = {i: f"class{i}" for i in range(nc)}
    if sorted(names) != list(range(nc)):
        raise SystemExit(f"the export's metadata names {len(names)} classes, its head has {nc}")

    coco = {}
    for item in filter(None, args.coco.split(",")):
        k, _, v = item.partition("=")
        k = k.strip()
        idx = int(k) if k.isdigit() else next((i for i, n in names.items() if n == k), None)
        if idx is None or idx not in names:
            raise SystemExit(f"--coco {item}: no class {k!r} (classes: {names})")
        coco[idx] = int(v) if v.strip().isdigit() else v.strip()

    os.makedirs(os.path.dirname(os.path.abspath(args.out_stem)), exist_ok=True)
    source = os.path.basename(args.onnx_file)
    write_safetensors(args.out_stem + ".safetensors", tensors, {
        "source": source,
        "ultralytics_version": meta.get("version", ""),
        "license": meta.get("license", ""),
        "classes": str(nc),
    })
    lines = [f"# Classes of {source} (ultralytics {meta.get('version', '?')}), for vlnav-detector.", "names:"]
    lines += [f"  {i}: {yaml_scalar(names[i])}" for i in range(nc)]
    if coco:
        lines += ["# The COCO-80 class each is reported as (FIND and FOLLOW name COCO classes).", "coco:"]
        lines += [f"  {i}: {coco[i] if isinstance(coco[i], int) else yaml_scalar(coco[i])}" for i in sorted(coco)]
    with open(args.out_stem + ".names.yaml", "w") as f:
        f.write("\n".join(lines) + "\n")

    if args.reference:
        # Expose the head's per-level raw outputs (box logits ++ class logits, [1, 64 + nc, h, w]).
        heads = [n.output[0] for n in model.graph.node
                 if n.op_type == "Concat" and len(n.input) == 2
                 and all("/model.22/cv" in i for i in n.input)]
        if len(heads) != 3:
            raise SystemExit(f"expected 3 head Concat nodes, found {len(heads)}")
        for h in heads:
            model.graph.output.append(onnx.helper.make_tensor_value_info(h, onnx.TensorProto.FLOAT, None))
        onnx.save(model, args.out_stem + ".onnx")

    params = sum(int(np.prod(t.shape)) for t in tensors.values())
    print(f"{args.out_stem}.safetensors: {len(tensors)} tensors, {params:,} parameters, {nc} classes {names}")


if __name__ == "__main__":
    sys.exit(main())
