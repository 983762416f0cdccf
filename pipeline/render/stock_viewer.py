"""What an ordinary glTF viewer shows of an export: ``sssbake verify --stock-viewer``.

pyrender (0.1.45), a renderer independent of sssbake's shaders, draws the file the way a stock
PBR viewer does: trimesh reads the glTF (geometry, node transforms, NORMAL, TEXCOORD_0 and the
core metallic-roughness material; its ``baseColorFactor`` is kept as 8-bit RGBA), pyrender ignores
``KHR_materials_transmission``, ``KHR_materials_volume``, ``KHR_materials_diffuse_transmission`` and
sssbake's data, and shades with its own GLSL: a viewer with no translucency at all. For the
fallback (base colour R_d, metallic 0; three.js takes the transmission factor's share out of it,
tests/render/test_fallback_three.py) that is Lambert's
c_diff / π, c_diff = 0.96 · base colour, weighted by 1 - F (Schlick, F0 = 0.04), plus a specular
lobe F G D / (4 n·l n·v), D GGX with α = ``roughnessFactor``², all times the
light's irradiance and n·l. A directional light casts pyrender's own shadow map, since the
reference and verify's Lambert have the geometry's shadows: without it a concave object's shadowed
parts are lit. Its price is pyrender's shadow acne, specks on lit surfaces, which darken a picture
that is too bright anyway (benchmarks/README.md#stock-viewer-shadows).
"""

from __future__ import annotations

import gc
import os
from pathlib import Path

import numpy as np

from sssbake.pipeline.render.renderer import Camera, RenderLight

#: pyrender writes ``pow(colour, 1 / 2.2)`` into an 8-bit target (a pure 2.2 gamma, not the sRGB curve).
PYRENDER_GAMMA = 2.2


def render_stock_viewer(path: str | os.PathLike, camera: Camera, light: RenderLight, size: int,
                        exposure: float = 1.0, only: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Render the .glb `path` with pyrender under verify's camera and light.

    Parameters
    ----------
    path : path
        A .glb (sssbake's main file: its fallback material; or ``<stem>.sss_normals.glb``).
    camera : Camera
        verify's camera (`render.fit_camera`); pyrender gets its exact view-projection.
    light : RenderLight
        A directional light (its irradiance, with pyrender's shadow map), or a point light
        (pyrender's falloff is intensity / d² in world units, so it gets intensity / mm_per_unit²;
        pyrender 0.1.45 casts no point-light shadows).
    size : int
        Image width and height in pixels.
    exposure : float
        verify's exposure: the light is this much brighter and the image divided by it again, so
        the 8-bit output spans the values `image_metrics.rmse` compares (its clip at 1 included).
    only : list of (n, 3) float arrays, optional
        Vertex positions of the primitives to draw (verify's: those its reference covers, not an
        opaque holder a viewer would also show); a primitive is drawn when its positions equal one
        of them. None: every primitive.

    Returns
    -------
    image : (size, size, 3) float32
        Linear radiance per unit irradiance, as verify's images (``Renderer.render``): pyrender's
        8-bit output decoded with `PYRENDER_GAMMA`, divided by `exposure`; row 0 at the top.
    coverage : (size, size) bool
        Alpha > 0.5, as verify's coverage (pyrender resolves 4x multisampling, so silhouette
        pixels blend with the black background).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"stock viewer: {path} does not exist")
    if not (np.isfinite(exposure) and exposure > 0):
        raise ValueError(f"stock viewer: exposure must be positive, got {exposure}")
    pyrender, trimesh = _import_pyrender()

    loaded = trimesh.load(str(path), force="scene")
    if only is not None:
        # trimesh names its geometries itself, so a primitive is told by its accessor's positions
        loaded.delete_geometry([name for name, mesh in loaded.geometry.items()
                                if not any(np.array_equal(mesh.vertices, positions) for positions in only)])
        if not loaded.geometry:
            raise ValueError(f"stock viewer: {path} has none of the primitives to draw")
    scene = pyrender.Scene.from_trimesh_scene(loaded, bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
    eye = np.eye(4)
    eye[:3, 3] = camera.eye

    class FixedCamera(pyrender.Camera):
        """verify's view-projection: pyrender draws P V with V = pose⁻¹, so P = VP · pose; the pose
        only places the eye (pyrender's view vector for the specular term). Its znear and zfar only
        linearise a depth image this module does not read."""

        def get_projection_matrix(self, width=None, height=None):
            return np.asarray(camera.view_projection, dtype=np.float64) @ eye

    scene.add(FixedCamera(), pose=eye)
    pose = np.eye(4)
    if light.point:
        pose[:3, 3] = light.vector
        scene.add(pyrender.PointLight(intensity=exposure * light.intensity / light.mm_per_unit ** 2), pose=pose)
    else:
        pose[:3, :3] = _frame(np.asarray(light.vector, dtype=np.float64))
        scene.add(pyrender.DirectionalLight(intensity=exposure * light.intensity), pose=pose)
    flags = pyrender.RenderFlags.OFFSCREEN | pyrender.RenderFlags.RGBA | pyrender.RenderFlags.SHADOWS_DIRECTIONAL
    rgba = _render(pyrender, scene, size, flags)
    image = (rgba[..., :3].astype(np.float64) / 255.0) ** PYRENDER_GAMMA / exposure
    return image.astype(np.float32), rgba[..., 3] > 127


def _frame(towards: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose z axis is unit `towards`: a pyrender light shines along its node's -z."""
    z = towards / np.linalg.norm(towards)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _render(pyrender, scene, size: int, flags) -> np.ndarray:
    """(size, size, 4) uint8 of `scene` in a fresh EGL context, the caller's context current again after.

    pyrender's `OffscreenRenderer` would end with ``eglTerminate`` on the display, which moderngl's
    contexts in this process share (measured: moderngl then could not create a texture), and
    would leave its own context current; so the context is made and destroyed here.
    """
    from OpenGL import EGL
    from pyrender.platforms.egl import EGLPlatform

    previous = (EGL.eglGetCurrentDisplay(), EGL.eglGetCurrentSurface(EGL.EGL_DRAW),
                EGL.eglGetCurrentSurface(EGL.EGL_READ), EGL.eglGetCurrentContext())
    platform = EGLPlatform(size, size)
    platform.init_context()
    try:
        renderer = pyrender.Renderer(size, size)
        try:
            rgba, _ = renderer.render(scene, flags)
        finally:
            renderer.delete()
            # `Renderer.__del__` deletes again, and 0.1.45 keeps its shadow framebuffer's name: run
            # it while this context is current, or it frees the caller's framebuffer of that name.
            del renderer
            gc.collect()
    finally:
        from OpenGL.error import GLError

        display = platform._egl_display
        restored = False
        if previous[3]:
            try:
                restored = bool(EGL.eglMakeCurrent(*previous))
            except GLError:
                pass  # the caller's context was released while current: EGL deleted it once unbound
        if not restored:
            EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(display, platform._egl_context)
    return np.asarray(rgba)


def _import_pyrender():
    """pyrender and trimesh, pyrender on headless EGL."""
    # PyOpenGL picks its platform at first import; pyrender needs EGL here, as moderngl uses.
    os.environ["PYOPENGL_PLATFORM"] = "egl"
    if not hasattr(np, "infty"):  # pyrender 0.1.45 still uses the alias numpy 2 removed
        np.infty = np.inf
    import pyrender
    import trimesh

    return pyrender, trimesh
