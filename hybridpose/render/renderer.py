"""MuJoCo offscreen renderer: exact pinhole intrinsics, space lighting, arm occluder, masks, depth.

The MuJoCo camera sits at the world origin with ``xyaxes="1 0 0 0 -1 0"``, so the world frame *is*
the OpenCV camera frame and the object's mocap pose is ``T_cam_obj`` itself. Intrinsics are given
in pixels (``focalpixel``/``principalpixel``); the alignment with ``cv2.projectPoints`` is tested.
"""
from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ["MUJOCO_GL"] == "egl":
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from dataclasses import dataclass  # noqa: E402

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from ..geometry import Camera, Pose, as_unit_direction, matrix_to_quat_wxyz  # noqa: E402
from ..objects import ObjectModel  # noqa: E402
from .appearance import MAX_FILL_LIGHTS, TEXTURE_FLOOR, Appearance  # noqa: E402
from .face_print import face_print_gain  # noqa: E402
from .lighting import SensorModel, SpaceLighting, earth_background  # noqa: E402
from .occluder import ArmState  # noqa: E402

_ARM_GROUP = 1  # MuJoCo geom group of the arm (its own segmentation)
# arm links and tool: (geom/body name, MuJoCo type, initial size, material); sizes are set per frame
_ARM_PARTS = (
    ("arm_upper", "capsule", "0.04 0.1", "arm_paint"),
    ("arm_fore", "capsule", "0.035 0.1", "arm_paint"),
    ("arm_tool", "cylinder", "0.1 0.015", "tool_metal"),
)
_ARM_NAMES = tuple(p[0] for p in _ARM_PARTS)
_NEAR_M = 0.01  # clip planes: a part 1 cm from the lens
_FAR_M = 50.0  # far clip plane


@dataclass(frozen=True, eq=False)
class RenderResult:
    """One rendered view.

    Attributes:
        rgb: (H, W, 3) uint8 RGB after lighting, background and sensor effects.
        depth: (H, W) float32 depth along the optical axis (z), metres; 0 where nothing is hit.
        mask_visib: (H, W) bool, pixels where the object is visible (not hidden by the arm).
        mask: (H, W) bool, the object's full silhouette (ignoring the arm).
    """

    rgb: np.ndarray
    depth: np.ndarray
    mask_visib: np.ndarray
    mask: np.ndarray

    @property
    def visible_fraction(self) -> float:
        """Visible share of the silhouette, 0..1 (BOP's ``visib_fract``)."""
        n = int(self.mask.sum())
        return float(self.mask_visib.sum()) / n if n else 0.0


def _fmt(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.ravel(v))


def _quat_z_to(axis: np.ndarray) -> np.ndarray:
    """(w, x, y, z) rotating +z onto ``axis``."""
    a = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, a))
    if c < -1 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    v = np.cross(z, a)
    q = np.array([1.0 + c, *v])
    return q / np.linalg.norm(q)


PRINT_FILE = "object_print.png"  # the part's print, handed to MuJoCo as an in-memory asset


