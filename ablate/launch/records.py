"""What a launch records about itself: the commit that ran, each variant's tracked params, the grid and the
machine (the launch run's tags and files). Pure reads of git and the host; no Ray, no MLflow.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

from ablate import sources
from ablate.config import KNOBS, SCHEMA, flatten
from ablate.env_spec import versions
from ablate.experiment import Experiment
from ablate.launch.grid import GridTrial, tuning_trials


def git_commit() -> str:
    """HEAD, ``-dirty`` when tracked files differ from it; ``reports/`` does not count: every ablation rewrites
    the committed report, and the code that ran is what the commit names."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ":(top)", ":(top,exclude)reports"],
            capture_output=True,
            text=True,
        )
        return commit + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def tracked_params(variant: str, config) -> dict:
    """A trial's MLflow params: every knob that shaped it, and none that did not (the test-only fault knobs
    unless set, the built-in CNN's window knobs on other networks, an unset ``solve_threshold``), so MLflow's params
    table and its "diff only" view show real differences."""
    params = {"variant": variant, **flatten(config)}
    for key in [name for name, knob in KNOBS.items() if knob.test_only]:
        if not params[key]:
            del params[key]
    for column, knob in SCHEMA.items():
        if knob.only_for and (config.model.architecture != knob.only_for or config.model.factory):
            del params[column]  # a knob of one built-in network, which this trial does not run
    if params["solve_threshold"] is None:
        del params["solve_threshold"]
    return params | package_versions(config)


def package_versions(config) -> dict:
    """The installed package a ``package.module`` factory or an ``env_module`` comes from, as ``name==version``
    (``model.package_version``, ``env_module.package_version``): recorded, not keyed (a new version reruns
    nothing). Local code has none: its hash is in the key."""
    versions = {}
    target = config.model.factory.rsplit(":", 1)[0]
    if target and not target.endswith(".py") and not config.model.factory_source:
        versions["model.package_version"] = sources.package_version(target) or "not installed"
    if config.env_module and not config.env_module_source:
        versions["env_module.package_version"] = sources.package_version(config.env_module) or "not installed"
    return versions


def grid_document(experiment: Experiment, trials: list[GridTrial]) -> dict:
    """What the report needs to know of the launch without reading the experiment file again, in ``grid.json``'s
    form (lists, not tuples) whether it is stored or not."""
    document = {
        "experiment": experiment.name,
        "description": experiment.description,
        "baseline": experiment.baseline,
        "seeds": list(experiment.seeds),
        "variants": [{"name": v.name, "overrides": dict(v.overrides)} for v in experiment.variants],
        "base": flatten(experiment.base),
        "trials": [{"key": t.key, "variant": t.variant, "seed": t.seed} for t in trials],
    }
    if experiment.tune:
        tuning = tuning_trials(experiment)
        document["tune_trials"] = [
            {"key": t.key, "variant": t.variant, "seed": t.seed, "stage": t.stage} for t in tuning
        ]
    return json.loads(json.dumps(document))


PACKAGES = ("torch", "gymnasium", "ale-py", "ray", "mlflow", "numpy", "pandas", "scipy", "matplotlib", "imageio")


class TorchKernels:
    """The CPU kernels torch picks here (``torch.backends.cpu.get_cpu_capability``), asked of a child Python
    begun when the launch begins: importing torch takes ~1 s of CPU, which in the launch's own process held the
    interpreter while Ray started (``ray.init`` 2.4-4.8 s against 1.9-2.3 s without it, ``docs/performance.md``);
    a child runs it on a core the store's opening leaves idle. ``close`` ends it where nothing ran."""

    CODE = "import torch; print(torch.backends.cpu.get_cpu_capability())"

    def __init__(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-c", self.CODE], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
        )

    def result(self) -> str:
        try:
            out, _ = self.process.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            self.close()
            return "unknown"
        return out.strip() or "unknown"

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()


def environment_document(kernels: TorchKernels) -> dict:
    """Where the launch ran: Python, package versions, machine, CPU model and the CPU kernels torch uses (asked of
    ``kernels``)."""
    packages = versions(PACKAGES)
    capability = kernels.result()
    # Float kernels differ by CPU: the model and the kernels torch picks say where the results were produced.
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.is_file() else []
    models = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    cpu_model = models[0] if models else platform.processor() or "unknown"
    return {
        "python": platform.python_version(),
        "packages": packages,
        "machine": f"{platform.system()} {platform.machine()}, {os.cpu_count()} CPUs ({platform.platform()})",
        "cpu_model": cpu_model,
        "torch_cpu_capability": capability,
    }
