"""A self-contained 3D page: meshcat's viewer (three.js) with the scene's drawing commands.

meshcat's Python package ships its browser viewer as one minified file; the page embeds it and
the drawing commands (msgpack, base64) the way meshcat's own static export does, so the page
needs no server and no network. Geometry is in the robot base frame [m] (meshcat is z-up).
"""

from __future__ import annotations

import base64
import html
import json
import pathlib

import numpy as np
import umsgpack
from meshcat import commands, geometry as g
from meshcat.animation import Animation, AnimationClip
from meshcat.path import Path

VIEWER_JS = pathlib.Path(g.__file__).parent / 'viewer' / 'dist' / 'main.min.js'
BACKGROUND_RGB = (255, 255, 255)
"""The viewer's background (uniform, so a test can tell drawn pixels from it)."""
CAMERA_POSITION_M = (1.45, -1.1, 1.0)
"""Default eye point in the base frame."""
TARGET_M = (0.35, 0.0, 0.3)
"""Point the camera looks at and orbits around, in the base frame [m]."""


def rgb_int(rgb) -> int:
    """0xRRGGBB of an (r, g, b) triple in 0..1."""
    r, gr, b = (int(round(255 * float(np.clip(v, 0, 1)))) for v in rgb)
    return (r << 16) | (gr << 8) | b


def _material(rgb, opacity: float = 1.0) -> g.MeshLambertMaterial:
    return g.MeshLambertMaterial(color=rgb_int(rgb), opacity=opacity,
                                 transparent=opacity < 1, depthWrite=opacity >= 1)


class _TextSprite(g.Object):
    """A camera-facing label: a three.js Sprite textured with meshcat's ``_text`` canvas."""

    def __init__(self, text: str, T_base_label: np.ndarray):
        texture = g.GenericTexture({'type': '_text', 'text': text, 'font_size': 160,
                                    'font_face': 'sans-serif'})
        super().__init__(None, g.GenericMaterial(map=texture, transparent=True,
                                                 depthTest=False))
        self.material._type = 'SpriteMaterial'
        self.T = T_base_label

    def lower(self):
        data = {'metadata': {'version': 4.5, 'type': 'Object'}, 'geometries': [],
                'materials': [], 'textures': [],
                'object': {'uuid': self.uuid, 'type': 'Sprite', 'material': self.material.uuid,
                           'matrix': [float(v) for v in self.T.T.flatten()],
                           'renderOrder': 10}}
        self.material.lower_in_object(data)
        return data


class ViewBuilder:
    """Drawing commands of one page, in the order the viewer applies them."""

    def __init__(self):
        self._commands: list[dict] = []
        self._animation = Animation(default_framerate=30)
        self._set('/Background', 'visible', False)  # the page's white shows through
        self._set('/Grid', 'visible', False)
        self._set('/Axes', 'visible', True)
        x, y, z = CAMERA_POSITION_M
        # The camera node is three.js's y-up frame: (x, y, z) in the base frame is (x, z, -y).
        self._set('/Cameras/default/rotated/<object>', 'position', [x, z, -y])

    def _set(self, path: str, key: str, value) -> None:
        self._commands.append(commands.SetProperty(key, value, Path(tuple(
            p for p in path.split('/') if p))).lower())

    def _object(self, path: str, obj) -> None:
        self._commands.append(commands.SetObject(obj, path=_path(path)).lower())

    def mesh(self, path: str, vertices_m, faces, rgb, opacity: float = 1.0,
             T_base_mesh: np.ndarray | None = None) -> None:
        """A triangle mesh (vertices in its own frame, placed by ``T_base_mesh``)."""
        geom = g.TriangularMeshGeometry(np.asarray(vertices_m, np.float32),
                                        np.asarray(faces, np.uint32))
        self._object(path, g.Mesh(geom, _material(rgb, opacity)))
        if T_base_mesh is not None:
            self.transform(path, T_base_mesh)

    def points(self, path: str, points_m, colors_rgb, size_m: float) -> None:
        """Points of edge ``size_m`` [m], coloured per point ((N, 3) in 0..1)."""
        pts = np.asarray(points_m, np.float32).reshape(-1, 3).T
        cols = np.asarray(colors_rgb, np.float32).reshape(-1, 3).T
        self._object(path, g.Points(g.PointsGeometry(pts, cols),
                                    g.PointsMaterial(size=float(size_m))))

    def label(self, path: str, text: str, position_m, size_m: float = 0.09) -> None:
        """Text that always faces the camera, centred at ``position_m``."""
        T = np.diag([size_m, size_m, size_m, 1.0])
        T[:3, 3] = np.asarray(position_m, float)
        self._object(path, _TextSprite(text, T))

    def transform(self, path: str, T_base_node: np.ndarray) -> None:
        self._commands.append(commands.SetTransform(np.asarray(T_base_node, float),
                                                    _path(path)).lower())

    def keyframes(self, path: str, T_base_node_frames: list[np.ndarray], fps: int = 30) -> None:
        """Animate the node at ``path`` through one transform per frame (looped)."""
        from meshcat.animation import js_position, js_quaternion

        clip = AnimationClip(fps=fps)
        for frame, T in enumerate(T_base_node_frames):
            clip.set_property(frame, 'position', 'vector3', [float(v) for v in js_position(T)])
            clip.set_property(frame, 'quaternion', 'quaternion',
                              [float(v) for v in js_quaternion(T)])
        self._animation.clips[_path(path)] = clip

    def commands(self) -> list[dict]:
        """Every command, the animation (when any) last."""
        out = list(self._commands)
        if self._animation.clips:
            out.append(commands.SetAnimation(self._animation, play=True,
                                             repetitions=100000).lower())
        return out


