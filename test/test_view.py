"""The 3D page: ``advocc audit`` writes ``audit.html``; headless Chromium draws it offline.

The browser tests need Debian's ``chromium`` (``.ci/run`` installs it); without it they are
skipped with the reason. ``ADVOCC_VIEW_SCREENSHOT=FILE`` copies the audit page's screenshot to
FILE (the README's picture is made this way).
"""

import json
import os
import pathlib
import re
import shutil
import subprocess

import numpy as np
import pytest
import yaml

from advocc_ros.cli import main as advocc
from conftest import CHROMIUM, needs_chromium

WINDOW = (1200, 800)
SIDE_PX = 340
"""Width of the page's side panel: the viewer is to its right."""


def _chromium(page: pathlib.Path, *flags: str, window=WINDOW, budget_ms: int = 10000) -> str:
    """Run headless Chromium (WebGL through SwiftShader) on ``page`` for ``budget_ms`` of
    virtual time; returns its stdout. Host names resolve to nothing, so a remote request fails
    fast instead of reaching the network."""
    cmd = [CHROMIUM, '--headless', '--no-sandbox', '--use-angle=swiftshader',
           '--enable-unsafe-swiftshader', '--disable-background-networking',
           '--disable-component-update', '--disable-sync', '--no-first-run',
           '--host-resolver-rules=MAP * ~NOTFOUND', f'--window-size={window[0]},{window[1]}',
           f'--virtual-time-budget={budget_ms}', *flags, page.resolve().as_uri()]
    return subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=120).stdout


def chromium_screenshot(page: pathlib.Path, png: pathlib.Path, netlog: pathlib.Path,
                        window=WINDOW, budget_ms: int = 10000) -> None:
    """Screenshot ``page`` and log every network request to ``netlog``."""
    _chromium(page, f'--screenshot={png}', f'--log-net-log={netlog}', window=window,
              budget_ms=budget_ms)
    assert png.is_file(), f'chromium wrote no screenshot of {page}'


def page_requests(netlog: pathlib.Path) -> list[str]:
    """URLs the page (not the browser's own services) requested that are not in the page:
    every URL request an origin initiated, less ``file:`` and ``data:``."""
    data = json.loads(netlog.read_text())
    start = data['constants']['logEventTypes']['URL_REQUEST_START_JOB']
    jobs = [e.get('params', {}) for e in data['events'] if e['type'] == start]
    return [p['url'] for p in jobs if 'url' in p and p.get('initiator') != 'not an origin'
            and not p['url'].startswith(('file:', 'data:'))]


def remote_references(page_html: str) -> list[str]:
    """``src``/``href``/``url(...)`` values of the HTML that point off the page."""
    refs = re.findall(r'''(?:src|href)\s*=\s*["']?\s*((?:https?:|wss?:)?//[^"'\s>]+)''',
                      page_html, re.I)
    return refs + re.findall(r'url\(\s*["\']?((?:https?:)?//[^)"\']+)', page_html, re.I)


def drawn_fraction(png: pathlib.Path, box) -> float:
    """Fraction of the pixels in ``box`` (x0, y0, x1, y1) that differ from the white
    background by more than 40 in some channel."""
    import matplotlib.image

    rgb = (matplotlib.image.imread(png)[..., :3] * 255).astype(int)
    x0, y0, x1, y1 = box
    region = rgb[y0:y1, x0:x1]
    return float((np.abs(region - 255).max(axis=2) > 40).mean())


def test_blank_and_remote_detectors_can_fail(tmp_path):
    import matplotlib.image

    white = np.ones((100, 200, 3))
    matplotlib.image.imsave(tmp_path / 'white.png', white)
    assert drawn_fraction(tmp_path / 'white.png', (0, 0, 200, 100)) == 0.0
    white[20:60, 50:150] = (0.9, 0.1, 0.1)
    matplotlib.image.imsave(tmp_path / 'box.png', white)
    assert drawn_fraction(tmp_path / 'box.png', (0, 0, 200, 100)) == pytest.approx(0.2)
    assert remote_references('<script src="https://cdn.example/x.js"></script>'
                             '<link href=//cdn.example/a.css><div style="a: url(http://x/y)">'
                             ) == ['https://cdn.example/x.js', '//cdn.example/a.css', 'http://x/y']
    assert remote_references('<a href="#top"><img src="data:image/png;base64,AA">') == []


@pytest.mark.processes
def test_remote_request_seen_in_chromium(tmp_path):
    """The request log catches a page that loads from the network (the check can fail)."""
    needs_chromium()
    page = tmp_path / 'remote.html'
    page.write_text('<html><body><img src="https://example.invalid/a.png">'
                    '<script src="http://example.invalid/b.js"></script>x</body></html>')
    chromium_screenshot(page, tmp_path / 'r.png', tmp_path / 'net.json', (400, 300), 2000)
    assert sorted(page_requests(tmp_path / 'net.json')) == [
        'http://example.invalid/b.js', 'https://example.invalid/a.png']


