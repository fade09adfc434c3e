"""Headless OpenGL drawing for the 3-D world: moderngl on Mesa's EGL (llvmpipe, software, no display).

One `GLCanvas` draws triangle meshes through the camera model of shared/camera.py and reads back
three things per pixel: the colour (BGR uint8), the depth along the optical axis [m] (the
fragment's own camera-x, not the non-linear z-buffer; inf for the sky) and which kind of surface
it is (`SURFACE_*`). Two ways to colour a mesh:
- `uv`: a texture at per-vertex texture coordinates times a per-vertex light factor, and a finer
  detail texture (photographs, the ground, solid objects; a cut-out's texels with alpha < 0.5 are
  not drawn);
- `colour`: per-vertex colours, lit by the sun with the face's own normal (the person).
Projection (camera x forward, y left, z up; u = 1/2 - f y / (x w_s), v = 1/2 - f z / (x h_s))
maps pixel u W to window x exactly, so a point lands in the pixel that camera.project_world names.
The context is made where the first draw happens (a GL context belongs to one thread at a time).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from cinetransfer.shared import camera as cam

#: surface kinds in the read-back id buffer
SURFACE_NONE, SURFACE_GROUND, SURFACE_BACKGROUND, SURFACE_FOREGROUND, SURFACE_SUBJECT, SURFACE_SKY = 0, 1, 2, 3, 4, 5
SURFACE_OBJECT = 6
NEAR_M = 0.05
FAR_M = 20000.0
#: the sky's depth in the read-back (as far as anything)
SKY_DEPTH = math.inf
#: direction towards the sun (world, normalised in the shader) and the ambient share of the light
SUN_DIR = (-0.35, 0.45, 0.82)
AMBIENT = 0.45

_VERTEX = """
#version 330
uniform mat4 mvp;
uniform vec4 depth_row;
in vec3 in_pos;
in vec2 in_uv;
in vec3 in_col;
out vec3 v_world;
out float v_depth;
out vec2 v_uv;
out vec3 v_col;
void main() {
    vec4 w = vec4(in_pos, 1.0);
    gl_Position = mvp * w;
    v_depth = dot(depth_row, w);
    v_world = in_pos;
    v_uv = in_uv;
    v_col = in_col;
}
"""

_FRAGMENT_HEAD = """
#version 330
uniform sampler2D tex;
uniform sampler2D detail;
uniform float detail_period_m;  // detail repeats per texture repeat
uniform float detail_gain;
uniform float detail_lod_offset;  // the detail's mip level minus the texture's (a constant per mesh)
uniform float surface;
uniform float fixed_depth;      // > 0: write this depth (the sky: inf)
uniform vec3 sun;
uniform float ambient;
in vec3 v_world;
in float v_depth;
in vec2 v_uv;
in vec3 v_col;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
layout(location = 2) out float f_id;
"""

#: the body of each colouring (`mode`), with and without the detail texture and the sun: one small
#: program each (llvmpipe runs both sides of a branch, so a do-everything shader costs every path)
_FRAGMENT_BODY = {
    "uv": """
