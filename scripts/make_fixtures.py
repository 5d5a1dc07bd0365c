#!/usr/bin/env python3
"""Generate the ONNX test fixtures in assets/fixtures/ (and their manifests).

Usage:  pip install onnx numpy ; python3 scripts/make_fixtures.py [outdir]

Everything is deterministic (fixed numpy seeds), so re-running reproduces the
committed files byte for byte. The fixtures are:

  avoiding_path.onnx        deterministic Avoiding policy along one path (code 138)
  avoiding_noise.onnx       same steering, with a `noise` input [B,1] deciding every fork
                            (8 paths through the three obstacle rows -> entropy > 0)
  avoiding_k5_h3.onnx       avoiding_path with history k=5 and an action chunk H=3
  aligning_mlp.onnx         BC-MLP-sized MLP (20 -> 6x128 -> 3), random weights (benchmarks)
  aligning_mlp_batch1.onnx  the same MLP exported with a fixed batch dimension of 1
  aligning_image.onnx       image-policy shape fixture: `images` [B,1,2,3,96,96] -> [B,3]
  aligning_image_k2_h4.onnx image policy with history 2 and chunks of 4 executed whole:
                            the engine skips the frames the policy never sees
  aligning_resnet18.onnx    the paper's image architecture with random weights (benchmarks):
                            a ResNet-18 encoder per camera on the 96x96 BGR images, the two
                            512-d features concatenated with the low-dim `obs` [B,1,3], an MLP
                            head (1027 -> 256 -> 256 -> 3). Each conv weight is a small random
                            block tiled to the full ResNet-18 shape (`Tile` of a constant, which
                            the runtime folds at load time): the same compute as 2 x 11.2 M
                            weights, in a file of a few hundred KB instead of 90 MB
  hostile_*.onnx            truncated, garbage, huge declared initializer, external data,
                            wrong obs dim, wrong act dim, NaN output, endless compute,
                            a Tile memory bomb

Avoiding geometry (docs/original-d3il.md §10.2.1, §10.2.3-10.2.5): the policy input is
[desired x, desired y, measured x, measured y]; the action is the delta of the
desired xy. The policy steers the desired x towards a waypoint chosen from the
desired y (three phases: y < -0.04 before row 1, y < 0.16 before row 2, then row 3),
with |dx| <= 0.008 and dy = 0.008 (the demonstrations' step size, docs/original-d3il.md §10.1.8).
The deterministic path 0.57 -> 0.50 -> 0.575 is the spec's check case that succeeds
with code 138 (docs/original-d3il.md §10.2.5).

Noise policy: in each phase the rollout starts at a "home" x (the previous phase's
waypoint, or the start x 0.525). While the desired x is within 4 mm of home, the sign
of the noise picks the lower or upper waypoint; one step moves x by 8 mm, so the
choice is latched from then on by which side of home x lies. Waypoints sit in the
middle of the corridors of docs/original-d3il.md §10.2.1.
"""

import json
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17
EPS_HOME = 0.004
STEP = 0.008

# Phase boundaries on the desired y.
PHASE1_END = -0.04
PHASE2_END = 0.16

# (home x, lower waypoint, upper waypoint) per phase; region boundaries split x
# between homes (a waypoint shared by two homes lies on the boundary, and both
# homes steer to it, so a rollout sitting exactly there is consistent either way).
PHASES = [
    {"homes": [(0.525, 0.43, 0.57)], "bounds": []},
    {"homes": [(0.43, 0.35, 0.50), (0.57, 0.50, 0.65)], "bounds": [0.50]},
    {
        "homes": [(0.35, 0.30, 0.425), (0.50, 0.425, 0.575), (0.65, 0.575, 0.72)],
        "bounds": [0.425, 0.575],
    },
]
# The deterministic path: upper (0.57), lower (0.50), upper (0.575) -> code 2+8+128.
DETERMINISTIC_CHOICE = {0.525: True, 0.57: False, 0.50: True, 0.43: True, 0.35: True, 0.65: False}


