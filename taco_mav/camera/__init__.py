"""The camera: frame sources (OpenCV device, video, URL, GStreamer, image folder, registered schemes; sources.py),
the ground-plane geometry (geometry.py), lens calibration and undistortion (calibration.py) and the horizon
check of the mount's pitch (horizon.py)."""
