"""Where shipped configuration lives, for a source checkout and for an installed package."""

import pathlib
import sys


def config_dir() -> pathlib.Path:
    source = pathlib.Path(__file__).resolve().parents[1] / 'config'
    if source.is_dir():
        return source
    return pathlib.Path(sys.prefix) / 'share' / 'advocc_ros' / 'config'


def scene_path(name_or_path: str) -> pathlib.Path:
    """A scene file path; a bare name like ``table_pick`` means ``config/scenes/table_pick.yaml``."""
    path = pathlib.Path(name_or_path)
    if path.suffix or path.exists():
        return path
    return config_dir() / 'scenes' / f'{name_or_path}.yaml'
