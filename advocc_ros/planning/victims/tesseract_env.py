"""A Tesseract environment of our robot and scene: what the TrajOpt victim plans in.

Tesseract (ROS-Industrial; PyPI ``tesseract-robotics`` 0.5.1, SWIG bindings) loads a robot from
URDF + SRDF, where the SRDF also names the kinematics plugins (KDL) and the contact managers
(Bullet) as YAML files. We write those files for our ``RobotModel`` into a private directory:

- the URDF is the robot's own, with ``package://example-robot-data/`` made absolute and
  ``tesseract:make_convex`` set, so each collision mesh becomes its convex hull: what Tesseract's
  TrajOpt examples do (the signed distances of the SQP need convex shapes), and the shapes our
  own checker uses too;
- the SRDF has one chain group ``manipulator`` (URDF root -> end-effector link) and the robot
  SRDF's ``disable_collisions`` pairs;
- the plugin YAML files name the wheel's bundled factory libraries. ``auditwheel`` renamed them
  (``libtesseract_kinematics_kdl_factories-<hash>.so``), so the names are looked up on disk.

Scene objects become fixed links of the URDF root (boxes, spheres, cylinders as Tesseract's
primitives; meshes as convex meshes). Joints outside the planning group (the Panda's fingers)
are set to the robot's locked values and stay there: TrajOpt moves only the group's joints.

The SWIG objects follow the C++ lifetimes (the bindings' README warns about it): anything read
out of a temporary (``response.results.flatten()``) must be kept referenced while it is used,
or the process segfaults (seen here). Keep every intermediate in a local variable.
"""

from __future__ import annotations

import pathlib
import re
import tempfile
import xml.etree.ElementTree as ET

import numpy as np

from advocc_ros.model.robot import RobotError, RobotModel, example_robot_data_share, resolve_path
from advocc_ros.model.shapes import Shape

_ERD_PACKAGE = 'package://example-robot-data/'
_TESSERACT_NS = 'https://github.com/tesseract-robotics/tesseract'
MANIPULATOR = 'manipulator'
"""Name of the SRDF chain group TrajOpt plans for."""


def _tesseract():
    """The Tesseract modules, imported on first use (a ~200 MB set of native libraries)."""
    import tesseract_robotics.tesseract_collision as tc
    import tesseract_robotics.tesseract_common as tcm
    import tesseract_robotics.tesseract_environment as te
    import tesseract_robotics.tesseract_geometry as tg
    import tesseract_robotics.tesseract_scene_graph as tsg
    return tc, tcm, te, tg, tsg


def _plugin_library(stem: str) -> tuple[str, str]:
    """(directory, library name without ``lib``/``.so``) of a bundled plugin factory."""
    import tesseract_robotics

    libs = pathlib.Path(tesseract_robotics.__file__).resolve().parent.parent / \
        'tesseract_robotics.libs'
    found = sorted(libs.glob(f'lib{stem}*.so*'))
    if not found:
        raise RobotError(f'tesseract-robotics ships no {stem} library in {libs}')
    name = found[0].name
    return str(libs), name[3:name.index('.so')]


def _root_link(urdf: ET.Element) -> str:
    children = {j.find('child').get('link') for j in urdf.iter('joint')}
    roots = [link.get('name') for link in urdf.iter('link') if link.get('name') not in children]
    if len(roots) != 1:
        raise RobotError(f'URDF has {len(roots)} root links {roots}: expected one')
    return roots[0]