// the mip level from the area of the pixel's footprint in texels (the Jacobian's determinant), not
// from its longer side: ground seen at a grazing angle stays as sharp as across (no anisotropic
// filtering, which costs llvmpipe ~10x)
float area_lod(sampler2D s, vec2 uv) {
    vec2 size = vec2(textureSize(s, 0));
    vec2 dx = dFdx(uv) * size, dy = dFdy(uv) * size;
    return 0.5 * log2(max(abs(dx.x * dy.y - dx.y * dy.x), 1e-8));
}
void main() {
    float lod = area_lod(tex, v_uv);
    vec4 t = textureLod(tex, v_uv, lod);
#ifdef ALPHA
    if (t.a < 0.5) discard;
#endif
    vec3 c = t.rgb * v_col;
#ifdef DETAIL
    vec2 d_uv = v_uv * detail_period_m;
    c *= 1.0 + detail_gain * (2.0 * textureLod(detail, d_uv, lod + detail_lod_offset).r - 1.0);
#endif
""",
    "colour": """
void main() {
    vec3 n = normalize(cross(dFdx(v_world), dFdy(v_world)));
    vec3 c = v_col;
""",
}
_FRAGMENT_TAIL = """
#ifdef LIT
    c *= ambient + (1.0 - ambient) * abs(dot(n, normalize(sun)));
#endif
    f_color = vec4(clamp(c, 0.0, 1.0), 1.0);
    f_depth = fixed_depth > 0.0 ? fixed_depth : v_depth;
    f_id = surface / 255.0;
}
"""


#: a depth-only draw (the truth of a frame without its picture): no colour is computed, and only a
#: cut-out samples its texture, for the alpha that decides which of its pixels exist (the very test of
#: the colour pass, so the depth and surface ids are the same bytes)
_FRAGMENT_DEPTH_ONLY = """
void main() {
#ifdef ALPHA
    if (textureLod(tex, v_uv, area_lod(tex, v_uv)).a < 0.5) discard;
#endif
    f_color = vec4(0.0, 0.0, 0.0, 1.0);
"""
_AREA_LOD = _FRAGMENT_BODY["uv"][:_FRAGMENT_BODY["uv"].index("void main()")]


def fragment_source(mode: str, detail: bool, lit: bool, alpha: bool = False, depth_only: bool = False) -> str:
    defines = "".join(f"#define {d}\n" for d, on in (("DETAIL", detail), ("LIT", lit), ("ALPHA", alpha)) if on)
    head = _FRAGMENT_HEAD.replace("#version 330\n", "#version 330\n" + defines, 1)
    if depth_only:
        return head + (_AREA_LOD if alpha else "") + _FRAGMENT_DEPTH_ONLY + _FRAGMENT_TAIL[_FRAGMENT_TAIL.index(
            "    f_depth"):]
    return head + _FRAGMENT_BODY[mode] + _FRAGMENT_TAIL


@dataclass
class MeshData:
    """Triangles in world metres and how to colour them (see the module's docstring)."""

    name: str
    vertices: np.ndarray  # (N, 3) float32 world
    faces: np.ndarray  # (F, 3) int32
    mode: str  # 'uv' | 'colour'
    surface: int
    uv: np.ndarray | None = None  # (N, 2) float32 (mode uv)
    colours: np.ndarray | None = None  # (N, 3) float32 BGR 0..1 (mode colour); mode uv: a light factor (1 = none)
    texture: str | None = None  # a texture's key in the canvas (mode uv)
    detail: str | None = None
    detail_period_m: float = 1.0
    detail_gain: float = 0.0
    lit: bool = False  # mode colour: shaded by the sun (mode uv carries its light in `colours`)
    sky: bool = False
    alpha: bool = False  # mode uv: texels with alpha < 0.5 are not drawn (a cut-out picture)
    closed: bool = False  # a closed surface, counter-clockwise seen from outside: its back faces are not drawn


def clip_matrix(position_m: np.ndarray, ypr_rad: np.ndarray, focal_mm: float, sensor: cam.Sensor
                ) -> tuple[np.ndarray, np.ndarray]:
    """(world -> clip 4x4, world -> camera-x row) for the camera model of shared/camera.py. Window y runs
    down the image (GL's first row read back is the image's top row: no flip after the read)."""
    r = cam.rotation_ypr(*np.asarray(ypr_rad, float))
    view = np.eye(4)
    view[:3, :3] = r.T
    view[:3, 3] = -r.T @ np.asarray(position_m, float)
    a = (FAR_M + NEAR_M) / (FAR_M - NEAR_M)
    b = -2.0 * FAR_M * NEAR_M / (FAR_M - NEAR_M)
    proj = np.array([[0.0, -2.0 * focal_mm / sensor.width_mm, 0.0, 0.0],
                     [0.0, 0.0, -2.0 * focal_mm / sensor.height_mm, 0.0],
                     [a, 0.0, 0.0, b],
                     [1.0, 0.0, 0.0, 0.0]])
    return proj @ view, view[0]


class GLCanvas:
    """An offscreen framebuffer of (width, height) and the meshes drawn into it."""

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)
        self._ctx = None
        self._owner: int | None = None
        self._textures: dict[str, tuple[np.ndarray, bool]] = {}
        self._gl_textures: dict = {}
        self._static: dict[str, tuple] = {}  # mesh name -> (vertex buffer, index buffer, shape)
        self._vaos: dict[tuple[str, tuple], object] = {}  # (mesh name, program key) -> its vertex array

    # -- resources -------------------------------------------------------------------------
    def add_texture(self, key: str, bgr: np.ndarray, repeat: bool = True) -> None:
        """A texture (h, w, 3|4) uint8 BGR(A) under `key`, tiled (`repeat`) or clamped at its edges."""
        img = np.ascontiguousarray(bgr)
        if img.shape[2] == 3:
            img = np.dstack([img, np.full(img.shape[:2], 255, np.uint8)])
        self._textures[key] = (img, repeat)

    def _context(self):
        me = threading.get_ident()
        if self._ctx is None:
            import moderngl

            self._ctx = moderngl.create_standalone_context(backend="egl", require=330)
            self._owner = me
            self._build()
        elif self._owner != me:
            raise RuntimeError("GLCanvas used from a second thread: a GL context belongs to the thread that made it")
        return self._ctx

    def _build(self) -> None:
        import moderngl

        ctx = self._ctx
        self._cull_face = moderngl.CULL_FACE
        self._programs: dict[tuple[str, bool, bool, bool, bool], object] = {}
        self._color = ctx.renderbuffer((self.width, self.height), 4)
        # the depth and the surface id each in a buffer of its own, read back straight into the arrays handed
        # on: one interleaved float pair a pixel cost a 4 MB read-back and two strided copies out of it
        self._depth = ctx.renderbuffer((self.width, self.height), 1, dtype="f4")
        self._surface = ctx.renderbuffer((self.width, self.height), 1, dtype="f1")  # id / 255: exact in 8 bits
        self._zbuf = ctx.depth_renderbuffer((self.width, self.height))
        self._fbo = ctx.framebuffer(color_attachments=[self._color, self._depth, self._surface],
                                    depth_attachment=self._zbuf)
        for key, (img, repeat) in self._textures.items():
            t = ctx.texture((img.shape[1], img.shape[0]), 4, img[::-1].tobytes())
            t.repeat_x = t.repeat_y = repeat
            t.build_mipmaps()
            # nearest mip level, bilinear within it: trilinear and anisotropic filtering cost llvmpipe
            # 2x and 10x; the detail texture keeps a texel per pixel where the mip level drops
            t.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
            self._gl_textures[key] = t

    @staticmethod
    def _program_key(mesh: MeshData, depth_only: bool) -> tuple:
        if depth_only:  # one program for every mesh but the cut-outs
            return (mesh.mode if mesh.alpha else "uv", False, False, mesh.alpha, True)
        return (mesh.mode, mesh.detail is not None and mesh.detail_gain > 0, mesh.lit, mesh.alpha, False)

    def _program(self, key: tuple):
        prog = self._programs.get(key)
        if prog is None:
            prog = self._ctx.program(vertex_shader=_VERTEX, fragment_shader=fragment_source(*key))
            for name, value in (("sun", SUN_DIR), ("ambient", AMBIENT), ("tex", 0), ("detail", 1)):
                if name in prog:
                    prog[name].value = value
            self._programs[key] = prog
        return prog

    def _vao(self, mesh: MeshData, static: bool, key: tuple):
        """The mesh's vertex array for program `key`: its buffers made on first use and rewritten each
        draw unless `static`; one vertex array per program that draws it, on the same buffers."""
        cached = self._static.get(mesh.name)
        shape = (len(mesh.vertices), len(mesh.faces))
        if cached is None or not (static or cached[2] == shape):
            self._rebuffer(mesh, shape)
        elif not static:
            vbo, ibo, _ = cached
            vbo.write(self._vertex_bytes(mesh, shape))
            ibo.write(np.ascontiguousarray(mesh.faces, np.int32).tobytes())
        vao = self._vaos.get((mesh.name, key))
        if vao is None:
            vbo, ibo, _ = self._static[mesh.name]
            vao = self._ctx.vertex_array(self._program(key), [(vbo, "3f 2f 3f", "in_pos", "in_uv", "in_col")],
                                         index_buffer=ibo, index_element_size=4, skip_errors=True)
            self._vaos[(mesh.name, key)] = vao
        return vao

    @staticmethod
    def _vertex_bytes(mesh: MeshData, shape: tuple[int, int]) -> bytes:
        n = shape[0]
        uv = mesh.uv if mesh.uv is not None else np.zeros((n, 2), np.float32)
        col = mesh.colours if mesh.colours is not None else np.ones((n, 3), np.float32)
        return np.hstack([mesh.vertices, uv, col]).astype(np.float32).tobytes()

    def _rebuffer(self, mesh: MeshData, shape: tuple[int, int]) -> None:
        """New buffers for `mesh` (first use, or another size): its vertex arrays are made again."""
        cached = self._static.pop(mesh.name, None)
        for k in [k for k in self._vaos if k[0] == mesh.name]:
            self._vaos.pop(k).release()
        if cached is not None:
            for obj in cached[:2]:
                obj.release()
        faces = np.ascontiguousarray(mesh.faces, np.int32).tobytes()
        self._static[mesh.name] = (self._ctx.buffer(self._vertex_bytes(mesh, shape)), self._ctx.buffer(faces), shape)

    # -- drawing ---------------------------------------------------------------------------
    def draw(self, meshes: list[MeshData], position_m: np.ndarray, ypr_rad: np.ndarray, focal_mm: float,
             sensor: cam.Sensor, static: set[str] | None = None, colour: bool = True
             ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """(BGR uint8 (h, w, 3), depth [m] float32 (h, w), surface uint8 (h, w)) of `meshes` seen by
        the camera; meshes named in `static` keep the vertex buffer of their first draw. `colour`
        False: depth and surface only (the same bytes), no picture (None): no texture is sampled but
        a cut-out's alpha, and nothing is shaded."""
        import moderngl

        ctx = self._context()
        mvp, row = clip_matrix(position_m, ypr_rad, focal_mm, sensor)
        self._fbo.use()
        self._fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        # window y runs down the image (clip_matrix): a face counter-clockwise from outside shows clockwise
        ctx.front_face = "cw"
        static = static or set()
        camera = {"mvp": mvp.T.astype(np.float32).tobytes(), "depth_row": tuple(float(x) for x in row)}
        for mesh in meshes:
            self._draw_one(mesh, mesh.name in static, camera, not colour)
        bgr = None
        if colour:
            bgr = np.empty((self.height, self.width, 3), np.uint8)  # a new array each frame: frames are handed on
            self._fbo.read_into(bgr, components=3, attachment=0, alignment=1)
        depth = np.empty((self.height, self.width), np.float32)  # the sky's draw wrote SKY_DEPTH itself
        self._fbo.read_into(depth, components=1, attachment=1, dtype="f4", alignment=1)
        surface = np.empty((self.height, self.width), np.uint8)
        self._fbo.read_into(surface, components=1, attachment=2, dtype="f1", alignment=1)
        nothing = surface == SURFACE_NONE  # (none where the sky fills the frame: one look, no write)
        if nothing.any():
            depth[nothing] = np.float32(np.inf)
        return bgr, depth, surface

    def _draw_one(self, mesh: MeshData, static: bool, camera: dict, depth_only: bool = False) -> None:
        key = self._program_key(mesh, depth_only)
        p = self._program(key)
        vao = self._vao(mesh, static, key)
        p["mvp"].write(camera["mvp"])
        p["depth_row"].value = camera["depth_row"]
        values = {"detail_period_m": float(mesh.detail_period_m), "detail_gain": float(mesh.detail_gain),
                  "detail_lod_offset": self._detail_lod_offset(mesh),
                  "surface": float(mesh.surface), "fixed_depth": SKY_DEPTH if mesh.sky else 0.0}
        for name, value in values.items():
            if name in p:
                p[name].value = value
        # a closed body's back faces lie behind its front ones: culled, llvmpipe sets up half the triangles
        # (the person: 8.3 -> 5.6 ms CPU a frame, the same pixels but for a handful at its silhouette)
        if mesh.closed:
            self._ctx.enable(self._cull_face)
        else:
            self._ctx.disable(self._cull_face)
        if mesh.texture is not None:
            self._gl_textures[mesh.texture].use(0)
        if mesh.detail is not None and not depth_only:
            self._gl_textures[mesh.detail].use(1)
        vao.render(mode=self._ctx.TRIANGLES)

    def _detail_lod_offset(self, mesh: MeshData) -> float:
        """The detail texture's mip level less the main texture's at every pixel of `mesh`: its coordinates
        are the main ones times `detail_period_m`, so its footprint's area is the main one's times
        period² (sizes in texels aside): a constant per mesh, one derivative and log2 a pixel fewer."""
        if mesh.texture is None or mesh.detail is None:
            return 0.0
        main, detail = self._textures[mesh.texture][0], self._textures[mesh.detail][0]
        ratio = (detail.shape[0] * detail.shape[1]) / (main.shape[0] * main.shape[1])
        return 0.5 * math.log2(max(mesh.detail_period_m ** 2 * ratio, 1e-30))

    def close(self) -> None:
        if self._ctx is not None and self._owner == threading.get_ident():
            self._ctx.release()
        self._ctx = None
