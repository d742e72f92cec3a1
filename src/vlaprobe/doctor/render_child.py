"""One renderer backend, in its own process: ``python -m vlaprobe.doctor.render_child OUT.npy``.

``MUJOCO_GL`` (set by the parent) picks the backend when MuJoCo is imported, so each backend needs a fresh
process, and a driver that hangs or crashes takes only this process with it. It renders one small scene
(a checker floor, a box, a sphere, one light), times the renders, saves the last image to ``OUT.npy`` and prints
one JSON line: ``{"first_seconds", "render_ms", "gl_renderer", "mujoco"}``, or ``{"error": "..."}`` (exit 1)
with the exception and the first warning the backend gave (e.g. GLFW's "DISPLAY environment variable is missing").
"""

from __future__ import annotations

import json
import sys
import time
import warnings

SCENE = """<mujoco>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1=".2 .3 .4" rgb2=".8 .8 .8" width="64" height="64"/>
    <material name="grid" texture="grid" texrepeat="4 4"/>
  </asset>
  <worldbody>
    <light pos="0 0 2" dir="0 0 -1"/>
    <geom type="plane" size="1 1 .1" material="grid"/>
    <geom type="box" pos="0 0 .1" size=".1 .1 .1" rgba=".8 .2 .2 1"/>
    <geom type="sphere" pos=".25 .1 .08" size=".08" rgba=".2 .7 .3 1"/>
    <geom type="capsule" fromto="-.3 -.2 .05 -.1 -.35 .05" size=".04" rgba=".9 .8 .2 1"/>
    <camera name="view" pos=".8 -.8 .7" xyaxes="1 1 0 -.4 .4 .8"/>
  </worldbody>
</mujoco>"""

SIZE = 128
RENDERS = 5


def _gl_renderer() -> str:
    """The OpenGL renderer string of the current context (e.g. "llvmpipe (LLVM 15.0.6, 256 bits)")."""
    try:
        from OpenGL import GL

        name = GL.glGetString(GL.GL_RENDERER)
        return name.decode() if isinstance(name, bytes) else str(name)
    except Exception as exc:  # PyOpenGL missing or no current context: the string is only informative
        return f"unknown ({type(exc).__name__})"


def render(out: str) -> dict[str, object]:
    """Render the scene with the backend ``MUJOCO_GL`` names; the image goes to ``out``."""
    import mujoco
    import numpy as np

    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = time.perf_counter()
    renderer = mujoco.Renderer(model, SIZE, SIZE)
    renderer.update_scene(data, camera="view")
    image = renderer.render()
    first = time.perf_counter() - start
    gl = _gl_renderer()
    start = time.perf_counter()
    for _ in range(RENDERS):
        renderer.update_scene(data, camera="view")
        image = renderer.render()
    per_render = (time.perf_counter() - start) / RENDERS
    np.save(out, image)
    return {
        "first_seconds": first,
        "render_ms": 1000 * per_render,
        "gl_renderer": gl,
        "mujoco": mujoco.__version__,
    }


def main(argv: list[str]) -> int:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            print(json.dumps(render(argv[0])))
            return 0
        except Exception as exc:
            # When the backend warned first (GLFW: "DISPLAY environment variable is missing"), that is the cause.
            error = (
                f"{caught[0].message} ({type(exc).__name__})" if caught else f"{type(exc).__name__}: {exc}"
            )
            print(json.dumps({"error": error[:400]}))
            return 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