@pytest.fixture(scope='module')
def audit_dir(tmp_path_factory, table_scene):
    """A small real audit of table_pick through the CLI (its audit.html included)."""
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, save_heatmap

    out = tmp_path_factory.mktemp('audit')
    heatmap = build_heatmap(table_scene, HeatmapConfig(samples=2000), seed=0, workers=1)
    save_heatmap(heatmap, out / 'heatmap_table_pick.npz')
    assert advocc(['audit', '--scene', 'table_pick', '--planners', 'rrtconnect',
                   '--max-budget', '2', '--trials', '1', '--time', '1', '--workers', '1',
                   '--out', str(out), '--bag', str(out / 'audit.mcap')]) == 0
    return out


@pytest.mark.processes
def test_audit_writes_a_self_contained_page(audit_dir):
    from advocc_ros.audit.report import audit_answer

    page = (audit_dir / 'audit.html').read_text()
    audit = json.loads((audit_dir / 'audit.json').read_text())
    assert audit_answer(audit).splitlines()[0] in page
    assert 'src="data:image/png;base64,' in page          # the PSR figure, embedded
    assert 'MeshCat.Viewer' in page and len(page) > 500_000  # the viewer, embedded
    assert remote_references(page) == []
    for box in audit['boxes']:
        assert f'<td>{box["pick"]}</td><td>{box["id"]}</td>' in page


@pytest.mark.processes
def test_audit_bag_holds_the_audit_boxes(audit_dir):
    from advocc_msgs.msg import CollisionObject
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    with open(audit_dir / 'audit.mcap', 'rb') as stream:
        records = [(c.topic, m.data) for _, c, m in make_reader(stream).iter_messages()]
    boxes = [deserialize_message(data, CollisionObject) for topic, data in records
             if topic == '/advocc/collision_object']
    audit = json.loads((audit_dir / 'audit.json').read_text())
    assert [b.id for b in boxes] == [b['id'] for b in audit['boxes']]
    for got, want in zip(boxes, audit['boxes']):
        p = got.primitive_poses[0].position
        assert [p.x, p.y, p.z] == want['center_m']
    assert [t for t, _ in records][-1] == '/heatmap_server/heatmap'


@pytest.mark.processes
def test_audit_page_draws_offline_in_chromium(audit_dir, tmp_path):
    needs_chromium()
    png, netlog = tmp_path / 'audit.png', tmp_path / 'net.json'
    chromium_screenshot(audit_dir / 'audit.html', png, netlog)
    assert page_requests(netlog) == []
    width, height = WINDOW
    # The scene (table, robot, boxes) fills the middle of the viewer; its corners stay empty.
    middle = (SIDE_PX + (width - SIDE_PX) // 4, height // 4,
              SIDE_PX + 3 * (width - SIDE_PX) // 4, 3 * height // 4)
    assert drawn_fraction(png, middle) > 0.15, f'the viewer looks blank: {png}'
    assert drawn_fraction(png, (width - 150, height - 100, width, height)) < 0.02
    # The page script marks the body as soon as every drawing command ran (an error is marked
    # too), not after a rendered frame: on a loaded 2-core machine SwiftShader's frames once
    # took longer than 30 s of virtual time, and the unmarked body failed CI.
    dom = _chromium(audit_dir / 'audit.html', '--dump-dom', budget_ms=30000)
    commands = json.loads(re.search(r'<script id="view-commands" type="application/json">'
                                    r'(.*?)</script>', (audit_dir / 'audit.html').read_text(),
                                    re.S).group(1))
    body = re.search(r'<body[^>]*>', dom).group(0)
    assert body == f'<body data-drawn="{len(commands)}">', body
    target = os.environ.get('ADVOCC_VIEW_SCREENSHOT')
    if target:
        shutil.copyfile(png, target)


def test_view_command_with_obstacles_and_witness(tmp_path, table_scene, panda):
    """``advocc view`` reads an obstacles file and the witness beside it; bad input is a
    one-line error."""
    from advocc_ros.attack import obstacles_file_data, save_obstacles
    from advocc_ros.model.scene import make_box

    boxes = [make_box('adv_0', (0.5, 0.0, 0.5), (0.05,) * 3),
             make_box('adv_1', (0.3, 0.2, 0.6), (0.05,) * 3)]
    obstacles = tmp_path / 'obs.yaml'
    save_obstacles(obstacles, obstacles_file_data(boxes, 'task', 2))
    from advocc_ros.planning.witness import Witness, save_witness, witness_file

    q0 = np.array([table_scene.start[j] for j in panda.joint_names])
    save_witness(witness_file(obstacles), Witness(panda.joint_names, np.array([q0, q0 + 0.3]),
                                                  dict(panda.locked_values)))
    out = tmp_path / 'view.html'
    assert advocc(['view', '--scene', 'table_pick', '--obstacles', str(obstacles),
                   '--planner', 'none', '--out', str(out)]) == 0
    page = out.read_text()
    assert 'witness path (animated): 2 waypoints' in page
    assert '<td>2</td><td>adv_1</td><td>+0.300, +0.200, +0.600</td>' in page

    (tmp_path / 'obs.witness.yaml').write_text(yaml.safe_dump({
        'joint_names': list(panda.joint_names), 'waypoints': [[0.1]]}))
    assert advocc(['view', '--scene', 'table_pick', '--obstacles', str(obstacles),
                   '--out', str(out)]) == 2
    assert advocc(['view', '--scene', 'table_pick', '--heatmap', str(tmp_path / 'none.npz'),
                   '--out', str(out)]) == 2
