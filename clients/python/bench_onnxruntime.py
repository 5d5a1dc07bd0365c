#!/usr/bin/env python3
"""Time onnxruntime on the agent fixtures, for `d3il bench agents`.

Usage: python3 bench_onnxruntime.py DIR BATCH [SECONDS]
Prints one JSON object: {fixture name: milliseconds per call}. Inputs have the
shapes `d3il bench agents` uses (window k, batch BATCH, standard-normal noise);
onnxruntime runs with its defaults (all cores).
"""

import json
import os
import sys
import time

import numpy as np
import onnxruntime as ort


def main():
    d, batch = sys.argv[1], int(sys.argv[2])
    budget = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0
    rng = np.random.default_rng(0)
    out = {}
    for f in sorted(os.listdir(d)):
        if not f.endswith(".onnx"):
            continue
        name = f[:-5]
        with open(os.path.join(d, name + ".json")) as m:
            k = json.load(m)["history"]
        sess = ort.InferenceSession(os.path.join(d, f), providers=["CPUExecutionProvider"])
        feed = {}
        for i in sess.get_inputs():
            shape = [batch] + [k if not isinstance(s, int) else s for s in i.shape[1:]]
            if i.name == "prev_actions":
                shape[1] = k - 1
            feed[i.name] = rng.standard_normal(shape).astype(np.float32)
        sess.run(None, feed)
        n, t0 = 0, time.perf_counter()
        while n < 3 or time.perf_counter() - t0 < budget:
            sess.run(None, feed)
            n += 1
        out[name] = 1000.0 * (time.perf_counter() - t0) / n
    print(json.dumps(out))


if __name__ == "__main__":
    main()
