"""The README's Python examples run as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)


def test_the_readme_has_python_examples():
    assert len(BLOCKS) >= 2


@pytest.mark.parametrize("block", BLOCKS, ids=[f"block{i}" for i in range(len(BLOCKS))])
def test_readme_example_runs(block):
    shown = re.search(r"# ValueError: (.{20})", block)  # an example showing a user's error
    if shown is None:
        exec(compile(block, str(README), "exec"), {})
    else:
        with pytest.raises(ValueError, match=re.escape(shown.group(1))):
            exec(compile(block, str(README), "exec"), {})
