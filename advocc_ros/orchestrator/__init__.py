"""The benchmark orchestrator: runs the paper's protocol against the ROS 2 nodes."""

from advocc_ros.bench.report import write_report
from advocc_ros.orchestrator.cli import main
from advocc_ros.orchestrator.run import Orchestrator

__all__ = ['Orchestrator', 'main', 'write_report']