class Graph:
    """Tiny builder that names nodes and constants automatically."""

    def __init__(self):
        self.nodes = []
        self.inits = []
        self.n = 0

    def name(self, prefix):
        self.n += 1
        return f"{prefix}_{self.n}"

    def const(self, value, dtype=np.float32):
        arr = np.asarray(value, dtype=dtype)
        name = self.name("c")
        self.inits.append(numpy_helper.from_array(arr, name))
        return name

    def op(self, op_type, inputs, **attrs):
        out = self.name(op_type.lower())
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def op_to(self, op_type, inputs, out, **attrs):
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def model(self, inputs, outputs, name):
        graph = helper.make_graph(self.nodes, name, inputs, outputs, self.inits)
        m = helper.make_model(
            graph,
            opset_imports=[helper.make_opsetid("", OPSET)],
            producer_name="d3il make_fixtures.py",
        )
        m.ir_version = 8
        onnx.checker.check_model(m)
        return m


def last_obs(g, obs):
    """obs [B,k,4] -> the newest observation [B,4] (index k-1)."""
    sl = g.op("Slice", [obs, g.const([-1], np.int64), g.const([2**62], np.int64), g.const([1], np.int64)])
    return g.op("Squeeze", [sl, g.const([1], np.int64)])


def column(g, x2d, j):
    return g.op("Slice", [x2d, g.const([j], np.int64), g.const([j + 1], np.int64), g.const([1], np.int64)])


def waypoint_for_home(g, x, pick_upper, home, lower, upper):
    """Target x for one home: latched by side once away from home, else the pick."""
    if isinstance(pick_upper, bool):
        at_home = g.const(upper if pick_upper else lower)
    else:
        at_home = g.op("Where", [pick_upper, g.const(upper), g.const(lower)])
    below = g.op("Less", [x, g.const(home - EPS_HOME)])
    above = g.op("Greater", [x, g.const(home + EPS_HOME)])
    t = g.op("Where", [below, g.const(lower), at_home])
    return g.op("Where", [above, g.const(upper), t])


def phase_target(g, x, phase, pick):
    homes = phase["homes"]
    targets = [waypoint_for_home(g, x, pick(h[0]), *h) for h in homes]
    # Select the region from the right: x < bound_i -> home i.
    t = targets[-1]
    for i in reversed(range(len(phase["bounds"]))):
        cond = g.op("Less", [x, g.const(phase["bounds"][i])])
        t = g.op("Where", [cond, targets[i], t])
    return t


def avoiding_graph(noise, history=1, horizon=1):
    g = Graph()
    obs = "obs"
    last = last_obs(g, obs)
    x = column(g, last, 0)  # desired x [B,1]
    y = column(g, last, 1)  # desired y [B,1]
    if noise:
        # One fresh N(0,1) sample per query; its sign decides the fork at home.
        positive = g.op("Greater", ["noise", g.const(0.0)])
        pick = lambda home: positive  # noqa: E731
    else:
        pick = lambda home: DETERMINISTIC_CHOICE[home]  # noqa: E731
    t1 = phase_target(g, x, PHASES[0], pick)
    t2 = phase_target(g, x, PHASES[1], pick)
    t3 = phase_target(g, x, PHASES[2], pick)
    in1 = g.op("Less", [y, g.const(PHASE1_END)])
    in2 = g.op("Less", [y, g.const(PHASE2_END)])
    tx = g.op("Where", [in1, t1, g.op("Where", [in2, t2, t3])])
    dx = g.op("Clip", [g.op("Sub", [tx, x]), g.const(-STEP), g.const(STEP)])
    dy = g.op("Add", [g.op("Mul", [y, g.const(0.0)]), g.const(STEP)])
    if horizon == 1:
        g.op_to("Concat", [dx, dy], "actions", axis=1)
        out_shape = ["B", 2]
    else:
        act = g.op("Concat", [dx, dy], axis=1)
        act3 = g.op("Unsqueeze", [act, g.const([1], np.int64)])
        # The same action repeated H times; the manifest executes only the first.
        g.op_to("Concat", [act3] * horizon, "actions", axis=1)
        out_shape = ["B", horizon, 2]
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", history, 4])]
    if noise:
        inputs.append(helper.make_tensor_value_info("noise", TensorProto.FLOAT, ["B", 1]))
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, out_shape)]
    return g.model(inputs, outputs, "avoiding_noise" if noise else "avoiding_path")


