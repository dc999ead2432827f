"""Per-process thread limits (facesculpt.runtime.process_limits): a node limited to one thread
draws without llvmpipe threads of its own (they would wait for cores the graph's other nodes
hold), and a larger limit gives llvmpipe that many threads in all."""

from __future__ import annotations

import subprocess
import sys

import pytest

_DRAW = """
import glob
from facesculpt.runtime.process_limits import limit_threads
limit_threads({threads})
from facesculpt.nodes.renderer.gl_context import create_headless_context
ctx = create_headless_context()
fbo = ctx.simple_framebuffer((64, 64))
fbo.use()
fbo.clear(1.0)
fbo.read()
names = [open(p).read().strip() for p in glob.glob("/proc/self/task/*/comm")]
print(ctx.info["GL_RENDERER"])
print(sum(n.startswith("llvmpipe") for n in names))
"""


@pytest.mark.parametrize("threads, rasteriser_threads", [(1, 0), (3, 2)])
def test_the_thread_limit_holds_for_the_software_rasteriser(threads, rasteriser_threads):
    out = subprocess.run([sys.executable, "-c", _DRAW.format(threads=threads)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    renderer, count = out.stdout.split("\n")[-3:-1]
    if "llvmpipe" not in renderer:
        pytest.skip(f"the OpenGL renderer is {renderer}, not Mesa's llvmpipe")
    assert int(count) == rasteriser_threads
