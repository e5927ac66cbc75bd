"""mujoco.mjx imported without its warp backend: about 2.6 s less per process that imports MJX where warp-lang is
installed (the playground extra brings it), measured in experiments/compile_time/README.md.

mujoco.mjx imports NVIDIA Warp and MuJoCo Warp whenever `warp` can be imported, for its `impl="warp"` backend (NVIDIA
GPUs only). This project steps MJX's JAX implementation everywhere (Playground's environments too), so while
mujoco.mjx itself is first imported, `import warp` fails as it does where warp-lang is not installed: MJX then
runs as on such a machine (mujoco.mjx.warp.WARP_INSTALLED is False) and prints the same "Failed to import warp"
notice (the project's builders import MJX with stdout captured). `warp` stays importable afterwards. MJX keeps its
warp backend in a process that imported warp (or mujoco.mjx) before `envs`, or that sets MJX_GPU_DEFAULT_WARP=true
(MJX's own switch to it). The hiding is process-wide for the moment of that one import: another thread's first
`import warp` at that moment fails too.
"""

import importlib.abc
import importlib.machinery
import os
import sys

MJX = "mujoco.mjx"


class _HiddenWarp(importlib.abc.MetaPathFinder):
    """First on sys.meta_path from install() until mujoco.mjx has been imported once: that import runs with `warp`
    unimportable; the finder then removes itself."""

    def __init__(self):
        self.hiding = False

    def find_spec(self, name, path=None, target=None):
        if self.hiding and (name == "warp" or name.startswith("warp.")):
            raise ModuleNotFoundError(f"{name}: not imported with mujoco.mjx (envs/mjx_import.py: MJX's warp backend "
                                      "is for NVIDIA GPUs; this project uses its JAX implementation)", name=name)
        if name != MJX or self.hiding:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None:
            return None
        spec.loader = _Hiding(spec.loader, self)
        return spec


class _Hiding(importlib.abc.Loader):
    """The loader of mujoco.mjx, run with the finder hiding `warp`; the finder leaves sys.meta_path after it."""

    def __init__(self, loader, finder):
        self.loader, self.finder = loader, finder

    def __getattr__(self, name):  # get_source, get_code, is_package, ...: the file loader's own
        if name == "loader":  # not set yet (a copy being made): no recursion
            raise AttributeError(name)
        return getattr(self.loader, name)

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.finder.hiding = True
        try:
            self.loader.exec_module(module)
        finally:
            self.finder.hiding = False
            uninstall()


def install() -> None:
    """Hide `warp` from mujoco.mjx's first import in this process, unless warp or mujoco.mjx is already imported or
    MJX_GPU_DEFAULT_WARP asks MJX for its warp backend."""
    wanted = os.environ.get("MJX_GPU_DEFAULT_WARP", "").lower() == "true"
    if wanted or "warp" in sys.modules or MJX in sys.modules or any(isinstance(f, _HiddenWarp) for f in sys.meta_path):
        return
    sys.meta_path.insert(0, _HiddenWarp())


def uninstall() -> None:
    """Take the finder off sys.meta_path (once mujoco.mjx's first import has run, failed or not)."""
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _HiddenWarp)]
