"""The offline phase: the kinematic occupancy heatmap, its build and its file format. No ROS."""

from advocc_ros.heatmap.build import (CHUNK_SAMPLES, HeatmapConfig, LinkTables, build_heatmap,
                                      link_tables, placement_arrays, sample_weights,
                                      workspace_grid)
from advocc_ros.heatmap.store import (FORMAT_VERSION, Heatmap, HeatmapError, hottest_voxels,
                                      load_heatmap, merge_heatmaps, save_heatmap)

__all__ = [
    'CHUNK_SAMPLES', 'FORMAT_VERSION', 'Heatmap', 'HeatmapConfig', 'HeatmapError', 'LinkTables',
    'build_heatmap', 'hottest_voxels', 'link_tables', 'load_heatmap', 'merge_heatmaps',
    'placement_arrays', 'sample_weights', 'save_heatmap', 'workspace_grid']