def mlp_graph(batch="B", obs_dim=20, hidden=128, layers=6, act_dim=3, seed=0, noise=False):
    """BC-MLP size from the paper: 6 hidden layers of 128 (ReLU). With `noise`,
    the actions get 1e-4 times the evaluator's noise added, which makes the policy
    stochastic (every rollout is simulated) at the same cost."""
    rng = np.random.default_rng(seed)
    g = Graph()
    h = g.op("Flatten", ["obs"], axis=1)
    dims = [obs_dim] + [hidden] * layers + [act_dim]
    for i in range(len(dims) - 1):
        w = rng.normal(0.0, 1.0 / np.sqrt(dims[i]), size=(dims[i], dims[i + 1])).astype(np.float32)
        b = np.zeros(dims[i + 1], np.float32)
        if i == len(dims) - 2:
            w *= 0.01  # keep benchmark actions small (centimetre-scale deltas)
            if noise:
                mean = g.op("Gemm", [h, g.const(w), g.const(b)])
                g.op_to("Add", [mean, g.op("Mul", ["noise", g.const(1e-4)])], "actions")
            else:
                g.op_to("Gemm", [h, g.const(w), g.const(b)], "actions")
        else:
            h = g.op("Relu", [g.op("Gemm", [h, g.const(w), g.const(b)])])
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [batch, 1, obs_dim])]
    if noise:
        inputs.append(helper.make_tensor_value_info("noise", TensorProto.FLOAT, [batch, act_dim]))
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [batch, act_dim])]
    return g.model(inputs, outputs, "aligning_mlp")


def image_graph():
    """Mean over pixels of both cameras -> linear to 3 actions (shape fixture only)."""
    g = Graph()
    pooled = g.op("ReduceMean", ["images"], axes=[1, 2, 3, 4, 5], keepdims=0)  # [B]
    col = g.op("Unsqueeze", [pooled, g.const([1], np.int64)])  # [B,1]
    g.op_to("MatMul", [col, g.const(np.full((1, 3), 0.001, np.float32))], "actions")
    inputs = [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["B", 1, 2, 3, 96, 96])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 3])]
    m = g.model(inputs, outputs, "aligning_image")
    # ReduceMean with `axes` as attribute needs opset < 18; 17 is what we use.
    return m


def chunked_image_graph(history, horizon):
    """Mean over every pixel of the window (all k frames, both cameras) -> a chunk of
    `horizon` different actions (shape fixture for skipped frames)."""
    g = Graph()
    pooled = g.op("ReduceMean", ["images"], axes=[1, 2, 3, 4, 5], keepdims=0)  # [B]
    col = g.op("Unsqueeze", [pooled, g.const([1, 2], np.int64)])  # [B,1,1]
    w = np.array([[0.001 * (h + 1) * (a + 1) for a in range(3)] for h in range(horizon)], np.float32)
    g.op_to("Mul", [col, g.const(w[None])], "actions")  # [B,H,3]
    inputs = [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["B", history, 2, 3, 96, 96])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", horizon, 3])]
    return g.model(inputs, outputs, "aligning_image_chunked")


def wrong_obs_dim_graph():
    """Avoiding-shaped policy whose `obs` has last dimension 3 instead of 4."""
    g = Graph()
    g.op_to("Slice", [g.op("Flatten", ["obs"], axis=1), g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 3])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "wrong_obs_dim")


def wrong_act_dim_graph():
    """Avoiding input, but 3 actions per row instead of 2."""
    g = Graph()
    g.op_to("Slice", [g.op("Flatten", ["obs"], axis=1), g.const([0], np.int64), g.const([3], np.int64), g.const([1], np.int64)], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 3])]
    return g.model(inputs, outputs, "wrong_act_dim")


