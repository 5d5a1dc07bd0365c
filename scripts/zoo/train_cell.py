"""One zoo cell: train a paper method with the REFERENCE code (ALRhub/d3il) on our
demonstrations, export it to ONNX, evaluate it with our evaluator and write its
provenance record (docs/zoo.md).

    PYTHONPATH=clients/python ~/.cache/d3il/venvs/torch/bin/python scripts/zoo/train_cell.py \
        --reference /work/d3il-ref --demos /work/demos/aligning \
        --task aligning --method bc --seed 0 --out assets/zoo/aligning/bc-mlp-s0

The reference code is run, never copied: the configuration is composed with Hydra from
the checkout's configs/<task>_config.yaml, agents=<name>_agent and the overrides of the
checkout's scripts/<task>/<method>_benchmark.sh (read at run time), then ours (cpu, the
epoch budget, the seed, ...); `hydra.utils.instantiate(cfg.agents).train_agent()`
trains; like run.py, the checkpoint best on the evaluation split is the policy. The
reference's simulation is not run.

The dataset classes read fixed paths under the checkout
(environments/dataset/data/<dir>/...); the driver builds a private mirror of the
checkout out of symlinks in its work directory whose environments/dataset/data/<dir> is
the demonstration directory, so the checkout is never modified and the configs' own
data paths are used unchanged.

Stages, each written into <work>/<stage>.tmp and renamed to <work>/<stage> when done,
so a killed run resumes at the stage it stopped: train -> export -> eval -> final
(the cell directory, renamed into place with provenance.json last).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import functools
import hashlib
import json
import os
import platform
import random
import shlex
import shutil
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
PROJECT = HERE.parent.parent

#: our method key -> (paper name, reference agent config name)
METHODS = {
    "bc": ("BC-MLP", "bc_agent"),
    "cvae": ("VAE-State", "cvae_agent"),
    "act": ("VAE-ACT", "act_agent"),
    "bet_mlp": ("BeT-MLP", "bet_mlp_agent"),
    "bet": ("BeT", "bet_agent"),
    "ibc": ("IBC", "ibc_agent"),
    "ddpm": ("DDPM-MLP", "ddpm_agent"),
    "ddpm_transformer": ("DDPM-GPT", "ddpm_transformer_agent"),
    "ddpm_encdec": ("DDPM-ACT", "ddpm_encdec_agent"),
    "beso": ("BESO", "beso_agent"),
    "gpt_bc": ("BC-GPT", "gpt_bc_agent"),
}

#: our task name -> (config name, scripts/<dir>, environments/dataset/data/<dir>)
TASKS = {
    "avoiding": ("avoiding_config", "avoiding", "avoiding"),
    "aligning": ("aligning_config", "aligning", "aligning"),
    "pushing": ("pushing_config", "pushing", "pushing"),
    "sorting-2": ("sorting_2_config", "sorting", "sorting"),
    "sorting-4": ("sorting_4_config", "sorting_4", "sorting"),
    "sorting-6": ("sorting_6_config", "sorting_6", "sorting"),
    "stacking": ("stacking_config", "stacking", "stacking"),
}

STAGES = ("train", "export", "eval")


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True, text=True).stdout.strip()


def now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def load_budgets(path: Path, task: str, method: str) -> dict:
    """The cell's budget: budgets.json's default, then its entry for the method, then
    for the (task, method) cell, each overriding the one before."""
    doc = json.loads(path.read_text())
    cell = dict(doc["default"])
    cell.update(doc.get("methods", {}).get(method, {}))
    cell.update(doc.get("cells", {}).get(task, {}).get(method, {}))
    return {"paper": doc["paper"], "cell": cell}


def budget_epochs(cell: dict, train_samples: int) -> tuple[int, str]:
    """Epochs of a budget: given as "epoch", or as "samples" (training samples seen,
    i.e. epochs x the training set's windows), which fixes the compute whatever the
    number of demonstrations and, unlike a time budget, gives the same epochs on any
    machine."""
    if "epoch" in cell:
        return int(cell["epoch"]), f"epoch {cell['epoch']} (budgets.json)"
    want = float(cell["samples"])
    lo, hi = int(cell.get("min_epochs", 1)), int(cell.get("max_epochs", 500))
    e = max(lo, min(hi, round(want / max(train_samples, 1))))
    return e, (f"samples {want:.0f} / {train_samples} training windows = {want / max(train_samples, 1):.1f}, "
               f"rounded and kept in [{lo}, {hi}]: {e} epochs")


# ---------------------------------------------------------------- reference setup


def script_overrides(reference: Path, task: str, method: str) -> list[str]:
    """The overrides of scripts/<dir>/<method>_benchmark.sh, minus --multirun, the
    config name and the seed sweep (we set the seed)."""
    script = reference / "scripts" / TASKS[task][1] / f"{method}_benchmark.sh"
    text = script.read_text().replace("\\\n", " ")
    words = shlex.split(text, comments=True)
    if "run.py" not in words:
        raise SystemExit(f"{script}: no `python run.py ...` line")
    out = []
    for w in words[words.index("run.py") + 1 :]:
        if w.startswith("--") or w.startswith("seed="):
            continue
        out.append(w)
    return out


def rename_keys(overrides: list[str], renames: dict, values: dict | None = None) -> list[str]:
    """The script's overrides with keys renamed as budgets.json's "script_renames"
    says: for a benchmark script that names a key its own agent config does not
    have at that path (Hydra refuses it), the key where the config has it; and
    values replaced as its "script_values" says: for a script that names a config
    the checkout does not have (e.g. `agents=ddpm_encdec`, whose file is
    ddpm_encdec_agent.yaml), the one it has. Every rename and value is listed in the
    provenance's budget.changes with its reason."""
    values = values or {}
    out = []
    for o in overrides:
        key, sep, value = o.partition("=")
        if sep and key in values:
            value = values[key]
        out.append(f"{renames.get(key, key)}{sep}{value}" if sep else o)
    return out


def mirror(reference: Path, demos: Path, data_dir: str, dest: Path) -> Path:
    """A tree of symlinks to the checkout whose environments/dataset/data/<data_dir>
    is `demos` (sim_framework_path takes its root from the imported module's path,
    which does not resolve symlinks)."""
    if dest.exists():
        shutil.rmtree(dest)
    path = ["environments", "dataset", "data", data_dir]

    def build(src: Path, dst: Path, depth: int):
        dst.mkdir(parents=True)
        for entry in sorted(src.iterdir()):
            if depth < len(path) - 1 and entry.name == path[depth]:
                build(entry, dst / entry.name, depth + 1)
            elif depth == len(path) - 1 and entry.name == path[depth]:
                continue
            else:
                (dst / entry.name).symlink_to(entry.resolve())
        if depth == len(path) - 1:
            (dst / path[depth]).symlink_to(demos.resolve())

    build(reference.resolve(), dest, 0)
    return dest


def demos_info(demos: Path) -> dict:
    manifest = demos / "manifest.json"
    if not manifest.is_file():
        raise SystemExit(f"{demos}: no manifest.json (write the demonstrations with `d3il demos`)")
    doc = json.loads(manifest.read_text())
    info = {"path": str(demos.resolve()), "manifest_sha256": sha256(manifest)}
    # the manifest's small top-level entries (version, command, commit, options, counts,
    # histogram, ...); per-file hashes and per-episode rows stay in the manifest itself
    for key, value in doc.items():
        if len(json.dumps(value)) <= 2000:
            info.setdefault("manifest", {})[key] = value
    import pickle

    for p in sorted(demos.glob("*_files.pkl")):  # train_files.pkl, eval_files.pkl, 2_boxes_train_files.pkl
        with open(p, "rb") as f:
            info.setdefault("episodes_listed", {})[p.name] = len(pickle.load(f))
    if (demos / "data").is_dir():  # Avoiding: the dataset reads every file of data/
        info["episodes_in_data_dir"] = sum(1 for _ in (demos / "data").iterdir())
    return info


class Recorder:
    """What the agent logs to wandb, per epoch of its own tqdm(range(epoch)) loop."""

    def __init__(self):
        self.epoch = None
        self.logs = defaultdict(lambda: defaultdict(list))
        self.epoch_seconds = {}

    def tqdm(self, iterable, *args, **kwargs):
        """Replaces the agent module's tqdm around its epoch loop: records the epoch
        and its time, and prints progress about every 30 s."""
        total = len(iterable) if hasattr(iterable, "__len__") else None
        start = last = time.perf_counter()
        for item in iterable:
            self.epoch = item
            t0 = time.perf_counter()
            yield item
            t1 = time.perf_counter()
            self.epoch_seconds[item] = t1 - t0
            if t1 - last >= 30:
                last = t1
                vs = self.logs[item].get("loss", self.logs[item].get("total_loss", []))
                loss = f", loss {sum(vs) / len(vs):.4g}" if vs else ""
                print(f"[zoo]   epoch {item + 1}/{total or '?'}{loss}, {t1 - start:.0f} s", flush=True)
        self.epoch = None

    def log(self, data, *args, **kwargs):
        for k, v in dict(data).items():
            try:
                if hasattr(v, "detach"):
                    v = v.detach()
                self.logs[self.epoch][k].append(float(v))
            except (TypeError, ValueError):
                pass

    def curve(self) -> list[dict]:
        rows = []
        for e in sorted(k for k in self.logs if k is not None):
            row = {"epoch": e}
            for k, vs in self.logs[e].items():
                row[k] = sum(vs) / len(vs)
            loss = row.get("loss", row.get("total_loss"))
            if loss is not None:
                row["train_loss"] = loss
            if e in self.epoch_seconds:
                row["seconds"] = round(self.epoch_seconds[e], 3)
            rows.append(row)
        return rows


def reference_env(shadow: Path, threads: int):
    """Import path, torch threads, wandb off and recorded, the run.py resolver."""
    os.environ["WANDB_MODE"] = "disabled"
    os.environ.setdefault("WANDB_SILENT", "true")
    import torch
    import wandb
    from omegaconf import OmegaConf

    torch.set_num_threads(threads)
    if str(shadow) not in sys.path:
        sys.path.insert(0, str(shadow))
    OmegaConf.register_new_resolver("add", lambda *numbers: sum(numbers), replace=True)
    wandb.init(mode="disabled")
    recorder = Recorder()
    wandb.log = recorder.log
    return recorder


def set_seed_everywhere(seed: int):
    """run.py's seeding."""
    import numpy as np
    import torch

    torch.manual_seed(seed)
    np.random.seed(seed)
    random.seed(seed)


def compose(shadow: Path, task: str, overrides: list[str]):
    from hydra import compose as hcompose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(shadow / "configs"), version_base=None):
        return hcompose(config_name=TASKS[task][0], overrides=overrides)


