"""The benchmarks' baseline: modules as they were at a git revision, loaded beside the working tree's.

Takes in: a git revision and {short name: repository path of a module}, or a revision and a scratch folder.
Gives out: the modules at that revision as package `bench_baseline` (written to a scratch folder), with
their imports of one another pointed at each other, and every other import served by the working tree;
or the whole repository at that revision, extracted (baseline_tree), to run from PYTHONPATH.
"""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "bench_baseline"


def baseline_modules(rev: str, modules: dict[str, str], workdir: Path) -> dict[str, ModuleType]:
    """The modules at git revision `rev` (raises OSError or CalledProcessError where git cannot show them)."""
    package = workdir / PACKAGE
    package.mkdir()
    (package / "__init__.py").write_text("")
    dotted = "|".join(re.escape(path[:-3].replace("/", ".")) for path in modules.values())
    names = {path[:-3].replace("/", "."): name for name, path in modules.items()}
    for name, path in modules.items():
        source = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, capture_output=True, text=True,
                                check=True).stdout
        source = re.sub(rf"\bfrom ({dotted}) import", lambda m: f"from {PACKAGE}.{names[m[1]]} import", source)
        (package / f"{name}.py").write_text(source)
    sys.path.insert(0, str(workdir))
    return {name: importlib.import_module(f"{PACKAGE}.{name}") for name in modules}


def baseline_tree(rev: str, tmp: Path) -> Path:
    """The repository at git revision `rev`, extracted (git archive) into tmp/baseline, with its compiled
    kernels built in place where it has any (a setup.py), as `pip install` builds them: a baseline runs
    what it shipped, not its slower Python twins. Without a compiler the build fails quietly (the kernels
    are optional there too) and the twins run."""
    tree = tmp / "baseline"
    tree.mkdir()
    archive = subprocess.run(["git", "archive", rev], cwd=REPO, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    if (tree / "setup.py").is_file():
        subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=tree, capture_output=True,
                       stdin=subprocess.DEVNULL, timeout=600)
    return tree
