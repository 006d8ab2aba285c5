"""The output folder of a data set build: where each problem's files go, what counts as
finished (so a stopped build resumes without redoing it), and the build record.

Layout: ``OUT/<family>/<NNNN>/`` holds ``outcome.json`` (every problem: outcome, reason,
times), ``hardness.json`` (evaluated problems) and ``m<M>/`` per certified budget M with the
attacked problem in MotionBenchMaker's format (``sceneNNNN.yaml`` with the boxes,
``requestNNNN.yaml``, ``trajectoryNNNN.yaml``: the witness). Every file is written atomically,
``outcome.json`` last: a problem is finished exactly when its ``outcome.json`` reads back with a
final outcome. JSON is read with ``json`` and YAML with the safe loader; nothing is unpickled.
"""

from __future__ import annotations

import json
import pathlib
from typing import Any

from advocc_ros.dataset.job import FINAL_OUTCOMES
from advocc_ros.dataset.problems import DatasetError
from advocc_ros.fileio import atomic_write_text

OUTCOME_FILE = 'outcome.json'
HARDNESS_FILE = 'hardness.json'
BUILD_FILE = 'build.json'
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
    """Write one job's result (``job.run_problem``): its problem files, its hardness, then its
    outcome record."""
    from advocc_ros.model.scene import save_yaml_atomic

    record = result['record']
    folder = problem_dir(out, record['family'], record['problem'])
    for rel, data in result.get('files', {}).items():
        path = (folder / rel).resolve()
        if folder.resolve() not in path.parents:
            raise DatasetError(f'{rel}: a problem file outside its folder')
        save_yaml_atomic(path, data)
    if result.get('hardness') is not None:
        write_json(folder / HARDNESS_FILE, result['hardness'])
    write_json(folder / OUTCOME_FILE, record)


def finished(out: pathlib.Path, family: str, name: str) -> dict | None:
    """The outcome record of a problem that needs no redoing (a final outcome, and its
    hardness file when it has one), else None."""
    folder = problem_dir(out, family, name)
    record = read_json(folder / OUTCOME_FILE)
    if not isinstance(record, dict) or record.get('outcome') not in FINAL_OUTCOMES:
        return None
    if record['outcome'] in ('built', 'uncertified') and not isinstance(
            read_json(folder / HARDNESS_FILE), dict):
        return None
    return record


def records(out: pathlib.Path) -> list[tuple[dict, dict | None]]:
    """Every problem's (outcome record, hardness or None) under ``out``, by family and
    number."""
    found = []
    for path in sorted(out.glob(f'*/*/{OUTCOME_FILE}')):
        record = read_json(path)
        if isinstance(record, dict) and isinstance(record.get('outcome'), str):
            hardness = read_json(path.parent / HARDNESS_FILE)
            found.append((record, hardness if isinstance(hardness, dict) else None))
    return found


def check_settings(out: pathlib.Path, settings: dict) -> dict | None:
    """The previous build record of ``out``; ``DatasetError`` when its settings differ from
    ``settings`` (its problems would not be comparable with the new ones)."""
    previous = read_json(out / BUILD_FILE)
    if previous is None:
        if (out / BUILD_FILE).exists():
            raise DatasetError(f'{out / BUILD_FILE}: not a build record; choose another --out')
        return None
    old = previous.get('settings') if isinstance(previous, dict) else None
    if old != settings:
        diff = sorted(k for k in set(settings) | set(old or {})
                      if (old or {}).get(k) != settings.get(k))
        raise DatasetError(f'{out} holds a build with other settings ({", ".join(diff)}); '
                           'resume it with the same settings or choose another --out')
    return previous


__all__ = ['BUILD_FILE', 'HARDNESS_FILE', 'OUTCOME_FILE', 'check_settings', 'finished',
           'problem_dir', 'read_json', 'records', 'save_result', 'write_json']
