#!/usr/bin/env python3
"""ONNX Runtime as the reference for the detector's YOLOv8: runs an ultralytics
ONNX export (as deploy/models.d/32-yolov8-fall.sh keeps it, with the head's
per-level outputs exposed) on network inputs the Rust side wrote, and writes
what it computed.

  ort_reference.py MODEL.onnx OUT_DIR INPUT.npy... [--threads N] [--conf C] [--iou I] [--bench N]

For each INPUT.npy (float32 [1, 3, 640, 640]) it writes, in OUT_DIR:
  <stem>.output0.npy      the model's output0, [1, 4 + classes, points]
  <stem>.head<k>.npy      level k's raw head output, [1, 64 + classes, h, w]
  <stem>.boxes.json       boxes after confidence filtering and class-aware NMS, as
                          ultralytics post-processes output0 (best class per point,
                          score > conf, greedy NMS per class at IoU > iou), in
                          network-input pixels: [[x_min, y_min, x_max, y_max, score, class], ...]
With --bench N it also times N runs of the first input (after 2 warm-up runs)
and writes OUT_DIR/bench.json {"threads": T, "ms": [...]}.

Needs onnxruntime and numpy (deploy/setup-tools.sh installs them into ./.venv).
"""
import argparse
import json
import os
import sys
import time

import numpy as np
import onnxruntime as ort


def nms(boxes, scores, classes, iou_threshold, max_det=300):
    order = np.argsort(-scores, kind="stable")
    keep = []
    for i in order:
        if len(keep) >= max_det:
            break
        ok = True
        for j in keep:
            if classes[j] != classes[i]:
                continue
            xx0 = max(boxes[i, 0], boxes[j, 0])
            yy0 = max(boxes[i, 1], boxes[j, 1])
            xx1 = min(boxes[i, 2], boxes[j, 2])
            yy1 = min(boxes[i, 3], boxes[j, 3])
            inter = max(0.0, xx1 - xx0) * max(0.0, yy1 - yy0)
            area = lambda b: max(0.0, b[2] - b[0]) * max(0.0, b[3] - b[1])
            union = area(boxes[i]) + area(boxes[j]) - inter
            if union > 0 and inter / union > iou_threshold:
                ok = False
                break
        if ok:
            keep.append(i)
    return keep


def postprocess(output0, conf, iou):
    pred = output0[0].T  # [points, 4 + classes]
    scores_all = pred[:, 4:]
    cls = scores_all.argmax(axis=1)
    score = scores_all.max(axis=1)
    mask = score > conf
    xywh, score, cls = pred[mask, :4], score[mask], cls[mask]
    boxes = np.stack([xywh[:, 0] - xywh[:, 2] / 2, xywh[:, 1] - xywh[:, 3] / 2,
                      xywh[:, 0] + xywh[:, 2] / 2, xywh[:, 1] + xywh[:, 3] / 2], axis=1)
    keep = nms(boxes, score, cls, iou)
    return [[float(v) for v in boxes[k]] + [float(score[k]), int(cls[k])] for k in keep]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("out_dir")
    ap.add_argument("inputs", nargs="+")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--conf", type=float, default=0.25)
    ap.add_argument("--iou", type=float, default=0.45)
    ap.add_argument("--bench", type=int, default=0)
    args = ap.parse_args()

    so = ort.SessionOptions()
    if args.threads:
        so.intra_op_num_threads = args.threads
        so.inter_op_num_threads = 1
    sess = ort.InferenceSession(args.model, so, providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    if names[0] != "output0" or len(names) != 4:
        sys.exit(f"{args.model}: outputs {names}; expected output0 and the three head outputs "
                 "(convert with services/detector/tools/onnx_yolov8_to_safetensors.py --reference)")
    in_name = sess.get_inputs()[0].name
    os.makedirs(args.out_dir, exist_ok=True)
    for path in args.inputs:
        x = np.load(path).astype(np.float32)
        outs = sess.run(None, {in_name: x})
        stem = os.path.splitext(os.path.basename(path))[0]
        np.save(os.path.join(args.out_dir, f"{stem}.output0.npy"), outs[0].astype(np.float32))
        for k, h in enumerate(outs[1:]):
            np.save(os.path.join(args.out_dir, f"{stem}.head{k}.npy"), h.astype(np.float32))
        with open(os.path.join(args.out_dir, f"{stem}.boxes.json"), "w") as f:
            json.dump(postprocess(outs[0], args.conf, args.iou), f)
    if args.bench:
        x = np.load(args.inputs[0]).astype(np.float32)
        for _ in range(2):
            sess.run(["output0"], {in_name: x})
        ms = []
        for _ in range(args.bench):
            t = time.perf_counter()
            sess.run(["output0"], {in_name: x})
            ms.append((time.perf_counter() - t) * 1000.0)
        with open(os.path.join(args.out_dir, "bench.json"), "w") as f:
            json.dump({"threads": args.threads, "ort_version": ort.__version__, "ms": ms}, f)


if __name__ == "__main__":
    main()