def instantiate_agent(cfg, recorder: Recorder, workdir: Path):
    """hydra.utils.instantiate(cfg.agents) with the working directory (where the agent
    stores weights) set to `workdir`, and the agent module's tqdm recorded."""
    import importlib

    import hydra

    module = importlib.import_module(cfg.agents._target_.rsplit(".", 1)[0])
    module.tqdm = recorder.tqdm
    old = os.getcwd()
    os.chdir(workdir)
    try:
        agent = hydra.utils.instantiate(cfg.agents)
    finally:
        os.chdir(old)
    agent.working_dir = str(workdir)
    return agent


@contextlib.contextmanager
def trusted_torch_load():
    """BeT-MLP's store_model_weights pickles modules; its load_pretrained_model calls
    torch.load without arguments, which torch >= 2.6 refuses (weights_only=True).
    We load only the file this driver just wrote."""
    import torch

    orig = torch.load
    torch.load = functools.partial(orig, weights_only=False)
    try:
        yield
    finally:
        torch.load = orig


# ---------------------------------------------------------------- stages


def stage_train(a, work: Path, shadow: Path, tmp: Path):
    import torch
    from omegaconf import OmegaConf

    from d3il_client.agents.loading import save_scaler

    import hydra

    budgets = load_budgets(a.budgets, a.task, a.method)
    cell = budgets["cell"]
    paper = budgets["paper"]
    batch = a.batch_size if a.batch_size is not None else int(cell["train_batch_size"])
    # budgets.json may add overrides of its own to a cell (e.g. fewer sampling steps where
    # the method's own would not evaluate within the session; "why" says so): applied after
    # the benchmark script's (before the training set is sized), listed in budget.changes
    script = rename_keys(script_overrides(a.reference, a.task, a.method), cell.get("script_renames", {}),
                         cell.get("script_values", {}))
    extra = list(cell.get("overrides", []))
    base = [f"seed={a.seed}", "device=cpu", "num_workers=1", f"train_batch_size={batch}"]
    recorder = reference_env(shadow, a.threads)
    if a.epochs is not None:
        epochs, why = a.epochs, f"--epochs {a.epochs}"
        windows = None
    else:
        # the training set's size (windows of window_size steps) decides a samples budget
        windows = len(hydra.utils.instantiate(compose(shadow, a.task, script + extra + base).trainset))
        epochs, why = budget_epochs(cell, windows)
    # the paper evaluates 10 times in a training (every 50 of 500 epochs); a budget may
    # ask for fewer ("evaluations"), where one evaluation costs many epochs (IBC's)
    evaluations = int(cell.get("evaluations", paper["epoch"] // paper["eval_every_n_epochs"]))
    eval_every = a.eval_every or max(1, round(epochs / evaluations))
    ours = base + [f"epoch={epochs}", f"eval_every_n_epochs={eval_every}"]
    overrides = script + extra + ours
    cfg = compose(shadow, a.task, overrides)
    set_seed_everywhere(a.seed)
    t0 = time.perf_counter()
    agent = instantiate_agent(cfg, recorder, tmp)
    setup_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    agent.train_agent()
    train_s = time.perf_counter() - t1
    best = tmp / agent.eval_model_name
    chosen = best if best.is_file() else tmp / agent.last_model_name
    shutil.copyfile(chosen, tmp / "checkpoint.pth")
    for p in tmp.glob("*.pth"):
        if p.name != "checkpoint.pth":
            p.unlink()
    save_scaler(agent, tmp / "scaler.npz")
    (tmp / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    samples = len(agent.trainset)
    curve = recorder.curve()
    best_epochs = [r["best_model_epochs"] for r in curve if "best_model_epochs" in r]
    doc = {
        "started": now(),
        "demos_manifest_sha256": sha256(a.demos / "manifest.json"),
        "overrides": overrides,
        "script_overrides": script,
        "budget_overrides": extra,
        "our_overrides": ours,
        "config": OmegaConf.to_container(cfg, resolve=True),
        "epochs": epochs,
        "epochs_from": why,
        "budget": cell,
        "train_batch_size": batch,
        "eval_every_n_epochs": eval_every,
        "train_samples": samples,
        "val_samples": len(agent.valset),
        "batches_per_epoch": -(-samples // batch),
        "setup_seconds": round(setup_s, 2),
        "train_seconds": round(train_s, 2),
        "seconds_per_epoch": round(train_s / max(epochs, 1), 3),
        "torch_threads": torch.get_num_threads(),
        "checkpoint": {
            "reference_name": chosen.name,
            "which": "best on the evaluation split (run.py)" if chosen == best else "last epoch (no evaluation ran)",
            "best_epoch": int(best_epochs[-1]) if best_epochs and chosen == best else None,
            "sha256": sha256(tmp / "checkpoint.pth"),
            "bytes": (tmp / "checkpoint.pth").stat().st_size,
        },
        "scaler_sha256": sha256(tmp / "scaler.npz"),
        "loss_curve": curve,
    }
    (tmp / "train.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(f"[zoo] trained {a.task}/{a.method} s{a.seed}: {epochs} epochs in {train_s:.1f} s "
          f"({train_s / max(epochs, 1):.2f} s/epoch, {samples} samples)", flush=True)


def rebuild_agent(a, work: Path, shadow: Path, tmp: Path):
    """The trained agent object again: the constructor from the saved config (it reloads
    the demonstrations and refits the scaler, checked equal to the saved one), then the
    agent's own load_pretrained_model on the checkpoint."""
    import numpy as np
    from omegaconf import OmegaConf

    from d3il_client.agents.loading import load_scaler

    recorder = reference_env(shadow, a.threads)
    cfg = OmegaConf.load(work / "train" / "config.yaml")
    set_seed_everywhere(a.seed)
    agent = instantiate_agent(cfg, recorder, tmp)
    ctx = trusted_torch_load() if a.method in ("bet_mlp", "bet") else contextlib.nullcontext()
    with ctx:
        agent.load_pretrained_model(str(work / "train"), sv_name="checkpoint.pth")
    saved = load_scaler(work / "train" / "scaler.npz")
    for name in ("x_mean", "x_std", "y_mean", "y_std", "x_max", "x_min", "y_max", "y_min", "y_bounds"):
        if hasattr(agent.scaler, name) and hasattr(saved, name):
            if not np.array_equal(np.asarray(getattr(agent.scaler, name)), np.asarray(getattr(saved, name))):
                raise SystemExit(f"the rebuilt agent's scaler {name} differs from the trained one's: "
                                 "the demonstrations changed since training; retrain (delete the work dir)")
    return agent


def stage_export(a, work: Path, shadow: Path, tmp: Path):
    from d3il_client.agents.export import export_agent

    agent = rebuild_agent(a, work, shadow, tmp)
    t0 = time.perf_counter()
    report = export_agent(agent, task=a.task, out=tmp / "policy.onnx", require_d3il=True, d3il=a.d3il)
    seconds = time.perf_counter() - t0
    summary = report.summary() if hasattr(report, "summary") else str(report)
    (tmp / "export.txt").write_text(summary + "\n")
    for p in tmp.glob("*.pth"):
        p.unlink()
    doc = {"seconds": round(seconds, 2), "summary": summary}
    (tmp / "export.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(f"[zoo] exported {a.task}/{a.method} s{a.seed} in {seconds:.1f} s", flush=True)


def stage_eval(a, work: Path, shadow: Path, tmp: Path):
    cmd = [a.d3il, "eval", "--task", a.task, "--policy", str(work / "export" / "policy.onnx"),
           "--protocol", a.protocol, "--json", str(tmp / "result.json")]
    t0 = time.perf_counter()
    with open(tmp / "eval.log", "w") as log:
        log.write(" ".join(shlex.quote(c) for c in cmd) + "\n")
        log.flush()
        rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    seconds = time.perf_counter() - t0
    if rc != 0:
        raise SystemExit(f"d3il eval failed (exit {rc}); see {tmp / 'eval.log'}:\n"
                         + (tmp / "eval.log").read_text()[-2000:])
    (tmp / "eval.json").write_text(json.dumps({"command": cmd, "seconds": round(seconds, 2)}, indent=1) + "\n")
    print(f"[zoo] evaluated {a.task}/{a.method} s{a.seed} in {seconds:.1f} s", flush=True)


def paper_demos(reference: Path, task: str, demos: Path) -> list[str]:
    """How many training demonstrations the reference's own file list for the task
    names (the paper's data), against ours."""
    import pickle

    out = []
    for ours in sorted(demos.glob("*train_files.pkl")):
        theirs = reference / "environments" / "dataset" / "data" / TASKS[task][2] / ours.name
        if theirs.is_file():
            with open(theirs, "rb") as f, open(ours, "rb") as g:
                out.append(f"{len(pickle.load(g))} training demonstrations in {ours.name} "
                           f"(the reference's list of the paper's data names {len(pickle.load(f))})")
    return out


def headline(result: dict) -> dict:
    m = result.get("metrics", {})
    out = {}
    for k in ("success_rate", "behaviour_entropy", "conditional_entropy"):
        if k in m:
            out[k] = m[k]
    if "inference_ms" in m:
        out["inference_ms"] = m["inference_ms"]
    return out


#: provenance.json's schema version; server/src/zoo.rs reads zoo_version, task, method
#: (the paper's name), seed, demos.version and the sha256 map (onnx, result, manifest,
#: checkpoint) and keeps everything else as shipped
ZOO_VERSION = "v1"


def method_slug(method: str) -> str:
    """The cell directory's method part: the paper's name in lower case (BC-MLP ->
    bc-mlp), as server/src/zoo.rs names cells (aligning/bc-mlp-s0)."""
    return METHODS[method][0].lower()


def finish(a, work: Path, out: Path):
    """The cell directory: files copied from the stages, provenance.json last, renamed
    into place."""
    import onnx
    import onnxruntime
    import torch

    train = json.loads((work / "train" / "train.json").read_text())
    export = json.loads((work / "export" / "export.json").read_text())
    ev = json.loads((work / "eval" / "eval.json").read_text())
    tmp = out.parent / f".{out.name}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    for stage, src, name in (("train", "checkpoint.pth", "checkpoint.pt"), ("train", "scaler.npz", "scaler.npz"),
                             ("train", "config.yaml", "config.yaml"), ("export", "policy.onnx", "policy.onnx"),
                             ("export", "policy.json", "policy.json"), ("eval", "result.json", "result.json")):
        shutil.copyfile(work / stage / src, tmp / name)
    result = json.loads((tmp / "result.json").read_text())
    paper = load_budgets(a.budgets, a.task, a.method)["paper"]
    try:
        ours_commit = git(PROJECT, "rev-parse", "HEAD")
        ours_dirty = bool(git(PROJECT, "status", "--porcelain", "--untracked-files=no"))
    except Exception:  # noqa: BLE001 - provenance says what it could not read
        ours_commit, ours_dirty = None, None
    demos = demos_info(a.demos)
    if train.get("demos_manifest_sha256") not in (None, demos["manifest_sha256"]):
        raise SystemExit(f"{a.demos}/manifest.json changed since this cell was trained "
                         f"({train['demos_manifest_sha256']} then, {demos['manifest_sha256']} now): "
                         f"delete {work} and train again")
    manifest = demos.get("manifest", {})
    paper_name, agent_name = METHODS[a.method]
    prov = {
        "zoo_version": ZOO_VERSION,
        "task": a.task,
        "method": paper_name,
        "reference_agent": agent_name,
        "seed": a.seed,
        "complete": True,
        "written": now(),
        "method_detail": {"key": a.method, "reference_config": f"configs/agents/{agent_name}.yaml",
                          "reference_class": train["config"]["agents"]["_target_"],
                          "benchmark_script": f"scripts/{TASKS[a.task][1]}/{a.method}_benchmark.sh"},
        "demos": {
            "version": str(manifest.get("demos_version", manifest.get("version", "unknown"))),
            "manifest_sha256": demos["manifest_sha256"],
            **{k: v for k, v in demos.items() if k not in ("manifest_sha256",)},
        },
        "reference": {
            "repo": "ALRhub/d3il",
            "commit": git(a.reference, "rev-parse", "HEAD"),
            "checkout": str(a.reference.resolve()),
            # tracked files changed in the checkout (a clone without the large media blobs
            # shows them deleted: textures, camera meshes, the README gif; training reads none)
            "changed_files": git(a.reference, "status", "--porcelain", "--untracked-files=no").splitlines(),
        },
        "overrides": train["overrides"],
        "config": train["config"],
        "budget": {
            "epochs": train["epochs"],
            "epochs_from": train["epochs_from"],
            "budgets_json": train["budget"],
            "train_batch_size": train["train_batch_size"],
            "eval_every_n_epochs": train["eval_every_n_epochs"],
            "samples_seen": train["train_samples"] * train["epochs"],
            "paper": paper,
            "changes": [
                f"epoch {train['epochs']} instead of the paper's {paper['epoch']}",
                f"eval_every_n_epochs {train['eval_every_n_epochs']} instead of {paper['eval_every_n_epochs']} "
                f"({train['epochs'] // train['eval_every_n_epochs']} evaluations on the evaluation split in training, "
                f"the paper {paper['epoch'] // paper['eval_every_n_epochs']}; the checkpoint best there is the policy)",
                *([f"train_batch_size {train['train_batch_size']} instead of {paper['train_batch_size']}"]
                  if train["train_batch_size"] != paper["train_batch_size"] else []),
                f"{train['train_samples']} training windows x {train['epochs']} epochs = "
                f"{train['train_samples'] * train['epochs']} samples seen",
                *paper_demos(a.reference, a.task, a.demos),
                *[f"{o} (budgets.json: {train['budget'].get('why', 'no reason given')})"
                  for o in train["budget"].get("overrides", [])],
                *[f"the benchmark script's {old} applied as {new} "
                  f"(budgets.json: {train['budget'].get('why', 'no reason given')})"
                  for old, new in train["budget"].get("script_renames", {}).items()],
                *[f"the benchmark script's {key} applied as {key}={value} "
                  f"(budgets.json: {train['budget'].get('why', 'no reason given')})"
                  for key, value in train["budget"].get("script_values", {}).items()],
                "device cpu and num_workers 1 (the loaders need >= 1)",
                "demonstrations recorded from our tasks by `d3il demos` (see demos), "
                "not the paper's recorded data",
            ],
        },
        "training": {
            "wall_s": train["train_seconds"],
            "setup_s": train["setup_seconds"],
            "seconds_per_epoch": train["seconds_per_epoch"],
            "train_samples": train["train_samples"],
            "val_samples": train["val_samples"],
            "batches_per_epoch": train["batches_per_epoch"],
            "torch_threads": train["torch_threads"],
            "checkpoint": train["checkpoint"],
            "loss_curve": [{"epoch": r["epoch"], "loss": r.get("train_loss")} for r in train["loss_curve"]],
            "logged_per_epoch": train["loss_curve"],
        },
        "sha256": {
            "onnx": sha256(tmp / "policy.onnx"),
            "result": sha256(tmp / "result.json"),
            "manifest": sha256(tmp / "policy.json"),
            "checkpoint": sha256(tmp / "checkpoint.pt"),
            "scaler": sha256(tmp / "scaler.npz"),
            "config": sha256(tmp / "config.yaml"),
        },
        "bytes": {p.name: p.stat().st_size for p in sorted(tmp.iterdir())},
        "policy_manifest": json.loads((tmp / "policy.json").read_text()),
        "export": export,
        "evaluation": {
            "command": ev["command"],
            "wall_s": ev["seconds"],
            "protocol": a.protocol,
            "metrics": headline(result),
            "protocol_manifest": result.get("manifest"),
        },
        "software": {
            "torch": torch.__version__,
            "onnx": onnx.__version__,
            "onnxruntime": onnxruntime.__version__,
            "python": platform.python_version(),
            "ours": {"commit": ours_commit, "dirty": ours_dirty},
            "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        },
    }
    (tmp / "provenance.json").write_text(json.dumps(prov, indent=1) + "\n")
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp.rename(out)
    print(f"[zoo] {out}: success {headline(result).get('success_rate')}", flush=True)


def complete(out: Path) -> bool:
    p = out / "provenance.json"
    if not p.is_file():
        return False
    try:
        if json.loads(p.read_text()).get("complete") is not True:
            return False
    except ValueError:
        return False
    packed = (out / "result.json.gz").is_file()  # scripts/zoo/pack.py
    return all((out / n).is_file() for n in ("policy.onnx", "policy.json")) and (
        packed or (out / "result.json").is_file())


def run_stage(name, fn, a, work: Path, shadow: Path):
    done = work / name
    if done.is_dir():
        print(f"[zoo] {name}: done before ({done})", flush=True)
        return
    tmp = work / f"{name}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    fn(a, work, shadow, tmp)
    tmp.rename(done)


def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reference", required=True, type=Path, help="work-tree checkout of ALRhub/d3il")
    ap.add_argument("--demos", required=True, type=Path,
                    help="demonstration directory of the task (`d3il demos --out`), with manifest.json")
    ap.add_argument("--task", required=True, choices=sorted(TASKS))
    ap.add_argument("--method", required=True, choices=sorted(METHODS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, type=Path, help="cell directory, e.g. assets/zoo/aligning/bc-s0")
    ap.add_argument("--work", type=Path, default=None,
                    help="work directory of the stages (default ~/.cache/d3il/zoo-work/<task>/<method>-s<seed>)")
    ap.add_argument("--budgets", type=Path, default=HERE / "budgets.json")
    ap.add_argument("--epochs", type=int, default=None, help="override the budget's epochs")
    ap.add_argument("--batch-size", type=int, default=None, help="override the budget's train_batch_size")
    ap.add_argument("--eval-every", type=int, default=None,
                    help="eval_every_n_epochs (default: the paper's 50 of 500 scaled to the epochs, at least 1)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--d3il", default=os.environ.get("D3IL_BIN") or str(PROJECT / "target" / "release" / "d3il"))
    ap.add_argument("--protocol", default="paper")
    ap.add_argument("--until", choices=STAGES + ("final",), default="final", help="stop after this stage")
    ap.add_argument("--keep-work", action="store_true", help="keep the work directory after the cell is complete")
    a = ap.parse_args(argv)
    if a.work is None:
        a.work = Path.home() / ".cache" / "d3il" / "zoo-work" / a.task / f"{a.method}-s{a.seed}"
    return a


def main(argv=None):
    a = parse(argv)
    if complete(a.out):
        print(f"[zoo] {a.out}: complete, skipped", flush=True)
        return 0
    demos_info(a.demos)  # refuses a directory without manifest.json before any training
    os.environ.setdefault("OMP_NUM_THREADS", str(a.threads))
    os.environ["D3IL_BIN"] = a.d3il
    a.work.mkdir(parents=True, exist_ok=True)
    shadow = mirror(a.reference, a.demos, TASKS[a.task][2], a.work / "reference")
    fns = {"train": stage_train, "export": stage_export, "eval": stage_eval}
    for name in STAGES:
        run_stage(name, fns[name], a, a.work, shadow)
        if a.until == name:
            return 0
    finish(a, a.work, a.out)
    if not a.keep_work:
        shutil.rmtree(a.work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
