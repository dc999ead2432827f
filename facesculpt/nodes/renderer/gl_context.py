"""The OpenGL context the renderer draws with (moderngl, GL 3.3 core or newer).

Headless by default: a standalone EGL context (Mesa llvmpipe on a machine
without a GPU, the GPU's driver where there is one). A window (glfw) brings its
own context instead: see :mod:`facesculpt.nodes.renderer.window`.
"""

from __future__ import annotations

import moderngl

REQUIRED_GL = 330


def create_headless_context(backend: str = "egl") -> moderngl.Context:
    """A standalone moderngl context without a display.

    backend: "egl" (default; works without X) or "" to let moderngl pick (GLX on X11).
    Raises RuntimeError naming the backend when no context can be made.
    """
    kwargs = {"backend": backend} if backend else {}
    try:
        ctx = moderngl.create_standalone_context(require=REQUIRED_GL, **kwargs)
    except Exception as exc:  # moderngl raises plain Exception subclasses per backend
        raise RuntimeError(
            f"cannot create a headless OpenGL {REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10} context "
            f"through {backend or 'the default backend'}: {exc} (on Debian/Ubuntu: apt-get install libegl1 "
            f"libgl1-mesa-dri)"
        ) from exc
    return ctx


def describe(ctx: moderngl.Context) -> str:
    """One line naming the renderer and GL version, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits), GL 450'."""
    return f"{ctx.info.get('GL_RENDERER', '?')}, GL {ctx.version_code}"
