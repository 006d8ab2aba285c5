"""advocc_ros: planner-agnostic adversarial obstacles for tolerance-aware manipulation.

The core (robot, scene, collision, heatmap, attack, planning, metrics, ...) never imports rclpy;
the ROS 2 nodes in ``advocc_ros.nodes`` are thin shells over it.
"""

__version__ = '0.1.0'


def lazy_exports(package: str, modules: dict[str, tuple[str, ...]]):
    """``(__getattr__, __all__)`` for a package that names the public entry points of its
    modules (``{module: names}``) and loads each module on first use of one of its names
    (PEP 562), so importing one light module of the package does not load them all."""
    import importlib
    import sys

    home = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str):
        if name not in home:
            raise AttributeError(f'module {package!r} has no attribute {name!r}')
        value = getattr(importlib.import_module(f'{package}.{home[name]}'), name)
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__, sorted(home)
