"""Node parameters declared with descriptors (the ros2/demos way).

Each parameter carries its description, whether it is read at start-up only (``read_only``)
and its closed range, so rclpy itself refuses a bad ``ros2 param set`` with a reason naming
the range, and ``ros2 param describe`` shows all of it. What a descriptor cannot say (a choice
among names, a bound another parameter sets, an open interval) stays with the core's own
config checks, which the nodes call from their on-set callbacks.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

INT_MAX = 2 ** 63 - 1
"""Upper end of an integer range that has none (ROS 2 integers are 64-bit)."""


@dataclasses.dataclass(frozen=True)
class Param:
    """One node parameter: name, default, and what its descriptor says."""

    name: str
    default: Any
    description: str
    read_only: bool = False
    """Read at start-up only: rclpy refuses later sets."""
    low: float | None = None
    high: float | None = None
    """Closed range ``[low, high]`` of a number (both or neither)."""
    constraints: str = ''
    """Constraints in words (``additional_constraints``) that a range cannot express."""

    def __post_init__(self):
        if (self.low is None) != (self.high is None):
            raise ValueError(f'parameter {self.name}: give both ends of the range or neither')

    def descriptor(self) -> ParameterDescriptor:
        desc = ParameterDescriptor(description=self.description, read_only=self.read_only,
                                   additional_constraints=self.constraints)
        if self.low is None:
            return desc
        if isinstance(self.default, bool) or not isinstance(self.default, (int, float)):
            raise ValueError(f'parameter {self.name}: a range needs a numeric default')
        if isinstance(self.default, int):
            desc.integer_range = [IntegerRange(from_value=int(self.low),
                                               to_value=int(min(self.high, INT_MAX)), step=0)]
        else:
            desc.floating_point_range = [FloatingPointRange(from_value=float(self.low),
                                                            to_value=float(self.high), step=0.0)]
        return desc


def declare(node, params) -> None:
    """Declare every ``Param`` of ``params`` on ``node`` with its descriptor."""
    for p in params:
        node.declare_parameter(p.name, p.default, p.descriptor())


def defaults(params) -> dict[str, Any]:
    """``{name: default}`` of ``params`` (what ``config/<node>.yaml`` must say)."""
    return {p.name: p.default for p in params}


__all__ = ['INT_MAX', 'Param', 'declare', 'defaults']