def _urdf_text(robot: RobotModel) -> tuple[str, str, str]:
    """(URDF text for Tesseract, root link name, robot name)."""
    path = resolve_path(robot.spec.urdf)
    text = path.read_text()
    text = text.replace(_ERD_PACKAGE, str(example_robot_data_share() / 'example-robot-data') + '/')
    others = sorted(set(re.findall(r'package://[^/"]+', text)))
    if others:
        raise RobotError(f'{path}: mesh packages {others} cannot be resolved for Tesseract')
    # Relative mesh paths are relative to the URDF's folder, as in ROS.
    text = re.sub(r'filename="(?!/)([^"]+)"',
                  lambda m: f'filename="{(path.parent / m.group(1)).resolve()}"', text)
    root = ET.fromstring(text)
    root.set('xmlns:tesseract', _TESSERACT_NS)
    root.set('tesseract:make_convex', 'true')
    return ET.tostring(root, encoding='unicode'), _root_link(root), root.get('name', '')


def _plugins_yaml(base: str, tip: str) -> tuple[str, str]:
    """(kinematics plugins YAML, contact managers YAML)."""
    kin_dir, kin_lib = _plugin_library('tesseract_kinematics_kdl_factories')
    col_dir, col_lib = _plugin_library('tesseract_collision_bullet_factories')
    chain = f'{{base_link: {base}, tip_link: {tip}}}'
    kinematics = f"""kinematic_plugins:
  search_paths: ['{kin_dir}']
  search_libraries: ['{kin_lib}']
  fwd_kin_plugins:
    {MANIPULATOR}:
      default: KDLFwdKinChain
      plugins:
        KDLFwdKinChain: {{class: KDLFwdKinChainFactory, config: {chain}}}
  inv_kin_plugins:
    {MANIPULATOR}:
      default: KDLInvKinChainLMA
      plugins:
        KDLInvKinChainLMA: {{class: KDLInvKinChainLMAFactory, config: {chain}}}
"""
    contact = f"""contact_manager_plugins:
  search_paths: ['{col_dir}']
  search_libraries: ['{col_lib}']
  discrete_plugins:
    default: BulletDiscreteBVHManager
    plugins:
      BulletDiscreteBVHManager: {{class: BulletDiscreteBVHManagerFactory}}
  continuous_plugins:
    default: BulletCastBVHManager
    plugins:
      BulletCastBVHManager: {{class: BulletCastBVHManagerFactory}}
"""
    return kinematics, contact


def write_robot_files(robot: RobotModel, folder: pathlib.Path
                      ) -> tuple[pathlib.Path, pathlib.Path]:
    """Write the URDF, SRDF and plugin YAML files Tesseract needs; return (URDF, SRDF)."""
    urdf_text, base, name = _urdf_text(robot)
    kinematics, contact = _plugins_yaml(base, robot.spec.ee_link)
    disabled = ET.parse(resolve_path(robot.spec.srdf)).getroot().iter('disable_collisions')
    pairs = '\n'.join(f'  <disable_collisions link1="{d.get("link1")}" '
                      f'link2="{d.get("link2")}" reason="{d.get("reason", "")}"/>'
                      for d in disabled)
    (folder / 'kinematics.yaml').write_text(kinematics)
    (folder / 'contact_managers.yaml').write_text(contact)
    srdf = f"""<?xml version="1.0"?>
<robot name="{name}">
  <group name="{MANIPULATOR}"><chain base_link="{base}" tip_link="{robot.spec.ee_link}"/></group>
  <kinematics_plugin_config filename="{folder / 'kinematics.yaml'}"/>
  <contact_managers_plugin_config filename="{folder / 'contact_managers.yaml'}"/>
{pairs}
</robot>
"""
    (folder / 'robot.urdf').write_text(urdf_text)
    (folder / 'robot.srdf').write_text(srdf)
    return folder / 'robot.urdf', folder / 'robot.srdf'


def _geometry(shape: Shape, where: str):
    _, _, _, tg, _ = _tesseract()
    if shape.kind == 'box':
        return tg.Box(*shape.dims)
    if shape.kind == 'sphere':
        return tg.Sphere(shape.dims[0])
    if shape.kind == 'cylinder':
        return tg.Cylinder(shape.dims[1], shape.dims[0])  # ours: (height, radius)
    raise ValueError(f'{where}: the TrajOpt victim takes boxes, spheres and cylinders, not '
                     f'{shape.kind!r}')


