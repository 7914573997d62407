"""clients/python/README.md's notebook runs as written (on a smaller cloth, to be quick), and
shows what it says: the stiffer in bending, the less the cloth sags under the rock; the stream
gets the rocks; the recording of a 2 s step holds its 121 frames; the asyncio streams get the
same step in f32 and in the smaller q16."""

import contextlib
import io
import re

from conftest import PACKAGE


def test_the_readme_notebook_runs_and_a_stiffer_cloth_sags_less(start_daemon):
    d = start_daemon("--nx", "24", "--ny", "24")
    blocks = re.findall(r"```python\n(.*?)```", (PACKAGE / "README.md").read_text(), re.S)
    assert len(blocks) == 4
    out = io.StringIO()
    scope = {}
    with contextlib.redirect_stdout(out):
        for code in blocks:
            exec(compile(code.replace("http://127.0.0.1:8080", d.url), "README.md", "exec"), scope)
    lines = out.getvalue().splitlines()
    sags = [float(m.group(1)) for m in (re.match(r"k_bend +\d+ N/m: sag (-?[\d.]+) cm", x) for x in lines) if m]
    assert len(sags) == 5, lines
    assert all(a > b for a, b in zip(sags, sags[1:])), sags
    assert sags[0] > 0
    assert re.match(r"3 rocks at heights \[", lines[-3]), lines
    # The recording: 2 s at 60 frames a second, its first frame and its last.
    assert re.match(r"121 frames over 2.00 s, lowest vertex at 0, 1, 2 s: \[", lines[-2]), lines
    m = re.match(r"step (\d+): f32 frame of (\d+) bytes, q16 of (\d+)$", lines[-1])
    assert m and int(m.group(1)) > 0 and int(m.group(2)) > int(m.group(3)), lines