def nan_graph():
    """Avoiding shapes; every action is sqrt(-1 - |x|) = NaN (depends on the input,
    so it cannot be folded away; tract simplifies x*0/x*0 to a finite value)."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    two = g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)])
    negative = g.op("Sub", [g.const(-1.0), g.op("Abs", [two])])
    g.op_to("Sqrt", [negative], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "nan_output")


def random_op_graph():
    """Avoiding shapes; draws its own noise with a RandomNormalLike operator
    (what torch.randn in forward exports to) instead of taking the `noise` input."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    two = g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)])
    jitter = g.op("Mul", [g.op("RandomNormalLike", [two]), g.const(0.001)])
    g.op_to("Add", [two, jitter], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "random_op")


def mixes_rows_graph():
    """Avoiding shapes; subtracts the batch mean from each row (batch statistics, as
    a BatchNorm exported in training mode does), so a row's actions depend on the
    other rows of the batch."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    two = g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)])
    g.op_to("Sub", [two, g.op("ReduceMean", [two], axes=[0], keepdims=1)], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "mixes_rows")


def endless_graph(n=4096, repeats=64):
    """A chain of input-dependent n x n MatMuls: ~64 x 1.4e11 flop per query, so a
    query never finishes in useful time; the file itself stays tiny (the big
    matrix is built at run time from the observation, so nothing can be folded)."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    s = g.op("ReduceSum", [flat], keepdims=0)  # scalar over the whole batch
    row = g.op("Reshape", [s, g.const([1, 1], np.int64)])
    m = g.op("Tile", [row, g.const([n, n], np.int64)])
    m = g.op("Mul", [m, g.const(1.0 / n)])
    for _ in range(repeats):
        m = g.op("MatMul", [m, m])
    corner = g.op("Slice", [m, g.const([0, 0], np.int64), g.const([1, 2], np.int64), g.const([0, 1], np.int64)])  # [1,2]
    zeros = g.op("Mul", [g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)]), g.const(0.0)])
    g.op_to("Add", [zeros, corner], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "endless")