class TesseractWorld:
    """Tesseract environment of one robot; ``set_objects`` swaps the scene objects.

    Loading the robot (meshes, convex hulls, plugins) takes ~0.3-1 s and is done once; a new
    scene removes the previous objects' links and adds its own (~10-20 ms). (``env.clone()``
    returns a type the planners' bindings do not accept.)
    """

    def __init__(self, robot: RobotModel):
        tc, tcm, te, _, _ = _tesseract()
        self.robot = robot
        self._locator = tcm.GeneralResourceLocator()  # must outlive the environment
        self.env = te.Environment()
        # The files are read by init only; removed at once, since a worker that is killed
        # (watchdog, close timeout) would leave them in /tmp.
        with tempfile.TemporaryDirectory(prefix='advocc_tesseract_') as folder:
            urdf, srdf = write_robot_files(robot, pathlib.Path(folder))
            loaded = self.env.init(tcm.FilesystemPath(str(urdf)), tcm.FilesystemPath(str(srdf)),
                                   self._locator)
        if not loaded:
            raise RobotError('Tesseract could not load the robot (see its log above)')
        group = list(self.env.getJointGroup(MANIPULATOR).getJointNames())
        if group != list(robot.joint_names):
            raise RobotError(f'Tesseract chain joints {group} differ from the planning group '
                             f'{list(robot.joint_names)}')
        self.root = _urdf_text(robot)[1]
        if robot.locked_values:
            names = list(robot.locked_values)
            self.env.setState(names, np.array([robot.locked_values[n] for n in names]))
        self._objects: list[str] = []
        self._manager = None

    def set_objects(self, shapes: list[Shape]) -> None:
        """Scene objects of the next plans (replaces the previous ones)."""
        _, tcm, te, _, tsg = _tesseract()
        env = self.env
        for name in self._objects:
            env.applyCommand(te.RemoveLinkCommand(name))
        self._objects = []
        self._manager = None
        for i, shape in enumerate(shapes):
            link = tsg.Link(f'advocc_object_{i}')
            collision = tsg.Collision()
            collision.geometry = _geometry(shape, f'object shape {i}')
            link.collision.push_back(collision)
            joint = tsg.Joint(f'advocc_object_{i}_joint')
            joint.parent_link_name = self.root
            joint.child_link_name = link.getName()
            joint.type = tsg.JointType_FIXED
            x, y, z, w = shape.pose.quat_xyzw
            joint.parent_to_joint_origin_transform = (
                tcm.Isometry3d.Identity() * tcm.Translation3d(*shape.pose.position_m)
                * tcm.Quaterniond(w, x, y, z))
            if not env.applyCommand(te.AddLinkCommand(link, joint)):
                raise ValueError(f'Tesseract refused object shape {i}')
            self._objects.append(link.getName())

    def collisions(self, Q: np.ndarray) -> np.ndarray:
        """(N,) bool: configuration i collides in Tesseract's own model (Bullet, convex hulls;
        self-collision per SRDF and the scene)."""
        tc, tcm, _, _, _ = _tesseract()
        if self._manager is None:
            manager = self.env.getDiscreteContactManager()
            manager.setActiveCollisionObjects(self.env.getActiveLinkNames())
            manager.setCollisionMarginData(tcm.CollisionMarginData(0.0))
            self._manager, self._solver = manager, self.env.getStateSolver()
        names = list(self.robot.joint_names)
        out = np.zeros(len(Q), bool)
        for i, q in enumerate(np.asarray(Q, float)):
            self._solver.setState(names, q)
            state = self._solver.getState()
            self._manager.setCollisionObjectsTransform(state.link_transforms)
            contacts = tc.ContactResultMap()
            self._manager.contactTest(contacts, tc.ContactRequest(tc.ContactTestType_FIRST))
            out[i] = contacts.size() > 0
        return out
