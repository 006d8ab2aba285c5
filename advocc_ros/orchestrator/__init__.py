"""The benchmark orchestrator: runs the paper's protocol against the ROS 2 nodes."""

from advocc_ros.orchestrator.cli import main
from advocc_ros.orchestrator.run import Orchestrator, write_report

__all__ = ['Orchestrator', 'main', 'write_report']