def tile_bomb_graph(n=1 << 20):
    """A tiny file whose one Tile node asks for an n x n float32 tensor at run
    time (4 TiB for n = 2^20): more than any memory limit or machine allows,
    built from the observation so nothing can be folded at load."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    s = g.op("ReduceSum", [flat], keepdims=0)
    row = g.op("Reshape", [s, g.const([1, 1], np.int64)])
    m = g.op("Tile", [row, g.const([n, n], np.int64)])
    corner = g.op("Slice", [m, g.const([0, 0], np.int64), g.const([1, 2], np.int64), g.const([0, 1], np.int64)])  # [1,2]
    zeros = g.op("Mul", [g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)]), g.const(0.0)])
    g.op_to("Add", [zeros, corner], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    return g.model(inputs, outputs, "tile_bomb")


def huge_initializer_model(external):
    """A valid-looking Avoiding graph with a 100000 x 100000 float32 initializer
    (40 GB declared). Embedded variant: 16 bytes of actual data; external variant:
    data_location = EXTERNAL pointing at a file that does not exist."""
    g = Graph()
    flat = g.op("Flatten", ["obs"], axis=1)
    two = g.op("Slice", [flat, g.const([0], np.int64), g.const([2], np.int64), g.const([1], np.int64)])
    big = TensorProto()
    big.name = "huge_weight"
    big.data_type = TensorProto.FLOAT
    big.dims.extend([100000, 100000])
    if external:
        big.data_location = TensorProto.EXTERNAL
        for k, v in [("location", "huge_weight.bin"), ("offset", "0"), ("length", str(100000 * 100000 * 4))]:
            e = big.external_data.add()
            e.key = k
            e.value = v
    else:
        big.raw_data = b"\0" * 16
    g.inits.append(big)
    first = g.op("Slice", ["huge_weight", g.const([0, 0], np.int64), g.const([1, 2], np.int64), g.const([0, 1], np.int64)])
    g.op_to("Add", [two, first], "actions")
    inputs = [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 4])]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 2])]
    graph = helper.make_graph(g.nodes, "huge_initializer", inputs, outputs, g.inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    m.ir_version = 8
    # No checker: it would try to read the external file / validate sizes.
    return m


def resnet18_image_graph(seed=3, block=8):
    """The paper's image policy shape (see the module docstring). BatchNorm is folded
    into the convolutions (inference form: conv + bias)."""
    rng = np.random.default_rng(seed)
    g = Graph()

    def weight(cout, cin, k, gain=1.0):
        bo, bi = min(block, cout), min(block, cin)
        # The tiled input channels repeat in groups (the previous layer's outputs are
        # tiled too), so the sum over cin adds cin/bi equal copies: scale for that.
        std = gain * np.sqrt(2.0 / (bi * k * k)) / (cin // bi)
        small = g.const(rng.normal(0.0, std, size=(bo, bi, k, k)).astype(np.float32))
        reps = g.const([cout // bo, cin // bi, 1, 1], np.int64)
        return g.op("Tile", [small, reps])

    def conv(x, cout, cin, k, stride, relu=True, gain=1.0):
        pad = k // 2
        y = g.op("Conv", [x, weight(cout, cin, k, gain), g.const(np.zeros(cout, np.float32))],
                 kernel_shape=[k, k], strides=[stride, stride], pads=[pad] * 4)
        return g.op("Relu", [y]) if relu else y

    def basic_block(x, cin, cout, stride):
        y = conv(x, cout, cin, 3, stride)
        y = conv(y, cout, cout, 3, 1, relu=False, gain=0.5)
        skip = x if (stride == 1 and cin == cout) else conv(x, cout, cin, 1, stride, relu=False)
        return g.op("Relu", [g.op("Add", [y, skip])])

    def encoder(img):  # [B,3,96,96] -> [B,512]
        x = conv(img, 64, 3, 7, 2)  # 48x48
        x = g.op("MaxPool", [x], kernel_shape=[3, 3], strides=[2, 2], pads=[1, 1, 1, 1])  # 24x24
        cin = 64
        for cout, stride in [(64, 1), (128, 2), (256, 2), (512, 2)]:
            x = basic_block(x, cin, cout, stride)
            x = basic_block(x, cout, cout, 1)
            cin = cout
        return g.op("Flatten", [g.op("GlobalAveragePool", [x])], axis=1)

    feats = []
    for cam in range(2):
        sl = g.op("Slice", ["images", g.const([0, cam], np.int64), g.const([1, cam + 1], np.int64),
                            g.const([1, 2], np.int64)])  # [B,1,1,3,96,96], newest frame
        img = g.op("Reshape", [sl, g.const([-1, 3, 96, 96], np.int64)])
        feats.append(encoder(img))
    low = g.op("Flatten", [last_obs(g, "obs")], axis=1)  # [B,3]
    h = g.op("Concat", feats + [low], axis=1)  # [B,1027]
    dims = [2 * 512 + 3, 256, 256, 3]
    for i in range(len(dims) - 1):
        w = rng.normal(0.0, 1.0 / np.sqrt(dims[i]), size=(dims[i], dims[i + 1])).astype(np.float32)
        b = np.zeros(dims[i + 1], np.float32)
        if i == len(dims) - 2:
            w *= 0.001  # keep benchmark actions small
            g.op_to("Gemm", [h, g.const(w), g.const(b)], "actions")
        else:
            h = g.op("Relu", [g.op("Gemm", [h, g.const(w), g.const(b)])])
    inputs = [
        helper.make_tensor_value_info("images", TensorProto.FLOAT, ["B", 1, 2, 3, 96, 96]),
        helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["B", 1, 3]),
    ]
    outputs = [helper.make_tensor_value_info("actions", TensorProto.FLOAT, ["B", 3])]
    return g.model(inputs, outputs, "aligning_resnet18")


def manifest(task, history=1, horizon=1, execute=1, obs_type="state"):
    return {"task": task, "obs_type": obs_type, "history": history, "horizon": horizon, "execute": execute}


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "assets", "fixtures")
    os.makedirs(out, exist_ok=True)

    def save(name, model_or_bytes, man, note):
        path = os.path.join(out, name + ".onnx")
        data = model_or_bytes if isinstance(model_or_bytes, bytes) else model_or_bytes.SerializeToString()
        with open(path, "wb") as f:
            f.write(data)
        man = dict(man, note=note)
        with open(os.path.join(out, name + ".json"), "w") as f:
            json.dump(man, f, indent=2)
            f.write("\n")
        print(f"{path}: {len(data)} bytes")

    av = manifest("avoiding")
    save("avoiding_path", avoiding_graph(noise=False), av,
         "deterministic path 0.57 -> 0.50 -> 0.575 (behaviour code 138); expected success, entropy 0")
    save("avoiding_noise", avoiding_graph(noise=True), av,
         "noise sign picks the waypoint at each of the three rows: 8 paths, entropy > 0")
    save("avoiding_k5_h3", avoiding_graph(noise=False, history=5, horizon=3), manifest("avoiding", 5, 3, 1),
         "avoiding_path with history 5 (uses the newest) and a chunk of 3 identical actions, execute 1")
    save("aligning_mlp", mlp_graph(), manifest("aligning"),
         "BC-MLP size (20 -> 6x128 ReLU -> 3), random weights, for benchmarks")
    save("aligning_mlp_noise", mlp_graph(noise=True), manifest("aligning"),
         "aligning_mlp plus 1e-4 x the noise input: stochastic, so every rollout is simulated (bench scale)")
    save("aligning_mlp_batch1", mlp_graph(batch=1), manifest("aligning"),
         "the same MLP with a fixed batch dimension of 1 (evaluator runs rows one by one)")
    save("aligning_image", image_graph(), manifest("aligning", obs_type="image"),
         "image policy shape fixture: images [B,1,2,3,96,96] -> actions [B,3]")
    save("aligning_image_k2_h4", chunked_image_graph(2, 4),
         manifest("aligning", history=2, horizon=4, execute=4, obs_type="image"),
         "image policy, history 2, chunks of 4 executed whole: the mean pixel of both frames "
         "and cameras -> 4 different actions; 2 of every 4 frames leave the window unseen")
    save("aligning_resnet18", resnet18_image_graph(), manifest("aligning", obs_type="image"),
         "the paper's image architecture, random weights (benchmarks): ResNet-18 per camera on "
         "images [B,1,2,3,96,96] + obs [B,1,3] -> MLP 256x2 -> actions [B,3]")

    good = avoiding_graph(noise=False).SerializeToString()
    save("hostile_truncated", good[: len(good) // 2], av, "first half of avoiding_path.onnx")
    save("hostile_garbage", np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes(), av,
         "4096 random bytes")
    save("hostile_huge_initializer", huge_initializer_model(external=False), av,
         "initializer declaring 100000x100000 float32 (40 GB) with 16 bytes of data")
    save("hostile_external_data", huge_initializer_model(external=True), av,
         "initializer stored as external data (a 40 GB file next to the model)")
    save("hostile_wrong_obs_dim", wrong_obs_dim_graph(), av, "obs last dimension 3, Avoiding needs 4")
    save("hostile_wrong_act_dim", wrong_act_dim_graph(), av, "3 actions per row, Avoiding needs 2")
    save("hostile_nan", nan_graph(), av, "every action is NaN")
    save("hostile_mixes_rows", mixes_rows_graph(), av,
         "subtracts the batch mean from each row: a row's actions depend on the other rows")
    save("hostile_random_op", random_op_graph(), av,
         "draws noise with an in-graph RandomNormalLike instead of the noise input (not reproducible)")
    save("hostile_endless", endless_graph(), av, "64 chained 4096x4096 MatMuls per query: never finishes in time")
    save("hostile_tile_bomb", tile_bomb_graph(), av, "one Tile node asking for a 2^20 x 2^20 float32 tensor (4 TiB) per query")


if __name__ == "__main__":
    main()
