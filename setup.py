"""ament_python package advocc_ros; dependencies are pinned (README, 'How the install works')."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'advocc_ros'

RUNTIME = [
    'ros-jazzy-rclpy[fastrtps]==7.1.6',
    'ros-jazzy-common-interfaces==5.3.6',
    'pin==4.1.0',
    'coal==3.0.3',
    # 1.7.0, not 2.0.1: 2.0.1's PRM* deadlocks with Python validity checkers (README).
    'ompl==1.7.0',
    'trimesh==5.2.0',
    'numpy==2.4.6',
    'scipy==1.17.1',
    'example-robot-data==6.0.0',
    'pyyaml==6.0.3',
    'matplotlib==3.11.2',
    'tqdm==4.70.1',
    'cmaes==0.13.1',
    'meshcat==0.3.2',  # its bundled browser viewer makes the offline 3D pages
    'mcap==1.6.0',  # ROS 2 bags in rosbag2's MCAP storage
    'pypcd4==1.5.1',  # PCD point-cloud files (cloud scene objects)
    'ray==2.60.0',  # advocc dataset build: one task per problem, local or on a cluster
]
# Wheels needed to build the interface package msg_defs/ (advocc_msgs) with cmake.
BUILD = [
    f'ros-jazzy-{name}=={version}' for name, version in [
        ('ament-cmake', '2.5.4'), ('ament-cmake-core', '2.5.4'),
        ('ament-cmake-export-definitions', '2.5.4'), ('ament-cmake-export-dependencies', '2.5.4'),
        ('ament-cmake-export-include-directories', '2.5.4'),
        ('ament-cmake-export-interfaces', '2.5.4'), ('ament-cmake-export-libraries', '2.5.4'),
        ('ament-cmake-export-link-flags', '2.5.4'), ('ament-cmake-export-targets', '2.5.4'),
        ('ament-cmake-gen-version-h', '2.5.4'), ('ament-cmake-gmock', '2.5.4'),
        ('ament-cmake-gtest', '2.5.4'), ('ament-cmake-include-directories', '2.5.4'),
        ('ament-cmake-libraries', '2.5.4'), ('ament-cmake-pytest', '2.5.4'),
        ('ament-cmake-python', '2.5.4'), ('ament-cmake-ros', '0.12.0'),
        ('ament-cmake-target-dependencies', '2.5.4'), ('ament-cmake-test', '2.5.4'),
        ('ament-cmake-vendor-package', '2.5.4'), ('ament-cmake-version', '2.5.4'),
        ('ament-package', '0.16.4'), ('fastrtps-cmake-module', '3.6.2'),
        ('gmock-vendor', '1.14.9000'), ('gtest-vendor', '1.14.9000'),
        ('python-cmake-module', '0.11.1'), ('rmw-implementation-cmake', '7.3.2'),
        ('rosidl-adapter', '4.6.6'), ('rosidl-cli', '4.6.6'), ('rosidl-cmake', '4.6.6'),
        ('rosidl-core-generators', '0.2.0'), ('rosidl-core-runtime', '0.2.0'),
        ('rosidl-default-generators', '1.6.0'), ('rosidl-default-runtime', '1.6.0'),
        ('rosidl-dynamic-typesupport', '0.1.2'), ('rosidl-dynamic-typesupport-fastrtps', '0.1.0'),
        ('rosidl-generator-c', '4.6.6'), ('rosidl-generator-cpp', '4.6.6'),
        ('rosidl-generator-py', '0.22.2'), ('rosidl-generator-type-description', '4.6.6'),
        ('rosidl-parser', '4.6.6'), ('rosidl-pycommon', '4.6.6'),
        ('rosidl-runtime-c', '4.6.6'), ('rosidl-runtime-cpp', '4.6.6'),
        ('rosidl-typesupport-c', '3.2.2'), ('rosidl-typesupport-cpp', '3.2.2'),
        ('rosidl-typesupport-fastrtps-c', '3.6.2'), ('rosidl-typesupport-fastrtps-cpp', '3.6.2'),
        ('rosidl-typesupport-interface', '4.6.6'),
        ('rosidl-typesupport-introspection-c', '4.6.6'),
        ('rosidl-typesupport-introspection-cpp', '4.6.6'),
    ]
] + ['catkin-pkg==1.1.1']
# colcon: the workspace test builds this repository with colcon, as a ROS 2 user does;
# pytest-xdist runs the suite on two workers (setup.cfg).
TEST = ['pytest==9.2.0', 'pytest-xdist==3.8.0', 'hypothesis==6.170.15', 'flake8==7.3.0',
        'mcap-ros2-support==0.6.0', 'colcon-common-extensions==0.3.0']
# Outside victims in this interpreter: TrajOpt via Tesseract (0.5.1 imports with numpy 2; the
# nanobind successor needs a newer libstdc++ than Debian 12's). MPlib has its own venv.
VICTIMS = ['tesseract-robotics==0.5.1']

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={f'{PACKAGE}.kernels': ['*.c', '*.h']},  # built on first use (kernels/)
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml') + ['config/advocc.rviz']),
        (f'share/{PACKAGE}/config/scenes', glob('config/scenes/*.yaml')),
    ],
    python_requires='>=3.11,<3.12',
    install_requires=RUNTIME,
    extras_require={'build': BUILD, 'test': TEST, 'victims': VICTIMS},
    zip_safe=True,
    maintainer='advocc_ros maintainers',
    maintainer_email='maintainers@advocc-ros.org',
    description='Planner-agnostic adversarial obstacles for tolerance-aware manipulation.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'advocc = advocc_ros.cli:main',
            'heatmap_server = advocc_ros.nodes.heatmap_server:main',
            'attacker = advocc_ros.nodes.attacker:main',
            'planner_shim = advocc_ros.nodes.planner_shim:main',
            'orchestrator = advocc_ros.orchestrator:main',
        ],
    },
)
