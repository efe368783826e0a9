"""Lint as a test: ruff (pyflakes and pycodestyle's error rules) is clean on the tree."""
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_is_clean():
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--output-format", "concise", "src", "tests"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


RUNTIME = ("yowo_common", "yowo_ego", "yowo_cmc", "yowo_fusion", "yowo_bringup")


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def test_runtime_packages_never_import_the_evaluation():
    """Benchmark, metrics and baselines live in yowo_eval; the runtime finds it only
    through entry points (yowo_bringup.plugins), so an install without it still runs."""
    offenders = [f"{p.relative_to(ROOT)}: {m}" for pkg in RUNTIME for p in (ROOT / "src" / pkg / pkg).rglob("*.py")
                 for m in imported_modules(p) if m.split(".")[0] in ("yowo_eval", "yowo_sim")]
    assert not offenders, offenders
