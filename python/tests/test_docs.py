"""The Python blocks of docs/python.md and README.md run as written: the blocks of one file in
order, in one namespace (a tour builds on its earlier blocks), each `# prints: TEXT` line naming
text that block's output must contain. The runnable example is run too."""

import contextlib
import io
import re
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def blocks(path):
    return BLOCK.findall(path.read_text())


@pytest.mark.parametrize("doc", ["docs/python.md", "README.md"])
def test_python_blocks_run_and_print_what_they_say(doc, monkeypatch):
    monkeypatch.chdir(ROOT)  # the blocks read files of the repository by relative paths
    found = blocks(ROOT / doc)
    assert found, f"{doc} has no python block"
    namespace = {}
    for k, code in enumerate(found, 1):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"{doc} python block {k}", "exec"), namespace)
        for expected in re.findall(r"^\s*# prints: (.*)$", code, re.M):
            assert expected.strip() in out.getvalue(), (
                f"{doc} block {k}: expected {expected!r} in its output:\n{out.getvalue()}")


def test_example_tour_runs():
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_status:
        runpy.run_path(str(ROOT / "examples" / "python" / "tour.py"), run_name="__main__")
    assert exit_status.value.code == 0, out.getvalue()
    assert out.getvalue().rstrip().endswith("OK")
