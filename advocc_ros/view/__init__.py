"""The offline 3D page of an attack or an audit (meshcat's viewer, one self-contained HTML file).
No ROS."""
