"""The pybullet world: scene, vehicle posing, cameras, lidar, line of sight, ground truth.

`layout` has no pybullet import (scenario validation uses it); the other
modules need pybullet. Every World owns a private DIRECT client. `dataset_cli` is
`v2i dataset` (labelled camera frames from a scenario's world).
"""
