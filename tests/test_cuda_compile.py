"""Every module of the package that defines Warp kernels compiles for CUDA: PTX for sm_80 (Ampere;
later GPUs load it too), through the NVRTC compiler that Warp links in. That needs no GPU and no
driver, so the CPU-only CI proves that no kernel uses what only the CPU back end accepts.

The compile runs in one subprocess (this file run as a script) whose Warp kernel cache, temporary
files and PTX all lie under pytest's tmp dir: an ahead-of-time compile writes only into the folder
it is given, and the test checks that the kernel cache stayed empty, so a run leaves nothing in the
user's cache. It compiles every module from scratch (about 20 s for the package on one core).

Modules are found by importing the package and asking Warp which modules hold kernels; a text search
of the sources for kernel definitions must find the same set, so a new kernel module cannot be
missed, and a deliberately broken throwaway module must fail, so failures cannot be missed either.
"""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "warp_mpm_bubbles"
ARCH = 80
# The package has 19 modules with kernels; a discovery that finds fewer than this has stopped seeing
# them (the comparison with the text search below names exactly which).
MIN_MODULES = 12
# A kernel is defined by the decorator, by calling wp.kernel (a kernel factory), or by line_kernel
# (core/lines.py), which makes a cell function's kernel in the cell function's module: the module that
# holds that factory defines no kernel of its own.
KERNEL_DEFINITION = re.compile(r"^\s*@wp\.kernel\b|^[^#\n]*\bwp\.kernel\(|^\w+ = line_kernel\(", re.MULTILINE)
FACTORY_MODULES = {"core/lines.py"}


def modules_defining_kernels_by_text(root: Path = ROOT, package: str = PACKAGE) -> list[str]:
    """The package's modules whose source defines a kernel, found by reading the files."""
    names = []
    for path in sorted((root / package).rglob("*.py")):
        if path.relative_to(root / package).as_posix() in FACTORY_MODULES:
            continue
        if KERNEL_DEFINITION.search(path.read_text(encoding="utf-8")):
            parts = path.relative_to(root).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


# ------------------------------------------------------------------------------------ the compiler
# Runs in the subprocess: imports Warp with the cache and temporary folders the parent set.

def kernel_modules(python_modules) -> dict[str, dict]:
    """{Python module: {Warp module name: Warp module}} for every Python module whose code defines
    kernels: the Warp module registered under its name, and the modules of the kernels bound in its
    namespace (a kernel made with module="unique" has a module of its own)."""
    import warp as wp

    found: dict[str, dict] = {}
    for pm in python_modules:
        for value in vars(pm).values():
            # a table of kernels by dimension (core/transfer_kernels.py's P2G, G2P) counts as its kernels
            for kernel in value.values() if isinstance(value, dict) else [value]:
                if isinstance(kernel, wp.Kernel):
                    found.setdefault(kernel.func.__module__, {})[kernel.module.name] = kernel.module
        registered = wp.get_module(pm.__name__)
        if registered.kernels:
            found.setdefault(pm.__name__, {})[registered.name] = registered
    return found


def compile_module(module, out_dir: Path) -> dict:
    """Compile one Warp module to PTX, with what the native compiler printed (NVRTC's errors go to
    the process's stderr, not into the exception) and the kernels the PTX lacks."""
    import warp as wp

    log_path = out_dir / f"{module.name}.log"
    start = time.perf_counter()
    error, paths = None, []
    with open(log_path, "w+", encoding="utf-8", errors="replace") as log:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(log.fileno(), 2)
        try:
            paths = [str(p) for p in wp.compile_aot_module(module, device=None, arch=ARCH, use_ptx=True,
                                                           module_dir=out_dir / module.name)]
        except Exception as e:  # the harness reports every failure; the test asserts there is none
            error = f"{type(e).__name__}: {e}"
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        log.seek(0)
        native = log.read()
    ptx = "".join(Path(p).read_text(errors="replace") for p in paths if Path(p).is_file())
    missing = [k.key for k in module.kernels.values()
               if not re.search(rf"\.entry {re.escape(k.key)}_[0-9a-f]+_cuda_kernel_forward\b", ptx)]
    return {"seconds": time.perf_counter() - start, "error": error, "log": native[-4000:], "ptx": paths,
            "target": f".target sm_{ARCH}" in ptx, "kernels": len(module.kernels), "missing": missing}


def compiler_main(argv: list[str]) -> None:
    """python test_cuda_compile.py OUT_DIR (--walk PACKAGE | MODULE...): writes OUT_DIR/result.json."""
    import warp as wp

    out_dir, targets = Path(argv[0]), argv[1:]
    wp.config.quiet = True
    wp.init()
    result = {"archs": wp.get_cuda_supported_archs(), "cache": wp.config.kernel_cache_dir, "modules": {}}
    if ARCH in result["archs"]:
        if targets[0] == "--walk":
            package = importlib.import_module(targets[1])
            targets = [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")]
        found = kernel_modules([importlib.import_module(name) for name in targets])
        for python_name, modules in sorted(found.items()):
            result["modules"][python_name] = {name: compile_module(m, out_dir)
                                              for name, m in sorted(modules.items())}
    (out_dir / "result.json").write_text(json.dumps(result, indent=1))


# ------------------------------------------------------------------------------------- the tests

def run_compiler(out_dir: Path, *targets: str, pythonpath=()) -> dict:
    """The compiler subprocess with its kernel cache and temporary files under out_dir."""
    (out_dir / "tmp").mkdir(parents=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *map(str, pythonpath)]),
               WARP_CACHE_PATH=str(out_dir / "kernel_cache"), TMPDIR=str(out_dir / "tmp"))
    proc = subprocess.run([sys.executable, __file__, str(out_dir), *targets], env=env, capture_output=True,
                          text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-4000:]
    result = json.loads((out_dir / "result.json").read_text())
    if ARCH not in result["archs"]:
        pytest.skip(f"this Warp build cannot compile CUDA for sm_{ARCH} without a GPU (NVRTC targets: "
                    f"{result['archs'] or 'none, CUDA is not enabled in it'}); install a CUDA build of warp-lang")
    return result


