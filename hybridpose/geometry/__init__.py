"""Geometry: the ``Pose`` type, quaternion and SE(3) helpers, the pinhole ``Camera``.

Conventions: ``Pose`` is ``T_cam_obj`` (object → OpenCV camera frame, metres); quaternions are
Hamilton (w, x, y, z); tangent vectors are ``[ω (rad), v (m)]`` with right perturbation.
"""
from .camera import (
    Camera,
    facing_pose,
    line_jacobian,
    mirrored_tilt,
    parse_size,
    projection_jacobian,
    save_camera,
    shifted_in_image,
    sphere_directions,
    turned_about,
)
from .camera_files import NoImageSize, load_camera
from .checks import as_points3d, as_rgb_image, as_rotation_matrix, as_unit_direction, as_unit_quat, read_only
from .pose import Pose
from .rotations import (
    matrix_to_quat_wxyz,
    matrix_to_rotvec,
    quat_angle_between,
    quat_canonical,
    quat_conjugate,
    quat_multiply,
    quat_slerp,
    quat_to_rotvec,
    quat_wxyz_to_matrix,
    random_quat,
    rotvec_to_matrix,
    rotvec_to_quat,
    skew,
)
from .se3 import se3_exp, se3_log, so3_left_jacobian

__all__ = [
    "Camera", "Pose", "load_camera", "mirrored_tilt", "shifted_in_image", "turned_about", "facing_pose", "sphere_directions", "NoImageSize", "save_camera", "parse_size", "projection_jacobian", "line_jacobian",
    "as_points3d", "as_rgb_image", "as_rotation_matrix", "as_unit_direction", "as_unit_quat", "read_only",
    "matrix_to_quat_wxyz", "matrix_to_rotvec", "quat_angle_between", "quat_canonical", "quat_conjugate",
    "quat_multiply", "quat_slerp", "quat_to_rotvec", "quat_wxyz_to_matrix", "random_quat",
    "rotvec_to_matrix", "rotvec_to_quat", "skew", "se3_exp", "se3_log", "so3_left_jacobian",
]
