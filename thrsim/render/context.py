"""A headless OpenGL context: ModernGL on EGL (Mesa's llvmpipe where there is no GPU).

No window, no display server: EGL gives an OpenGL core context (4.5 on llvmpipe) on any Linux machine with
Mesa, which is what lets ``thrsim ream --png`` and the reports draw on a server or in CI.
"""

from __future__ import annotations

from thrsim.errors import ThrsimInputError

#: geometry shaders (the thesis's path) and the shaders' GLSL need OpenGL 3.3 core
REQUIRED_GL = 330


def offscreen_context():
    """A standalone ModernGL context on EGL; a one-line error where none can be made."""
    try:
        import moderngl
    except ImportError as error:  # pragma: no cover - moderngl is a dependency
        raise ThrsimInputError(f"offscreen rendering needs the moderngl package ({error}); run ./install.sh") from None
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=REQUIRED_GL)
    except Exception as error:  # moderngl raises plain Exception when EGL or the GL version is missing
        raise ThrsimInputError(
            f"no headless OpenGL {REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10} context through EGL ({error}); "
            "install Mesa's EGL (Debian: libegl1 libegl-mesa0 libgl1-mesa-dri, as ./install.sh does)"
        ) from None
    return ctx