def _path(path: str) -> Path:
    return Path(tuple(p for p in path.split('/') if p))


PAGE_CSS = """
body { margin: 0; font: 13px/1.4 sans-serif; display: flex; height: 100vh; }
#side { width: 340px; overflow-y: auto; padding: 10px 14px; box-sizing: border-box;
        border-right: 1px solid #ccc; background: #fafafa; }
#meshcat-pane { flex: 1; background: #fff; position: relative; overflow: hidden; }
h1 { font-size: 16px; margin: 4px 0 8px; } h2 { font-size: 14px; margin: 12px 0 4px; }
.sw { display: inline-block; width: 12px; height: 12px; margin-right: 6px;
      vertical-align: middle; border: 1px solid #888; }
pre { white-space: pre-wrap; font-size: 12px; background: #fff; padding: 6px;
      border: 1px solid #ddd; }
img { max-width: 100%; } table { border-collapse: collapse; font-size: 12px; }
td, th { border: 1px solid #ddd; padding: 1px 4px; text-align: right; }
"""

PAGE_SCRIPT = """
(function () {
  var status = document.getElementById('view-status');
  try {
    var viewer = new MeshCat.Viewer(document.getElementById('meshcat-pane'));
    var blobs = JSON.parse(document.getElementById('view-commands').textContent);
    blobs.forEach(function (b64) {
      var raw = atob(b64), bytes = new Uint8Array(raw.length);
      for (var i = 0; i < raw.length; i++) { bytes[i] = raw.charCodeAt(i); }
      viewer.handle_command_bytearray(bytes);
    });
    var t = TARGET_M;  // three.js is y-up: base-frame (x, y, z) is (x, z, -y)
    viewer.controls.target.set(t[0], t[2], -t[1]);
    viewer.controls.update();
    viewer.set_dirty();
    window.advoccViewer = viewer;
    // Marked as soon as the commands ran, not after a frame: how soon a headless browser
    // renders a frame depends on the machine's load, what the commands did does not.
    document.body.setAttribute('data-drawn', String(blobs.length));
    status.textContent = blobs.length + ' drawing commands applied';
  } catch (err) {
    document.body.setAttribute('data-error', String(err));
    status.textContent = 'viewer error: ' + err;
  }
})();
"""


def legend_html(entries: list[tuple[str, tuple[float, float, float]]]) -> str:
    """Colour swatches with their meaning."""
    rows = [f'<div><span class="sw" style="background:#{rgb_int(rgb):06x}"></span>'
            f'{html.escape(text)}</div>' for text, rgb in entries]
    return '\n'.join(rows)


def page_html(title: str, side_html: str, drawing: list[dict]) -> str:
    """The whole page: side panel (trusted HTML), the viewer and its commands, all inline."""
    blobs = [base64.b64encode(umsgpack.packb(cmd)).decode('ascii') for cmd in drawing]
    # JSON of base64 strings has no '<', so it cannot close the script element.
    return '\n'.join([
        '<!DOCTYPE html>', '<html><head><meta charset="utf-8">',
        f'<title>{html.escape(title)}</title>', f'<style>{PAGE_CSS}</style></head>',
        '<body>', f'<div id="side"><h1>{html.escape(title)}</h1>', side_html,
        '<p id="view-status">loading the viewer...</p></div>',
        '<div id="meshcat-pane"></div>',
        f'<script id="view-commands" type="application/json">{json.dumps(blobs)}</script>',
        f'<script>{VIEWER_JS.read_text()}</script>',
        '<script>' + PAGE_SCRIPT.replace('TARGET_M', json.dumps(TARGET_M)) + '</script>',
        '</body></html>', ''])


def png_data_uri(path: str | pathlib.Path) -> str:
    """An image file as a ``data:`` URI (the page must not reference other files)."""
    return 'data:image/png;base64,' + base64.b64encode(pathlib.Path(path).read_bytes()).decode()
