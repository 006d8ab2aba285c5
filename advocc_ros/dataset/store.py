"""The output folder of a data set build: where each problem's files go, what counts as
finished (so a stopped build resumes without redoing it), and the build record.

Layout: ``OUT/<family>/<NNNN>/`` holds ``outcome.json`` (every problem: outcome, reason,
times, provenance), ``hardness.json`` (evaluated problems) and ``m<M>/`` per certified budget M
with the attacked problem in MotionBenchMaker's format (``sceneNNNN.yaml`` with the boxes,
``requestNNNN.yaml``, ``trajectoryNNNN.yaml``: the witness); ``OUT/logs/<family>/<NNNN>.log``
is the problem's log. Every data file is written atomically, ``outcome.json`` last: a problem is
finished exactly when its ``outcome.json`` reads back with a final outcome. ``OUT/build.json``
holds the settings every run shares and one entry per run, appended. JSON is read with ``json``
and YAML with the safe loader; nothing is unpickled.
"""

from __future__ import annotations

import contextlib
import json
import pathlib
from typing import Any, Iterator

from advocc_ros.dataset.job import FINAL_OUTCOMES
from advocc_ros.dataset.problems import DatasetError
from advocc_ros.fileio import atomic_write_text

OUTCOME_FILE = 'outcome.json'
HARDNESS_FILE = 'hardness.json'
BUILD_FILE = 'build.json'
BUILD_FORMAT = 'advocc_dataset_build'
BUILD_VERSION = 2
"""``build.json``: ``{format, version, settings, runs: [one entry per run, oldest first]}``.
Version 1 (one run's entry beside the settings, overwritten by every run) reads as a version 2
record of that one run (``read_build``) and is written back as version 2 by the next run."""
LOG_DIR = 'logs'
LOCK_FILE = '.build.lock'
MAX_RECORD_BYTES = 16 << 20
"""A record file larger than this is not one of ours: it is redone, not parsed."""


def problem_dir(out: pathlib.Path, family: str, name: str) -> pathlib.Path:
    return out / family / name


def write_json(path: pathlib.Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=1, sort_keys=False) + '\n')


def read_json(path: pathlib.Path) -> Any | None:
    """The JSON in ``path``, or None when it is missing, too large or not JSON."""
    try:
        if path.stat().st_size > MAX_RECORD_BYTES:
            return None
        return json.loads(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, ValueError):
        return None


def save_result(out: pathlib.Path, result: dict) -> None:
    """Write one job's result (``job.run_problem``): its log when it came back as text, its
    problem files, its hardness, then its outcome record."""
    from advocc_ros.model.scene import save_yaml_atomic

    record = result['record']
    folder = problem_dir(out, record['family'], record['problem'])
    if result.get('log'):
        append_log(out, record['family'], record['problem'], result['log'])
    for rel, data in result.get('files', {}).items():
        path = (folder / rel).resolve()
        if folder.resolve() not in path.parents:
            raise DatasetError(f'{rel}: a problem file outside its folder')
        save_yaml_atomic(path, data)
    if result.get('hardness') is not None:
        write_json(folder / HARDNESS_FILE, result['hardness'])
    write_json(folder / OUTCOME_FILE, record)


def finished(out: pathlib.Path, family: str, name: str, timeout_s: float | None = None
             ) -> dict | None:
    """The outcome record of a problem that needs no redoing, else None: a final outcome (with
    its hardness file when it has one), or a ``timeout`` under a limit of at least
    ``timeout_s`` (a larger limit gives it another try)."""
    folder = problem_dir(out, family, name)
    record = read_json(folder / OUTCOME_FILE)
    if not isinstance(record, dict):
        return None
    if record.get('outcome') == 'timeout':
        limit = record.get('timeout_s')
        done = isinstance(limit, (int, float)) and (timeout_s is None or limit >= timeout_s)
        return record if done else None
    if record.get('outcome') not in FINAL_OUTCOMES:
        return None
    if record['outcome'] in ('built', 'uncertified') and not isinstance(
            read_json(folder / HARDNESS_FILE), dict):
        return None
    return record


