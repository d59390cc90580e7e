# The Python examples of docs/python.md, run: each ```python block in a fresh namespace, and
# what its print() calls write compared with the comment that follows each call (on its line,
# or alone on the next line). A block that reads TOPOS_REFERENCE_DIR or TOPOS_DATASETS_DIR is
# skipped without it.
import contextlib
import io
import os
import pathlib
import re

import pytest

DOC = pathlib.Path(__file__).resolve().parents[2] / "docs" / "python.md"


def blocks():
    text = DOC.read_text()
    found = re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)
    assert found, f"{DOC}: no python blocks"
    return [pytest.param(b, id=f"block{i}") for i, b in enumerate(found)]


def expected_prints(code):
    lines = code.splitlines()
    out = []
    for i, line in enumerate(lines):
        if not line.startswith("print("):
            continue
        m = re.search(r"\)\s+#\s?(.*)$", line)
        if m:
            out.append(m.group(1).strip())
        elif i + 1 < len(lines) and lines[i + 1].startswith("# "):
            out.append(lines[i + 1][2:].strip())
    return out


@pytest.mark.parametrize("code", blocks())
def test_doc_example(code):
    for var in ("TOPOS_REFERENCE_DIR", "TOPOS_DATASETS_DIR"):
        if var in code and not os.environ.get(var):
            pytest.skip(f"{var} is not set")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        exec(compile(code, str(DOC), "exec"), {"__name__": "docs_python"})
    printed = [line.strip() for line in buf.getvalue().splitlines()]
    assert printed == expected_prints(code)
