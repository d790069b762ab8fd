"""mkdocs hooks (``hooks:`` in mkdocs.yml): the generated figures and numbers, and the
KaTeX assets the site serves itself.

- Generated content: ``docs/generate.py`` runs the examples, the commands the pages show
  and the quick studies into ``build/docs/generated/`` when its sources changed (a
  fingerprint), or the build takes an existing directory from ``JAXHYST_DOCS_GENERATED``
  (the tests generate once and build from it). Pages include its Markdown fragments with
  ``--8<-- "generated/<step>/<file>"`` and show its figures as ``generated/<step>/<file>.png``.
- KaTeX: the npm registry's tarball of a pinned version, checked against its published
  SHA-512, unpacked once into the user's cache (``~/.cache/jaxhyst/katex-<version>``);
  ``JAXHYST_KATEX_DIST`` names an existing ``katex/dist`` folder instead (offline
  machines). The site then renders its mathematics with no network.
"""

from __future__ import annotations

import base64
import hashlib
import io
import os
import shutil
import subprocess
import sys
import tarfile
import urllib.request
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
KATEX_VERSION = "0.16.47"
KATEX_TARBALL = f"https://registry.npmjs.org/katex/-/katex-{KATEX_VERSION}.tgz"
KATEX_SHA512 = ("Eeo8Ys1doU1z+x8AZsPpQu+p/QcZBI5PeOo7QGQdy2x2m0MU/hYagBbGOmXwr5KVbEfVuWv9Lp"
                "nQWeehogurjg==")
#: What the site needs from katex/dist: the renderer, its style sheet and fonts, licence.
KATEX_KEEP = ("katex.min.js", "katex.min.css", "fonts/")

_state: dict = {}


def _cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jaxhyst" / f"katex-{KATEX_VERSION}"


def _katex_root() -> Path:
    """A folder holding ``assets/katex/`` (KaTeX's dist files and LICENSE)."""
    given = os.environ.get("JAXHYST_KATEX_DIST")
    if given:
        dist = Path(given)
        if not (dist / "katex.min.js").is_file():
            raise PluginError(f"JAXHYST_KATEX_DIST={given!r} holds no katex.min.js; point it at "
                              f"the dist folder of KaTeX {KATEX_VERSION}.")
        return _copy_dist(dist)
    root = _cache_root()
    if (root / "assets" / "katex" / "katex.min.js").is_file():
        return root
    try:
        with urllib.request.urlopen(KATEX_TARBALL, timeout=60) as r:
            blob = r.read()
    except OSError as err:
        raise PluginError(
            f"KaTeX {KATEX_VERSION} is not in {root} and {KATEX_TARBALL} cannot be fetched "
            f"({err}); fetch it once with network, or set JAXHYST_KATEX_DIST to the dist "
            f"folder of `npm install katex@{KATEX_VERSION}`.") from None
    digest = base64.b64encode(hashlib.sha512(blob).digest()).decode()
    if digest != KATEX_SHA512:
        raise PluginError(f"{KATEX_TARBALL} does not have the published SHA-512 ({digest}); "
                          f"not using it.")
    target = root / "assets" / "katex"
    tmp = root.with_name(root.name + f".tmp{os.getpid()}")
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r:gz") as tar:
        for member in tar.getmembers():
            name = member.name.removeprefix("package/")
            keep = name == "LICENSE" or any(
                name.removeprefix("dist/").startswith(k) for k in KATEX_KEEP
                if name.startswith("dist/"))
            if not member.isfile() or not keep or ".." in Path(name).parts:
                continue
            dest = tmp / "assets" / "katex" / name.removeprefix("dist/")
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(tar.extractfile(member).read())
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(tmp / "assets" / "katex", target)
    except OSError:  # another build got there first
        pass
    shutil.rmtree(tmp, ignore_errors=True)
    return root


def _copy_dist(dist: Path) -> Path:
    """A cache folder whose ``assets/katex`` is a copy of the files the site needs from
    ``dist``."""
    key = hashlib.sha1(str(dist.resolve()).encode()).hexdigest()[:8]
    root = _cache_root().with_name(f"katex-dist-{key}")
    target = root / "assets" / "katex"
    target.mkdir(parents=True, exist_ok=True)
    shutil.copy2(dist / "katex.min.js", target)
    shutil.copy2(dist / "katex.min.css", target)
    for licence in (dist / "LICENSE", dist.parent / "LICENSE"):
        if licence.is_file():
            shutil.copy2(licence, target)
            break
    shutil.copytree(dist / "fonts", target / "fonts", dirs_exist_ok=True)
    return root


def _generated_root() -> Path:
    """The folder holding ``generated/``, brought up to date first where it is ours."""
    given = os.environ.get("JAXHYST_DOCS_GENERATED")
    if given:
        root = Path(given)
        if not (root / "generated").is_dir():
            raise PluginError(f"JAXHYST_DOCS_GENERATED={given!r} has no generated/ folder; "
                              f"run `python docs/generate.py {given}` first.")
        return root
    root = ROOT / "build" / "docs"
    sys.path.insert(0, str(ROOT / "docs"))
    try:
        from generate import fingerprint
    finally:
        sys.path.pop(0)
    stamp = root / "generated" / "fingerprint"
    if stamp.is_file() and stamp.read_text() == fingerprint():
        return root
    print("[docs] the package, the examples or docs/generate.py changed: running them to "
          "regenerate the figures and numbers (several minutes on 2 cores) …", flush=True)
    rc = subprocess.run([sys.executable, str(ROOT / "docs" / "generate.py"), str(root)],
                        cwd=ROOT).returncode
    if rc != 0:
        raise PluginError(f"docs/generate.py failed (exit {rc}); its logs are in "
                          f"{root / 'generated'}.")
    return root


def on_config(config):
    _state["generated"] = _generated_root()
    _state["katex"] = _katex_root()
    snippets = config.mdx_configs.setdefault("pymdownx.snippets", {})
    snippets["base_path"] = [*snippets.get("base_path", ["."]), str(_state["generated"])]
    return config


def on_files(files, config):
    """Add the generated figures and the KaTeX assets to the site's files."""
    for root, sub in ((_state["generated"], "generated"), (_state["katex"], "assets/katex")):
        for path in sorted((root / sub).rglob("*")):
            if path.is_file() and (sub != "generated" or path.suffix == ".png"):
                files.append(File(path.relative_to(root).as_posix(), str(root),
                                  config.site_dir, config.use_directory_urls))
    return files
