"""The offline phase: the kinematic occupancy heatmap, its build and its file format. No ROS.

Names are loaded from their module on first use (``from advocc_ros.heatmap import Heatmap``
loads the file format, not the build's compiled kernels)."""

from advocc_ros import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {
    'config': ('HeatmapConfig', 'weight_config'),
    'build': ('CHUNK_SAMPLES', 'LinkTables', 'build_heatmap', 'link_tables', 'placement_arrays',
              'sample_weights', 'workspace_grid'),
    'store': ('FORMAT_VERSION', 'Heatmap', 'HeatmapError', 'hottest_voxels', 'load_heatmap',
              'merge_heatmaps', 'save_heatmap'),
})
