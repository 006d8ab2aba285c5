"""SIGKILL in the middle of writing a heatmap, obstacles, JSON or results file: nothing is lost.

Real processes run our real writers and are killed while a write is under way (the heatmap
build is killed while its temporary file beside the target exists); afterwards the previous
file must still load, bit for bit, or be the complete new one. For append-only JSON lines
(``bench.RecordStore``) every record must be whole and present once.
"""

import json
import os
import pathlib
import queue
import random
import signal
import subprocess
import sys
import threading
import time

import pytest

from conftest import REPO

pytestmark = pytest.mark.processes  # nodes, workers or CLI runs

ENV = dict(os.environ, PYTHONUNBUFFERED='1',
           PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get('PYTHONPATH')])))


def _kill(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait(10)


def test_heatmap_build_killed_mid_write_keeps_the_old_file(tmp_path, table_scene):
    from advocc_ros.heatmap import HeatmapConfig, build_heatmap, load_heatmap, save_heatmap
    out = tmp_path / 'existing.npz'
    save_heatmap(build_heatmap(table_scene, HeatmapConfig(samples=30, voxel_m=0.05), seed=1), out)
    old = out.read_bytes()
    killed_mid_write = 0
    for attempt in range(2):
        proc = subprocess.Popen(
            [sys.executable, '-m', 'advocc_ros.cli', 'heatmap', 'build', '--scene', 'table_pick',
             '--samples', '200', '--seed', str(attempt), '--out', str(out)],
            env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 120
            while proc.poll() is None and time.monotonic() < deadline:
                tmp = list(tmp_path.glob('.existing.npz.*.tmp'))
                if tmp:  # the writer is inside atomic_open: kill it now
                    time.sleep(random.Random(attempt).uniform(0, 0.01))
                    size = tmp[0].stat().st_size if tmp[0].exists() else -1
                    proc.send_signal(signal.SIGKILL)
                    proc.wait(10)
                    killed_mid_write += proc.returncode == -signal.SIGKILL
                    print(f'attempt {attempt}: killed with {size} bytes of the new file written')
                    break
                time.sleep(0.0005)
        finally:
            _kill(proc)
        assert out.read_bytes() == old, 'the previous heatmap was modified'
        assert load_heatmap(out).meta['seeds'] == ['1']
    assert killed_mid_write >= 1, 'never caught the writer mid-write'
    # Stale temporary files are the only trace; a later build replaces the file cleanly.
    save_heatmap(load_heatmap(out), out)
    assert load_heatmap(out).meta['seeds'] == ['1']


_WRITER = r'''
import sys
from advocc_ros.attack import AttackResult, AttackStatus, obstacles_data, save_obstacles
from advocc_ros.fileio import atomic_write_text
from advocc_ros.model.scene import make_box
out, js = sys.argv[1], sys.argv[2]
docs = []
for tag in range(2):
    boxes = tuple(make_box(f'adv_{i}', (0.5, 0.001 * i, 0.3 + tag), (0.05,) * 3)
                  for i in range(1000))
    docs.append(obstacles_data(AttackResult(AttackStatus.SUCCESS, f'version {tag}', boxes,
                                            (1.0,) * 1000, 1000.0, 0.01, 'ours', 1000, 0.05)))
texts = ['{"version": %d, "pad": "%s"}\n' % (t, 'x' * 2_000_000) for t in range(2)]
print('ready', flush=True)
k = 0
while True:
    save_obstacles(out, docs[k % 2])
    atomic_write_text(js, texts[k % 2])
    k += 1
    if k == 1:
        print('wrote', flush=True)
'''


def _lines(proc) -> queue.Queue:
    """The lines ``proc`` prints, as they come (a thread reads them)."""
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line.strip()) for line in proc.stdout],
                     daemon=True).start()
    return lines


def _next(lines: queue.Queue, timeout_s: float) -> str:
    try:
        return lines.get(timeout=timeout_s)
    except queue.Empty:
        return f'(nothing in {timeout_s:g} s)'


def test_obstacles_and_json_writers_killed_at_random(tmp_path):
    """Killed at a random moment after its first complete pass (however long a pass takes on
    this machine), the writer leaves each file whole: one version or the other."""
    from advocc_ros.attack import load_obstacles
    out, js = tmp_path / 'obstacles.yaml', tmp_path / 'summary.json'
    rng = random.Random(7)
    versions = set()
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, '-c', _WRITER, str(out), str(js)], env=ENV,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            lines = _lines(proc)
            assert _next(lines, 120) == 'ready', f'writer exit code {proc.poll()}'
            assert _next(lines, 120) == 'wrote', f'writer exit code {proc.poll()}'
            time.sleep(rng.uniform(0.0, 0.6))
        finally:
            _kill(proc)
        if out.exists():
            objects, meta = load_obstacles(out)
            assert len(objects) == 1000 and meta['message'] in ('version 0', 'version 1')
            versions.add(meta['message'])
        if js.exists():
            assert json.loads(js.read_text())['version'] in (0, 1)
    assert versions, 'the writer never finished one file'


_APPENDER = r'''
import sys
from advocc_ros.bench import RecordStore
store = RecordStore(sys.argv[1])
k = len(store)
print('ready', k, flush=True)
while True:
    store.append({'key': f'trial-{k}', 'k': k, 'pad': 'y' * 50_000})
    k += 1
'''


def test_records_jsonl_killed_mid_append(tmp_path):
    """Every kill leaves whole records 0..n-1, each once; the next writer resumes at n."""
    from advocc_ros import bench

    path = tmp_path / 'records.jsonl'
    rng = random.Random(3)
    previous = 0
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, '-c', _APPENDER, str(path)], env=ENV,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            line = proc.stdout.readline().split()
            assert line[:1] == ['ready'], proc.stderr.read()
            assert int(line[1]) == previous  # resumed where the last writer stopped
            time.sleep(rng.uniform(0.1, 0.4))
        finally:
            _kill(proc)
        store = bench.RecordStore(path)
        keys = sorted(rec['k'] for rec in store.records.values())
        assert keys == list(range(len(keys))) and store.duplicates == 0
        assert store.bad_lines == 0
        assert len(keys) >= previous
        previous = len(keys)
    assert previous > 0
    assert pathlib.Path(path).read_bytes().endswith(b'\n')
