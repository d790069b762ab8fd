"""The shape of the package: every equinox Module of jaxhyst is abstract or final (no
concrete method overridden, no concrete class subclassed), files stay small, the floors
hold (the model never imports identification, files or the command line), and the
command line starts without JAX."""

from __future__ import annotations

import ast
import importlib
import inspect
import pathlib
import pkgutil
import subprocess
import sys

import equinox as eqx
import pytest

import jaxhyst

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _modules():
    for info in pkgutil.walk_packages(jaxhyst.__path__, "jaxhyst."):
        if info.name.endswith("__main__"):
            continue
        yield importlib.import_module(info.name)


def _module_classes():
    seen = set()
    for module in _modules():
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if (issubclass(cls, eqx.Module) and cls.__module__.startswith("jaxhyst")
                    and cls not in seen):
                seen.add(cls)
                yield cls


def _is_abstract(cls) -> bool:
    return bool(inspect.isabstract(cls) or getattr(cls, "__abstractvars__", ())
                or cls.__name__.startswith("Abstract"))


def test_every_module_is_abstract_or_final():
    classes = list(_module_classes())
    assert len(classes) > 20
    for cls in classes:
        for base in cls.__mro__[1:]:
            if not (issubclass(base, eqx.Module) and base.__module__.startswith("jaxhyst")):
                continue
            assert _is_abstract(base), f"{cls.__name__} subclasses the concrete {base.__name__}"
            for name, value in vars(cls).items():
                if not callable(value) or name.startswith("__"):
                    continue
                inherited = vars(base).get(name)
                concrete = inherited is not None and callable(inherited) and not getattr(
                    inherited, "__isabstractmethod__", False)
                assert not concrete, f"{cls.__name__}.{name} overrides {base.__name__}.{name}"


def test_no_file_of_the_package_is_over_400_lines():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text(encoding="utf-8").splitlines())
             for p in (ROOT / "jaxhyst").rglob("*.py")}
    assert max(sizes.values()) <= 420, {k: v for k, v in sizes.items() if v > 400}


def _imports(path: pathlib.Path) -> set[str]:
    """Modules of jaxhyst that ``path`` imports (absolute names)."""
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                out.add(".".join([*base, node.module or ""]).rstrip("."))
            elif node.module and node.module.startswith("jaxhyst"):
                out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("jaxhyst"))
    return out


@pytest.mark.parametrize("floor, above", [
    ("jaxhyst/model", ("jaxhyst.identify", "jaxhyst.analysis", "jaxhyst.cli",
                       "jaxhyst.io", "jaxhyst.plots", "jaxhyst.fit")),
    ("jaxhyst/identify", ("jaxhyst.analysis", "jaxhyst.cli", "jaxhyst.io", "jaxhyst.plots",
                          "jaxhyst.fit")),
    ("jaxhyst/analysis", ("jaxhyst.cli", "jaxhyst.plots", "jaxhyst.fit")),
])
def test_no_import_runs_back_up(floor, above):
    for path in (ROOT / floor).rglob("*.py"):
        bad = [m for m in _imports(path) if m.startswith(above)]
        assert not bad, (str(path), bad)


def test_run_hybrid_is_a_thin_function():
    from jaxhyst.identify import run

    lines = inspect.getsource(run.run_hybrid).splitlines()
    assert len(lines) <= 60, len(lines)


def test_the_command_line_parses_without_importing_jax():
    code = ("import sys\nfrom jaxhyst.cli import build_parser\nbuild_parser()\n"
            "print('jax' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"
