#!/usr/bin/env python3
"""Time onnxruntime on the agent fixtures, for `d3il bench agents`.

Usage: python3 bench_onnxruntime.py DIR BATCH [SECONDS]
    Prints one JSON object: {fixture name: milliseconds per call}.
Usage: python3 bench_onnxruntime.py --serve DIR BATCH
    Reads lines `NAME SECONDS` on stdin and answers each with one line: the
    milliseconds per call of fixture NAME timed for SECONDS (at least 3 calls).
    `d3il bench agents` uses this to alternate onnxruntime's and its own timing
    of each fixture, so both see the same load on a shared machine.

Inputs have the shapes `d3il bench agents` uses (window k, batch BATCH,
standard-normal noise); onnxruntime runs with its defaults (all cores).
"""

import json
import os
import sys
import time

import numpy as np
import onnxruntime as ort


class Fixtures:
    def __init__(self, d, batch):
        self.d, self.batch = d, batch
        self.rng = np.random.default_rng(0)
        self.loaded = {}

    def names(self):
        return [f[:-5] for f in sorted(os.listdir(self.d)) if f.endswith(".onnx")]

    def get(self, name):
        if name not in self.loaded:
            with open(os.path.join(self.d, name + ".json")) as m:
                k = json.load(m)["history"]
            sess = ort.InferenceSession(os.path.join(self.d, name + ".onnx"), providers=["CPUExecutionProvider"])
            feed = {}
            for i in sess.get_inputs():
                shape = [self.batch] + [k if not isinstance(s, int) else s for s in i.shape[1:]]
                if i.name == "prev_actions":
                    shape[1] = k - 1
                feed[i.name] = self.rng.standard_normal(shape).astype(np.float32)
            sess.run(None, feed)  # warm-up
            self.loaded[name] = (sess, feed)
        return self.loaded[name]

    def time_ms(self, name, budget):
        sess, feed = self.get(name)
        n, t0 = 0, time.perf_counter()
        while n < 3 or time.perf_counter() - t0 < budget:
            sess.run(None, feed)
            n += 1
        return 1000.0 * (time.perf_counter() - t0) / n


def main():
    if sys.argv[1] == "--serve":
        fx = Fixtures(sys.argv[2], int(sys.argv[3]))
        for line in sys.stdin:
            parts = line.split()
            if len(parts) != 2:
                continue
            print(fx.time_ms(parts[0], float(parts[1])), flush=True)
        return
    fx = Fixtures(sys.argv[1], int(sys.argv[2]))
    budget = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0
    print(json.dumps({name: fx.time_ms(name, budget) for name in fx.names()}))


if __name__ == "__main__":
    main()
