"""The offline phase: the kinematic occupancy heatmap, its build and its file format."""

from advocc_ros.heatmap.build import (build_heatmap, CHUNK_SAMPLES, FORMAT_VERSION, Heatmap,
                                      HeatmapConfig, HeatmapError, load_heatmap, log,
                                      merge_heatmaps, sample_weights, save_heatmap, workspace_grid)

__all__ = [
    'build_heatmap', 'CHUNK_SAMPLES', 'FORMAT_VERSION', 'Heatmap', 'HeatmapConfig',
    'HeatmapError', 'load_heatmap', 'log', 'merge_heatmaps', 'sample_weights', 'save_heatmap',
    'workspace_grid']
