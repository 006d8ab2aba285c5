"""Disabled collision pairs for an SRDF, found the way MoveIt's Setup Assistant finds them.

The Setup Assistant (``moveit_setup_srdf_plugins``, ``compute_default_collisions``) disables
self-collision checks between two links with collision geometry when they are

1. ``Adjacent``: parent and child in the kinematic tree; a link without collision geometry joins
   its neighbours to each other (so a hand on a geometry-less flange is adjacent to the wrist);
2. ``Default``: in collision in the default state (each joint at 0, or mid-range when 0 is
   outside its limits);
3. ``Always``: in collision in at least ``always_fraction`` of ``samples`` random states;
4. ``Never``: in collision in none of the ``samples`` random states,

in that order (a pair gets the first reason that applies). Random states are uniform within the
joint limits, continuous joints uniform in [-pi, pi), every joint of the URDF moving. The
resulting ``<disable_collisions>`` elements are what pinocchio's ``removeCollisionPairs`` (and
MoveIt) read. No ROS.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import pathlib
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from advocc_ros.model.coal_state import exact_boxes

exact_boxes()  # its sampled collisions are queried on geometry it builds itself

REASONS = ('Adjacent', 'Default', 'Always', 'Never')


@dataclasses.dataclass(frozen=True)
class DisabledPair:
    """One ``<disable_collisions link1 link2 reason>`` element (``link1 < link2``)."""

    link1: str
    link2: str
    reason: str


@dataclasses.dataclass(frozen=True)
class CollisionPairsResult:
    """What :func:`disabled_collision_pairs` found."""

    disabled: tuple[DisabledPair, ...]
    links: tuple[str, ...]
    """Links with collision geometry."""
    enabled: tuple[tuple[str, str], ...]
    """Pairs left checked (in collision in some, not almost all, samples)."""
    samples: int
    q_default: np.ndarray
    """The default state (pinocchio configuration, (nq,))."""


def _link_graph(urdf_root: ET.Element, has_geometry: set[str]) -> set[frozenset]:
    """Adjacent link pairs: URDF joints' parent/child, geometry-less links bridged."""
    edges: dict[str, set[str]] = {}
    for joint in urdf_root.iter('joint'):
        parent, child = joint.find('parent'), joint.find('child')
        if parent is None or child is None:
            continue
        a, b = parent.get('link'), child.get('link')
        edges.setdefault(a, set()).add(b)
        edges.setdefault(b, set()).add(a)
    changed = True
    while changed:  # a link without geometry connects all its neighbours to each other
        changed = False
        for link, neighbours in list(edges.items()):
            if link in has_geometry:
                continue
            for a, b in itertools.combinations(sorted(neighbours), 2):
                if b not in edges[a]:
                    edges[a].add(b)
                    edges[b].add(a)
                    changed = True
    return {frozenset((a, b)) for a, ns in edges.items() for b in ns
            if a in has_geometry and b in has_geometry and a != b}


def default_configuration(model: pin.Model) -> np.ndarray:
    """MoveIt's default state: 0 for each joint, or mid-range when 0 is outside the limits."""
    q = pin.neutral(model)
    for joint in model.joints[1:]:
        if joint.nq != 1:  # continuous joints (cos, sin): neutral is angle 0
            continue
        lo, hi = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
        if not lo <= 0.0 <= hi and np.isfinite(lo) and np.isfinite(hi):
            q[joint.idx_q] = 0.5 * (lo + hi)
    return q


