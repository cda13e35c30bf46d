"""The Python examples of the README and of the docs that have them run as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = (
    README,
    *(
        ROOT / "docs" / name
        for name in (
            "controllers.md",
            "identification.md",
            "tuning.md",
            "hardware.md",
            "devices.md",
        )
    ),
    ROOT / "docs" / "residual.md",
    ROOT / "models" / "residual" / "README.md",
)
BLOCKS = [
    (path, block)
    for path in DOCS
    for block in re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.DOTALL)
]


def test_the_readme_has_python_examples():
    assert sum(path == README for path, _ in BLOCKS) >= 2


#: An example that trains a policy from scratch (the README's PPO, 300 000 steps: 99 s here)
#: runs in the slow suite: it is the whole default suite's largest item.
TRAINS = re.compile(r"\.learn\(\s*[0-9_]{6,}")


@pytest.mark.parametrize(
    ("path", "block"),
    [pytest.param(p, b, marks=[pytest.mark.slow] if TRAINS.search(b) else []) for p, b in BLOCKS],
    ids=[f"{p.stem}-block{i}" for i, (p, _) in enumerate(BLOCKS)],
)
def test_example_runs(path, block, monkeypatch):
    monkeypatch.chdir(ROOT)  # the docs' examples name files relative to the repository
    shown = re.search(r"# ValueError: (.{20})", block)  # an example showing a user's error
    if shown is None:
        exec(compile(block, str(path), "exec"), {})
    else:
        with pytest.raises(ValueError, match=re.escape(shown.group(1))):
            exec(compile(block, str(path), "exec"), {})