def _png(rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError("texture: OpenCV could not encode the part's print as PNG")
    return buf.tobytes()


def scene_xml(obj: ObjectModel, camera: Camera, lighting: SpaceLighting, shadow_size: int = 2048) -> str:
    """The MJCF scene: camera at the origin, one directional sun, the object and the arm (mocap)."""
    w, h = camera.width, camera.height
    # one vertex per face corner: MuJoCo then shades every face flat, as machined metal looks,
    # instead of averaging normals across the 90° creases of the beams
    v = obj.vertices[obj.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    # a part with a print: the image on its surface (OBJ's v counts up from the image's bottom row,
    # MuJoCo's texture rows from the top: tests/test_render.py checks the way up end to end)
    printed = obj.texture is not None
    texcoord = f' texcoord="{_fmt(np.c_[obj.face_uv[..., 0].ravel(), 1.0 - obj.face_uv[..., 1].ravel()])}"' if printed else ""
    print_asset = (f'\n    <texture name="object_print" type="2d" file="{PRINT_FILE}"/>' if printed else "")
    material = ('<material name="object_metal" texture="object_print" rgba="1 1 1 1" specular="0.3" shininess="0.3" reflectance="0"/>'
                if printed else
                '<material name="object_metal" rgba="0.78 0.78 0.80 1" specular="0.9" shininess="0.7" reflectance="0"/>')
    # a directional light in MuJoCo projects its shadow map around its position; we move the
    # light with the object each frame (see Renderer.render), the clip box spans the arm too.
    # lights besides the sun for scenes outside space (render(..., appearance=...)); dark unless asked
    fill_lights = "\n".join(
        f'    <light name="fill{i}" directional="true" castshadow="false" pos="0 0 -1" dir="0 0 1" '
        'diffuse="0 0 0" specular="0 0 0" ambient="0 0 0"/>' for i in range(MAX_FILL_LIGHTS))
    arm_bodies = "\n".join(
        f'    <body name="{name}" mocap="true" pos="0 0 -10">\n'
        f'      <geom name="{name}" type="{kind}" size="{size}" material="{material}" contype="0" conaffinity="0" group="{_ARM_GROUP}"/>\n'
        "    </body>"
        for name, kind, size, material in _ARM_PARTS
    )
    return f"""
<mujoco model="hybridpose">
  <compiler angle="radian"/>
  <option gravity="0 0 0"/>
  <statistic extent="1" center="0 0 0.7"/>
  <visual>
    <global offwidth="{w}" offheight="{h}"/>
    <quality shadowsize="{shadow_size}" offsamples="4"/>
    <headlight active="0" ambient="0 0 0" diffuse="0 0 0" specular="0 0 0"/>
    <map znear="{_NEAR_M}" zfar="{_FAR_M}" shadowclip="0.8" shadowscale="0.6"/>
    <rgba haze="0 0 0 1"/>
  </visual>
  <asset>
    <mesh name="object" vertex="{_fmt(v)}" face="{_fmt(f)}"{texcoord}/>{print_asset}
    {material}
    <material name="arm_paint" rgba="0.85 0.85 0.82 1" specular="0.3" shininess="0.3" reflectance="0"/>
    <material name="tool_metal" rgba="0.45 0.45 0.48 1" specular="0.8" shininess="0.6" reflectance="0"/>
  </asset>
  <worldbody>
    <camera name="cam" pos="0 0 0" xyaxes="1 0 0 0 -1 0" resolution="{w} {h}" sensorsize="{w * 1e-5:.9g} {h * 1e-5:.9g}"
            focalpixel="{camera.fx:.9g} {camera.fy:.9g}" principalpixel="{-(camera.cx - (w / 2 - 0.5)):.9g} {-(camera.cy - (h / 2 - 0.5)):.9g}"/>
    <light name="sun" directional="true" castshadow="true" pos="0 0 -1" dir="{_fmt(lighting.sun_direction_cam)}"
           diffuse="1 1 1" specular="1 1 1" ambient="0 0 0"/>
{fill_lights}
    <body name="object" mocap="true" pos="0 0 1">
      <geom name="object" type="mesh" mesh="object" material="object_metal" contype="0" conaffinity="0" group="0"/>
    </body>
{arm_bodies}
  </worldbody>
</mujoco>"""


class _OffscreenGL:
    """MuJoCo's public low-level rendering API on an offscreen EGL buffer.

    Written out (instead of using ``mujoco.Renderer``) so that one flat, segmented pass yields both
    the ID image and the depth buffer in a single ``mjr_readPixels``; ``mujoco.Renderer`` needs a
    pass for each and decodes IDs in Python, which tripled the cost of a frame (profiled: 23 ms vs
    8 ms for the RGB pass at 640×480).
    """

    def __init__(self, model: mujoco.MjModel, width: int, height: int) -> None:
        from mujoco import gl_context

        self.model, self.width, self.height = model, width, height
        self._ctx = gl_context.GLContext(width, height)
        self._ctx.make_current()
        self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._mjr.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self.scene = mujoco.MjvScene(model, maxgeom=64)
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "cam")
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._depth = np.empty((height, width), np.float32)
        near = np.float32(model.vis.map.znear * model.stat.extent)
        far = np.float32(model.vis.map.zfar * model.stat.extent)
        # reverse-Z depth buffer → metric depth (the mapping mujoco.Renderer uses)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        self._c, self._d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d

    def update(self, data: mujoco.MjData, option: mujoco.MjvOption) -> None:
        self._ctx.make_current()
        mujoco.mjv_updateScene(self.model, data, option, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL, self.scene)

    def render_rgb(self) -> np.ndarray:
        """(H, W, 3) uint8 shaded image."""
        mujoco.mjr_render(self._rect, self.scene, self._mjr)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._mjr)
        return np.flipud(self._rgb).copy()  # OpenGL rows run bottom-up

    def render_ids_depth(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) int32 segment code (scene geom index + 1, 0 = nothing) and (H, W) depth in metres."""
        flags = self.scene.flags
        seg, idc = mujoco.mjtRndFlag.mjRND_SEGMENT, mujoco.mjtRndFlag.mjRND_IDCOLOR
        flags[seg], flags[idc] = 1, 1
        try:
            mujoco.mjr_render(self._rect, self.scene, self._mjr)
            mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._mjr)
        finally:
            flags[seg], flags[idc] = 0, 0
        rgb = self._rgb.astype(np.int32)
        ids = rgb[..., 0] | (rgb[..., 1] << 8) | (rgb[..., 2] << 16)
        depth = self._d / (self._depth.astype(np.float64) + self._c)  # float64: precision at range
        return np.flipud(ids), np.flipud(depth)

    def close(self) -> None:
        if self._ctx is not None:
            self._ctx.make_current()
            self._mjr.free()
            self._ctx.free()
            self._ctx = None


class Renderer:
    """Render an object at ``T_cam_obj`` as a space camera sees it.

    Args:
        obj: the object model (metres).
        camera: intrinsics; every render has ``camera.width × camera.height`` pixels. Distortion
            is not rendered (MuJoCo is a pinhole); a camera with ``dist`` raises ValueError.
        lighting: sun direction/intensity, exposure, background.
        sensor: blur / noise / gamma applied to ``rgb`` (None = ideal sensor).
        shadow_size: shadow-map resolution (pixels per side).
    """

    def __init__(
        self,
        obj: ObjectModel,
        camera: Camera,
        lighting: SpaceLighting | None = None,
        sensor: SensorModel | None = None,
        shadow_size: int = 2048,
    ) -> None:
        if camera.dist:
            raise ValueError("camera: the renderer is a pinhole; pass a camera without distortion (dist=())")
        self.obj, self.camera = obj, camera
        self.lighting = lighting or SpaceLighting()
        self.sensor = sensor or SensorModel()
        assets = {PRINT_FILE: _png(obj.texture)} if obj.texture is not None else None
        self._model = mujoco.MjModel.from_xml_string(scene_xml(obj, camera, self.lighting, shadow_size), assets)
        self._data = mujoco.MjData(self._model)
        self._gl = _OffscreenGL(self._model, camera.width, camera.height)
        m = self._model
        self._object_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        self._mocap = {n: int(m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)])
                       for n in ("object", *_ARM_NAMES)}
        self._geom = {n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in _ARM_NAMES}
        self._light = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, "sun")
        self._fills = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, f"fill{i}") for i in range(MAX_FILL_LIGHTS)]
        self._object_material = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, "object_metal")
        self._object_rgba = m.mat_rgba[self._object_material].copy()
        self._opt_all = mujoco.MjvOption()
        self._opt_no_arm = mujoco.MjvOption()
        self._opt_no_arm.geomgroup[_ARM_GROUP] = 0
        # MuJoCo re-centres a mesh on its centre of mass; the geom frame carries the offset so the
        # vertices appear where the file puts them. The alignment test checks this end to end.

    def close(self) -> None:
        self._gl.close()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- scene state ---------------------------------------------------------------------------
    def _set_mocap(self, name: str, pos, quat_wxyz) -> None:
        i = self._mocap[name]
        self._data.mocap_pos[i] = pos
        self._data.mocap_quat[i] = quat_wxyz

    def _set_arm(self, arm: ArmState | None) -> None:
        if arm is None:
            for name in _ARM_NAMES:
                self._set_mocap(name, [0.0, 0.0, -10.0], [1.0, 0.0, 0.0, 0.0])  # behind the camera
            return
        for name, cap in zip(_ARM_NAMES[:2], arm.links):
            d = cap.p1 - cap.p0
            half = 0.5 * float(np.linalg.norm(d))
            self._model.geom_size[self._geom[name]][:2] = (cap.radius_m, max(half, 1e-4))
            self._model.geom_rbound[self._geom[name]] = half + cap.radius_m
            self._set_mocap(name, 0.5 * (cap.p0 + cap.p1), _quat_z_to(d))
        g = self._geom["arm_tool"]
        self._model.geom_size[g][:2] = (arm.tool_radius_m, arm.tool_half_thickness_m)
        self._model.geom_rbound[g] = float(np.hypot(arm.tool_radius_m, arm.tool_half_thickness_m))
        self._set_mocap("arm_tool", arm.tool_centre, _quat_z_to(arm.tool_axis))

    def _set_sun(self, T_cam_obj: Pose, sun_scale: float, sun_direction_cam=None) -> None:
        d = np.asarray(self.lighting.sun_direction_cam if sun_direction_cam is None else sun_direction_cam, dtype=np.float64)
        self._model.light_pos[self._light] = T_cam_obj.t - 1.5 * d
        self._model.light_dir[self._light] = d
        k = self.lighting.sun_intensity * sun_scale
        self._model.light_diffuse[self._light] = (k, k, k)
        s = self.lighting.sun_specular * sun_scale
        self._model.light_specular[self._light] = (s, s, s)

    def _set_appearance(self, look: Appearance | None) -> None:
        """Ambient light, fill lights and the part's colour of ``look`` (None: space — none of them)."""
        look = look or Appearance()
        for i, light in enumerate(self._fills):
            d, k = look.fill_lights[i] if i < len(look.fill_lights) else ((0.0, 0.0, 1.0), 0.0)
            self._model.light_dir[light] = d
            self._model.light_diffuse[light] = (k, k, k)
            self._model.light_specular[light] = (0.3 * k,) * 3
        # the ambient term rides on the first fill light: it lights every face whatever the sun does
        self._model.light_ambient[self._fills[0]] = (look.ambient,) * 3
        rgba = self._object_rgba.copy()
        # a part with its own print keeps the print's colours (white balance varies them in the image)
        if look.object_rgb is not None and self.obj.texture is None:
            rgba[:3] = look.object_rgb
        self._model.mat_rgba[self._object_material] = rgba

    def _object_code(self) -> int:
        """ID colour of the object in the current scene (segment index + 1; 0 = background)."""
        scene = self._gl.scene
        for i in range(scene.ngeom):
            g = scene.geoms[i]
            if g.objtype == int(mujoco.mjtObj.mjOBJ_GEOM) and g.objid == self._object_geom:
                return g.segid + 1
        return -1  # object culled (out of view)

    # --- rendering -----------------------------------------------------------------------------
    def render(
        self,
        T_cam_obj: Pose,
        arm: ArmState | None = None,
        sun_scale: float = 1.0,
        rng: np.random.Generator | int | None = None,
        sun_direction_cam=None,
        appearance: Appearance | None = None,
    ) -> RenderResult:
        """Render the object at ``T_cam_obj`` (object → camera, metres).

        Args:
            T_cam_obj: pose of the object; its origin must be in front of the camera (t_z > 0).
            arm: arm geometry for this frame (None = no arm in view).
            sun_scale: multiplies the sun's intensity (0 = eclipse).
            rng: seed for the background and sensor noise of this frame.
            sun_direction_cam: (3,) direction the sunlight travels in the camera frame for this
                frame only (None = the lighting's); normalised here.
            appearance: ambient and fill lights, the part's colour and the background of this frame
                (:mod:`hybridpose.render.appearance`; None = space: none of them).
        """
        if not isinstance(T_cam_obj, Pose):
            raise TypeError(f"T_cam_obj: expected a hybridpose Pose, got {type(T_cam_obj).__name__}")
        if T_cam_obj.t[2] <= _NEAR_M:
            raise ValueError(f"T_cam_obj: the object is behind the camera (t_z = {T_cam_obj.t[2]:.3f} m; expected > {_NEAR_M} m)")
        if not np.isfinite(sun_scale) or sun_scale < 0:
            raise ValueError(f"sun_scale: expected a non-negative factor, got {sun_scale}")
        if sun_direction_cam is not None:
            sun_direction_cam = as_unit_direction(sun_direction_cam, "sun_direction_cam")
        rng = np.random.default_rng(rng)
        self._set_mocap("object", T_cam_obj.t, matrix_to_quat_wxyz(T_cam_obj.R))
        self._set_arm(arm)
        self._set_sun(T_cam_obj, sun_scale, sun_direction_cam)
        self._set_appearance(appearance)
        mujoco.mj_forward(self._model, self._data)

        gl = self._gl
        gl.update(self._data, self._opt_all)
        rgb = gl.render_rgb()
        ids, depth = gl.render_ids_depth()
        hit = ids > 0
        depth = np.where(hit, depth, 0.0).astype(np.float32)
        mask_visib = ids == self._object_code()
        if arm is not None and np.any(hit & ~mask_visib):
            gl.update(self._data, self._opt_no_arm)
            ids_full, _ = gl.render_ids_depth()
            mask = ids_full == self._object_code()
        else:
            mask = mask_visib

        if self.lighting.exposure != 1.0:
            rgb = np.clip(rgb.astype(np.float32) * self.lighting.exposure, 0, 255).astype(np.uint8)
        if appearance is not None and appearance.background is not None:
            bg = appearance.background
            if bg.shape[:2] != (self.camera.height, self.camera.width):
                raise ValueError(f"appearance.background: expected {self.camera.height}×{self.camera.width} px, "
                                 f"got {bg.shape[0]}×{bg.shape[1]}")
            rgb = np.where(hit[..., None], rgb, bg)
        elif self.lighting.background == "earth":
            bg = earth_background(self.camera.width, self.camera.height, rng)
            rgb = np.where(hit[..., None], rgb, bg)
        if appearance is not None and appearance.object_texture is not None:
            tex = appearance.object_texture
            if tex.shape[:2] != (self.camera.height, self.camera.width):
                raise ValueError(f"appearance.object_texture: expected {self.camera.height}×{self.camera.width} px, "
                                 f"got {tex.shape[0]}×{tex.shape[1]}")
            if appearance.print_faces is None:
                ink = tex[mask_visib].astype(np.float32) / 255.0
            else:
                ink = face_print_gain(tex, appearance.print_faces, depth, mask_visib, self.camera, T_cam_obj,
                                      self.obj.bbox_min, self.obj.bbox_max)
            gain = TEXTURE_FLOOR + (1.0 - TEXTURE_FLOOR) * ink
            rgb = rgb.copy()
            rgb[mask_visib] = np.clip(rgb[mask_visib].astype(np.float32) * gain, 0, 255).astype(np.uint8)
        rgb = self.sensor.apply(rgb, rng)
        return RenderResult(rgb=rgb, depth=depth, mask_visib=mask_visib, mask=mask)