def random_configurations(model: pin.Model, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, nq) states uniform within the limits; continuous joints uniform in [-pi, pi)."""
    Q = np.tile(pin.neutral(model), (n, 1))
    for joint in model.joints[1:]:
        i = joint.idx_q
        if joint.nq == 1:
            lo, hi = model.lowerPositionLimit[i], model.upperPositionLimit[i]
            lo = lo if np.isfinite(lo) else -math.pi
            hi = hi if np.isfinite(hi) else math.pi
            Q[:, i] = rng.uniform(lo, hi, n)
        elif joint.nq == 2:
            angle = rng.uniform(-math.pi, math.pi, n)
            Q[:, i], Q[:, i + 1] = np.cos(angle), np.sin(angle)
    return Q


def _link_of(model: pin.Model, geom: pin.GeometryObject) -> str:
    return model.frames[geom.parentFrame].name


def disabled_collision_pairs(urdf: str | pathlib.Path, package_dirs: list[str] = (),
                             samples: int = 10000, seed: int = 0, always_fraction: float = 0.95,
                             threads: int = 1) -> CollisionPairsResult:
    """The Setup Assistant's disabled pairs of a URDF (see the module doc).

    Per-pair counts need each state's per-pair results, so the states are checked one at a
    time (``computeCollisionsInParallel`` over the pairs with ``threads`` > 1). A pair stops
    being checked once its fate is sealed: after it has both collided and missed more than
    ``1 - always_fraction`` of all samples (neither Never nor Always any more).
    """
    urdf = pathlib.Path(urdf)
    model = pin.buildModelFromUrdf(str(urdf))
    gmodel = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION,
                                   package_dirs=list(package_dirs))
    links_of_geom = [_link_of(model, g) for g in gmodel.geometryObjects]
    links = tuple(sorted(set(links_of_geom)))
    adjacent = _link_graph(ET.parse(urdf).getroot(), set(links))
    pairs = _LinkPairs(model, gmodel, links_of_geom, threads)
    reasons: dict[frozenset, str] = {p: 'Adjacent' for p in pairs.by_link if p in adjacent}
    q_default = default_configuration(model)
    pending = [p for p in pairs.by_link if p not in reasons]
    pairs.activate(pending)
    for p, hit in pairs.colliding(q_default, pending).items():
        if hit:
            reasons[p] = 'Default'
    pending = [p for p in pending if p not in reasons]
    Q = random_configurations(model, samples, np.random.default_rng(seed))
    counts = _collision_counts(pairs, pending, Q, (1.0 - always_fraction) * samples)
    for p in pending:
        if counts[p] >= always_fraction * samples:
            reasons[p] = 'Always'
        elif counts[p] == 0:
            reasons[p] = 'Never'
    order = {r: k for k, r in enumerate(REASONS)}
    disabled = tuple(sorted((DisabledPair(*sorted(p), r) for p, r in reasons.items()),
                            key=lambda d: (order[d.reason], d.link1, d.link2)))
    enabled = tuple(sorted(tuple(sorted(p)) for p in pairs.by_link if p not in reasons))
    return CollisionPairsResult(disabled, links, enabled, samples, q_default)


class _LinkPairs:
    """Every pair of geometries of two different links of a model, checked per link pair.

    Links on one joint are included (``addAllCollisionPairs`` skips them: the Setup Assistant
    lists them too, as Adjacent/Default/Never); two links may have several geometries each.
    """

    def __init__(self, model: pin.Model, gmodel: pin.GeometryModel, links_of_geom: list[str],
                 threads: int):
        self.model, self.gmodel, self.threads = model, gmodel, threads
        self.by_link: dict[frozenset, list[int]] = {}
        """Link pair -> indices of its geometry pairs."""
        for i, j in itertools.combinations(range(len(links_of_geom)), 2):
            if links_of_geom[i] != links_of_geom[j]:
                gmodel.addCollisionPair(pin.CollisionPair(i, j))
                self.by_link.setdefault(frozenset((links_of_geom[i], links_of_geom[j])),
                                        []).append(len(gmodel.collisionPairs) - 1)
        self.data, self.gdata = model.createData(), pin.GeometryData(gmodel)

    def colliding(self, q: np.ndarray, pairs: list[frozenset]) -> dict[frozenset, bool]:
        """Whether each link pair of ``pairs`` (all active) collides at ``q``."""
        if self.threads > 1:
            pin.computeCollisionsInParallel(self.threads, self.model, self.data, self.gmodel,
                                            self.gdata, q, False)
        else:
            pin.computeCollisions(self.model, self.data, self.gmodel, self.gdata, q, False)
        results = self.gdata.collisionResults
        return {p: any(results[k].isCollision() for k in self.by_link[p]) for p in pairs}

    def activate(self, pairs) -> None:
        """Check the geometry pairs of ``pairs`` only."""
        active = {k for p in pairs for k in self.by_link[p]}
        for k in range(len(self.gmodel.collisionPairs)):
            if k in active:
                self.gdata.activateCollisionPair(k)
            else:
                self.gdata.deactivateCollisionPair(k)


def _collision_counts(pairs: _LinkPairs, pending: list[frozenset], Q: np.ndarray,
                      misses_allowed: float) -> dict[frozenset, int]:
    """In how many of the configurations ``Q`` each link pair of ``pending`` collides; a pair
    stops being counted once it has both collided and missed more than ``misses_allowed``
    times (neither Never nor Always any more)."""
    counts = dict.fromkeys(pending, 0)
    live = list(pending)
    pairs.activate(live)
    for i, q in enumerate(Q):
        for p, hit in pairs.colliding(q, live).items():
            counts[p] += hit
        sealed = [p for p in live if counts[p] > 0 and (i + 1 - counts[p]) > misses_allowed]
        if sealed:
            live = [p for p in live if p not in set(sealed)]
            pairs.activate(live)
    return counts


def srdf_text(robot_name: str, disabled, group: str = '', group_joints=(),
              base: ET.Element | None = None) -> str:
    """An SRDF: ``base``'s elements (if given) plus a group of ``group_joints`` (if given) and
    the ``disabled`` pairs not already disabled in ``base`` (either link order)."""
    root = base if base is not None else ET.Element('robot', {'name': robot_name})
    if group_joints:
        element = ET.SubElement(root, 'group', {'name': group or 'arm'})
        for joint in group_joints:
            ET.SubElement(element, 'joint', {'name': joint})
    known = {frozenset((e.get('link1'), e.get('link2'))) for e in root.iter('disable_collisions')}
    for pair in disabled:
        if frozenset((pair.link1, pair.link2)) not in known:
            ET.SubElement(root, 'disable_collisions',
                          {'link1': pair.link1, 'link2': pair.link2, 'reason': pair.reason})
    ET.indent(root, '  ')
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding='unicode') + '\n'


__all__ = ['CollisionPairsResult', 'DisabledPair', 'REASONS', 'default_configuration',
           'disabled_collision_pairs', 'random_configurations', 'srdf_text']
