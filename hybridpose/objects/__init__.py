"""Object models: mesh in metres, sharp edges, 3D keypoints, diameter; built-in ``truss``, ``cube`` and ``box``."""
from .base import (ObjectModel, default_keypoints, light_azimuth_deg, sharp_edges, sun_phase_angle_deg,
                   view_elevation_deg)
from .loaders import load_builtin, load_object, save_object

__all__ = ["ObjectModel", "default_keypoints", "light_azimuth_deg", "load_builtin", "load_object", "save_object", "sharp_edges",
           "sun_phase_angle_deg", "view_elevation_deg"]
