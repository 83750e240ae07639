"""Moved: the camera models are :mod:`scheimpflug.calibration.camera` (issue 24).

This module re-exports their names so that code written before the calibration became a
package keeps working; new code imports from :mod:`scheimpflug.calibration`.
"""

from scheimpflug.calibration.camera import CAMERA_FROM_RIG, TiltedCamera, camera_from_sensor_pose, tilt_matrix

__all__ = ["CAMERA_FROM_RIG", "TiltedCamera", "camera_from_sensor_pose", "tilt_matrix"]
