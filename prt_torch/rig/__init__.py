"""prt_torch.rig: skinned characters (skeleton, LBS, pose features, glTF/BVH loading, built-in humanoid).

Importing this package does not import torch (torch LBS lives in :mod:`prt_torch.rig.skinning_torch`).
"""

from prt_torch.rig.character import Character, Poses
from prt_torch.rig.clip import Clip
from prt_torch.rig.features import pose_features
from prt_torch.rig.random_pose import random_poses
from prt_torch.rig.skeleton import forward_kinematics

__all__ = ["Character", "Clip", "Poses", "forward_kinematics", "pose_features", "random_poses"]