def failures(compiled: dict) -> list[str]:
    """One line per Warp module that did not compile completely to sm_80 PTX."""
    bad = []
    for name, r in compiled.items():
        if r["error"] or not r["ptx"] or not all(Path(p).is_file() for p in r["ptx"]) or not r["target"] \
                or r["missing"]:
            bad.append(f"{name}: {r['error'] or 'no error raised'}; PTX {r['ptx']}; kernels without an entry "
                       f"{r['missing']}\n{r['log']}")
    return bad


@pytest.fixture(scope="module")
def package_build(tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("cuda_build")
    result = run_compiler(out_dir, "--walk", PACKAGE)
    result["out_dir"] = out_dir
    return result


def test_discovery_finds_every_module_whose_source_defines_kernels(package_build):
    by_text = set(modules_defining_kernels_by_text())
    found = set(package_build["modules"])
    assert len(by_text) >= MIN_MODULES, f"the text search found only {sorted(by_text)}"
    assert found == by_text, (f"kernels found only by importing: {sorted(found - by_text)}; "
                              f"only in the source text: {sorted(by_text - found)}")
    for name in ("core.transfer_kernels", "core.pressure", "effects.foam", "physics.tension"):
        assert f"{PACKAGE}.{name}" in found
    # kernels in modules of their own (module="unique": the transfers, one per dimension, so that a
    # scene compiles only its own) are compiled with the module that defines them
    transfers = package_build["modules"][f"{PACKAGE}.core.transfer_kernels"]
    for kernel in ("p2g_2d", "p2g_3d", "g2p_advect_2d", "g2p_advect_3d"):
        assert any(name.startswith(kernel + "_") for name in transfers), sorted(transfers)


@pytest.mark.parametrize("module", modules_defining_kernels_by_text())
def test_module_compiles_to_sm80_ptx(package_build, module):
    compiled = package_build["modules"].get(module)
    assert compiled, f"{module} defines kernels, but importing it registered none with Warp"
    assert not failures(compiled), "\n".join(failures(compiled))


def test_the_compile_writes_nothing_into_the_kernel_cache(package_build):
    cache = Path(package_build["cache"])
    assert cache.is_relative_to(package_build["out_dir"]), cache
    assert not any(cache.iterdir()), sorted(p.name for p in cache.iterdir())


GOOD = """import warp as wp

@wp.kernel
def double(a: wp.array(dtype=float)):
    i = wp.tid()
    a[i] = 2.0 * a[i]
"""
# Valid for Warp's code generator, refused by NVRTC: the error comes from the CUDA compiler itself.
NOT_CUDA = """import warp as wp

@wp.func_native("a[i] = not_a_cuda_function(a[i]);")
def host_only(a: wp.array(dtype=float), i: int): ...

@wp.kernel
def calls_host_only(a: wp.array(dtype=float)):
    host_only(a, wp.tid())
"""
# A generic kernel that nothing instantiates: the compile skips it with a warning, so only the check
# that each kernel has an entry in the PTX catches it.
GENERIC = GOOD + """from typing import Any

@wp.kernel
def fill(a: wp.array(dtype=Any), value: Any):
    a[wp.tid()] = value
"""
# Refused already by Warp's code generator.
UNDEFINED = """import warp as wp

@wp.kernel
def calls_undefined(a: wp.array(dtype=float)):
    a[wp.tid()] = undefined_function(1.0)
"""


def test_a_kernel_that_cannot_compile_for_cuda_fails_the_harness(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    sources = {"good_mod": GOOD, "not_cuda_mod": NOT_CUDA, "undefined_mod": UNDEFINED, "generic_mod": GENERIC}
    for name, text in sources.items():
        (src / f"{name}.py").write_text(text)
    modules = run_compiler(tmp_path / "out", *sources, pythonpath=[src])["modules"]
    assert set(modules) == set(sources)
    assert not failures(modules["good_mod"])
    (not_cuda,) = modules["not_cuda_mod"].values()
    assert failures(modules["not_cuda_mod"]) and not not_cuda["ptx"]
    assert "not_a_cuda_function" in not_cuda["log"] and "undefined" in not_cuda["log"], not_cuda["log"]
    (undefined,) = modules["undefined_mod"].values()
    assert failures(modules["undefined_mod"]) and "undefined_function" in undefined["error"]
    (generic,) = modules["generic_mod"].values()
    assert generic["ptx"] and generic["missing"] == ["fill"] and failures(modules["generic_mod"])


def test_the_text_search_sees_decorated_and_factory_kernels(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "plain.py").write_text("import warp as wp\n\ndef f(): pass\n# @wp.kernel in a comment\n")
    (package / "decorated.py").write_text("import warp as wp\n\n@wp.kernel(enable_backward=False)\n"
                                          "def k(): pass\n")
    (package / "sub" / "factory.py").write_text("import warp as wp\n\ndef make(f):\n    return wp.kernel(f)\n")
    assert modules_defining_kernels_by_text(tmp_path, "pkg") == ["pkg.decorated", "pkg.sub.factory"]


if __name__ == "__main__":
    compiler_main(sys.argv[1:])
