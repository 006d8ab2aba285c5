"""Where shipped configuration lives, for a source checkout and for an installed package."""

import pathlib


def config_dir() -> pathlib.Path:
    """The checkout's ``config/``, else ``share/advocc_ros/config`` of the prefix this module is
    installed in (``<prefix>/lib/pythonX.Y/site-packages/advocc_ros``): a colcon install space,
    a venv or a ``--user`` site, which need not be ``sys.prefix``."""
    here = pathlib.Path(__file__).resolve()
    source = here.parents[1] / 'config'
    if source.is_dir():
        return source
    return here.parents[4] / 'share' / 'advocc_ros' / 'config'


def scene_path(name_or_path: str) -> pathlib.Path:
    """A scene file path; a bare name like ``table_pick`` means
    ``config/scenes/table_pick.yaml``."""
    path = pathlib.Path(name_or_path)
    if path.suffix or path.exists():
        return path
    return config_dir() / 'scenes' / f'{name_or_path}.yaml'


class PathError(ValueError):
    """A file path outside the directories a node may read."""


def default_allowed_dirs() -> list[pathlib.Path]:
    """Where nodes may read files when ``allowed_dirs`` is not set: the shipped config, the
    working directory (outputs such as ``out/`` live there), ``$ADVOCC_OUT`` if set, and the
    system temporary directory (tests and the orchestrator's scratch runs)."""
    import os
    import tempfile
    dirs = [config_dir(), pathlib.Path.cwd(), pathlib.Path(tempfile.gettempdir())]
    if os.environ.get('ADVOCC_OUT'):
        dirs.append(pathlib.Path(os.environ['ADVOCC_OUT']))
    return [d.resolve() for d in dirs]


def allowed_dirs(values: list[str] | None) -> list[pathlib.Path]:
    """``values`` (a node's ``allowed_dirs`` parameter) resolved, or the defaults if empty."""
    dirs = [pathlib.Path(v).expanduser().resolve() for v in values or [] if v]
    return dirs or default_allowed_dirs()


def confine(path: str | pathlib.Path, dirs: list[pathlib.Path], what: str) -> pathlib.Path:
    """``path`` resolved (symlinks and ``..`` followed); ``PathError`` unless it lies inside
    one of ``dirs``."""
    resolved = pathlib.Path(path).expanduser().resolve()
    if not any(resolved.is_relative_to(d) for d in dirs):
        raise PathError(f'{what} {str(path)!r} (resolves to {resolved}) is outside the allowed '
                        f'directories {[str(d) for d in dirs]}; set the allowed_dirs parameter')
    return resolved