def records(out: pathlib.Path, keys: list[str] | None = None
            ) -> list[tuple[dict, dict | None]]:
    """The (outcome record, hardness or None) of the problems ``keys`` (``family/NNNN``; None:
    every problem under ``out``) that have a record, by family and number."""
    if keys is None:
        paths = sorted(out.glob(f'*/*/{OUTCOME_FILE}'))
    else:
        paths = [out / key / OUTCOME_FILE for key in sorted(keys)]
    found = []
    for path in paths:
        record = read_json(path)
        if isinstance(record, dict) and isinstance(record.get('outcome'), str):
            hardness = read_json(path.parent / HARDNESS_FILE)
            found.append((record, hardness if isinstance(hardness, dict) else None))
    return found


def read_build(out: pathlib.Path) -> dict | None:
    """The build record of ``out`` as version 2 (``BUILD_VERSION``), None when there is none;
    ``DatasetError`` when ``build.json`` is not a build record this tool reads."""
    path = out / BUILD_FILE
    if not path.exists():
        return None
    data = read_json(path)
    if not isinstance(data, dict) or data.get('format') != BUILD_FORMAT \
            or not isinstance(data.get('settings'), dict):
        raise DatasetError(f'{path}: not a build record; choose another --out')
    if data.get('version') == BUILD_VERSION and isinstance(data.get('runs'), list):
        return data
    if data.get('version') == 1:
        return _migrated(data)
    raise DatasetError(f'{path}: build record version {data.get("version")!r}; this tool '
                       f'reads 1 and {BUILD_VERSION}')


def _migrated(old: dict) -> dict:
    """A version 1 record as version 2: its run becomes the first entry. Version 1 named a
    given heatmap by its path; version 2 by its content, read now from that path (when the
    file is gone, the settings keep the path and no resume matches them)."""
    from advocc_ros.dataset.heatmaps import file_sha256

    settings = dict(old['settings'])
    heatmap = settings.get('heatmap')
    if isinstance(heatmap, dict) and set(heatmap) == {'file'} \
            and pathlib.Path(heatmap['file']).is_file():
        settings['heatmap'] = {'sha256': file_sha256(heatmap['file'])}
    run = {k: v for k, v in old.items() if k not in ('format', 'version', 'settings')}
    run['migrated'] = {'from_version': 1, 'settings': old['settings']}
    return {'format': BUILD_FORMAT, 'version': BUILD_VERSION, 'settings': settings,
            'runs': [run]}


def check_settings(out: pathlib.Path, settings: dict) -> dict | None:
    """The build record of ``out`` (``read_build``); ``DatasetError`` when its settings differ
    from ``settings`` (its problems would not be comparable with the new ones). Reads only."""
    previous = read_build(out)
    if previous is None:
        return None
    old = previous['settings']
    if old != settings:
        diff = sorted(k for k in set(settings) | set(old) if old.get(k) != settings.get(k))
        hint = ''
        if 'heatmap' in diff and 'file' in (old.get('heatmap') or {}):
            hint = (f'; its heatmap was given as {old["heatmap"]["file"]}, which is no longer '
                    'there to compare')
        raise DatasetError(f'{out} holds a build with other settings ({", ".join(diff)}){hint};'
                           ' resume it with the same settings or choose another --out')
    return previous


def write_build(out: pathlib.Path, record: dict) -> None:
    write_json(out / BUILD_FILE, record)


def log_path(out: pathlib.Path, family: str, name: str) -> pathlib.Path:
    """The log of one problem: every attempt's output, and the driver's notes."""
    return out / LOG_DIR / family / f'{name}.log'


def append_log(out: pathlib.Path, family: str, name: str, text: str) -> None:
    """Add ``text`` to a problem's log (a log grows; it is never a data file)."""
    path = log_path(out, family, name)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'a', encoding='utf-8') as handle:
        handle.write(text if text.endswith('\n') else text + '\n')


@contextlib.contextmanager
def locked(out: pathlib.Path) -> Iterator[None]:
    """``out`` for one build at a time: an exclusive lock on ``OUT/.build.lock`` while it
    runs; ``DatasetError`` when another build holds it (two runs would each append their entry
    to a ``build.json`` the other rewrites)."""
    import fcntl

    path = out / LOCK_FILE
    with open(path, 'a') as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise DatasetError(f'{out}: another build is running on this folder; wait for it '
                               'or choose another --out') from None
        yield


__all__ = ['BUILD_FILE', 'BUILD_FORMAT', 'BUILD_VERSION', 'HARDNESS_FILE', 'LOCK_FILE', 'LOG_DIR',
           'OUTCOME_FILE', 'append_log', 'check_settings', 'finished', 'locked', 'log_path',
           'problem_dir', 'read_build', 'read_json', 'records', 'save_result', 'write_build',
           'write_json']
