"""The offline phase: the kinematic occupancy heatmap, its build and its file format. No ROS."""

from advocc_ros.heatmap.build import (CHUNK_SAMPLES, FORMAT_VERSION, Heatmap, HeatmapConfig,
                                      HeatmapError, build_heatmap, load_heatmap, merge_heatmaps,
                                      sample_weights, save_heatmap, workspace_grid)

__all__ = [
    'CHUNK_SAMPLES', 'FORMAT_VERSION', 'Heatmap', 'HeatmapConfig', 'HeatmapError',
    'build_heatmap', 'load_heatmap', 'merge_heatmaps', 'sample_weights', 'save_heatmap',
    'workspace_grid']
